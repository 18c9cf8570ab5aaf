"""Replay MCAP recordings through feature extraction and the ATIKT active-learning loop."""

from replay._export import ExportReport, export
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
from replay._run_history import LearnRun, load_run
from replay.errors import RecordingError, ReplayError

__all__ = [
    "MODALITIES",
    "ActionRecording",
    "ExportReport",
    "JointStates",
    "LearnRun",
    "PhaseStart",
    "RecordingError",
    "RecordingMetadata",
    "ReplayError",
    "SkinSeries",
    "TcpPoses",
    "export",
    "load_run",
    "read_recording",
]
