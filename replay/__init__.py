"""Replay MCAP recordings through feature extraction and the ATIKT active-learning loop."""

from replay.errors import RecordingError, ReplayError

__all__ = ["RecordingError", "ReplayError"]
