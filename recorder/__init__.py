"""Record exploratory actions of a UR10 with a multimodal skin into MCAP files."""

from recorder._catalog import ActionKind, ActionSpec, load_actions
from recorder._rig import Rig
from recorder._stream import (
    JointSample,
    Modality,
    Phase,
    PhaseEvent,
    PoseSample,
    SkinBlock,
    StreamItem,
)
from recorder.errors import CatalogError, OutputExistsError, RecorderError, RigError

__all__ = [
    "ActionKind",
    "ActionSpec",
    "CatalogError",
    "JointSample",
    "Modality",
    "OutputExistsError",
    "Phase",
    "PhaseEvent",
    "PoseSample",
    "RecorderError",
    "Rig",
    "RigError",
    "SkinBlock",
    "StreamItem",
    "load_actions",
]
