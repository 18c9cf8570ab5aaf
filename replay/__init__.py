"""Replay MCAP recordings through feature extraction and the ATIKT active-learning loop."""

from replay._reader import (
    MODALITIES,
    ActionRecording,
    JointStates,
    PhaseStart,
    RecordingMetadata,
    SkinSeries,
    TcpPoses,
    read_recording,
)
from replay.errors import RecordingError, ReplayError

__all__ = [
    "MODALITIES",
    "ActionRecording",
    "JointStates",
    "PhaseStart",
    "RecordingError",
    "RecordingMetadata",
    "ReplayError",
    "SkinSeries",
    "TcpPoses",
    "read_recording",
]
