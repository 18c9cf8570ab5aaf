"""The thesis's studies over a dataset: tasks, parallel runs, results and summaries."""
