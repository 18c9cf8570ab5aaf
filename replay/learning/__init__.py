"""Observations for the learner: features and their cache, executors, the learning session."""
