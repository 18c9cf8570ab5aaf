"""Replay MCAP recordings through feature extraction and the ATIKT active-learning loop."""

from replay.errors import RecordingError, ReplayError
from replay.learning._run_history import LearnRun, load_run
from replay.outputs._export import ExportReport, export
from replay.recording._reader import (
    MODALITIES,
    ActionRecording,
    JointStates,
    PhaseStart,
    SkinSeries,
    TcpPoses,
    check_dataset_location,
    read_recording,
)
from replay.recording._salvage import RecoveryReport, recovered_path, salvage
from schemas import RecordingMetadata

__all__ = [
    "MODALITIES",
    "ActionRecording",
    "ExportReport",
    "JointStates",
    "LearnRun",
    "PhaseStart",
    "RecordingError",
    "RecordingMetadata",
    "RecoveryReport",
    "ReplayError",
    "SkinSeries",
    "TcpPoses",
    "check_dataset_location",
    "export",
    "load_run",
    "read_recording",
    "recovered_path",
    "salvage",
]
