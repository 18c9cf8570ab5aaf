"""Record exploratory actions of a UR10 with a multimodal skin into MCAP files."""

import importlib
from typing import TYPE_CHECKING, Any

from recorder._catalog import (
    ActionKind,
    ActionSpec,
    ObjectPhysics,
    ObjectSpec,
    load_actions,
    load_objects,
)
from recorder._dataset import (
    RecordingTask,
    declare_objects,
    generate_dataset,
    plan_dataset,
    recording_path,
    set_aside_stale_parts,
    stale_parts,
    write_index,
)
from recorder._rig import Accounting, Connecting, Moving, Presenting, Rig
from recorder._rigconfig import (
    ENTRY_POINT_GROUP,
    SIM_RIG,
    ConfiguredRig,
    FrozenTable,
    RigConfig,
    RigPlugin,
    check_object_poses,
    find_rig,
    is_exclusive,
    load_rig_config,
    refuse_sections,
    register_rig,
    rig_factory,
    rig_names,
)
from recorder._session import RigCheck, check_rig_ready, refuse_unrecordable
from recorder.errors import (
    ActionStoppedError,
    BagImportError,
    CatalogError,
    OutputExistsError,
    RecorderError,
    RigError,
)
from recorder.runner import ArmDriver, ArmRig, ArmSample, RunnerOptions
from recorder.runner._record import record_action
from recorder.runner._viewer import Viewer
from recorder.writing._foxglove import FoxgloveView
from recorder.writing._stream import (
    JointSample,
    Modality,
    Phase,
    PhaseEvent,
    PoseSample,
    SkinBlock,
    StreamItem,
)
from recorder.writing._writer import (
    RecordingInfo,
    RecordingWriter,
    WrittenRecording,
)
from schemas import software_version

if TYPE_CHECKING:
    from recorder._sim import SimConfig, SimulatedRig
    from recorder._sim.rig import SIMULATOR_VERSION
    from recorder.bagimport._importer import import_bag
    from recorder.bagimport._report import ImportReport
    from recorder.bagimport._topicmap import TopicMap, load_topic_map

#: Names imported on first use: the simulator loads scipy, the bag importer rosbags' readers;
#: a live session, serve-sim or listen never needs them.
_LAZY = {
    "SimConfig": "recorder._sim",
    "SimulatedRig": "recorder._sim",
    "SIMULATOR_VERSION": "recorder._sim.rig",
    "import_bag": "recorder.bagimport._importer",
    "ImportReport": "recorder.bagimport._report",
    "TopicMap": "recorder.bagimport._topicmap",
    "load_topic_map": "recorder.bagimport._topicmap",
}


def __getattr__(name: str) -> Any:  # noqa: ANN401 (see _LAZY)
    """Import the simulator's and the bag importer's names on first use (see :data:`_LAZY`)."""
    module = _LAZY.get(name)
    if module is None:
        msg = f"module 'recorder' has no attribute {name!r}"
        raise AttributeError(msg)
    return getattr(importlib.import_module(module), name)


__all__ = [
    "ENTRY_POINT_GROUP",
    "SIMULATOR_VERSION",
    "SIM_RIG",
    "Accounting",
    "ActionKind",
    "ActionSpec",
    "ActionStoppedError",
    "ArmDriver",
    "ArmRig",
    "ArmSample",
    "BagImportError",
    "CatalogError",
    "ConfiguredRig",
    "Connecting",
    "FoxgloveView",
    "FrozenTable",
    "ImportReport",
    "JointSample",
    "Modality",
    "Moving",
    "ObjectPhysics",
    "ObjectSpec",
    "OutputExistsError",
    "Phase",
    "PhaseEvent",
    "PoseSample",
    "Presenting",
    "RecorderError",
    "RecordingInfo",
    "RecordingTask",
    "RecordingWriter",
    "Rig",
    "RigCheck",
    "RigConfig",
    "RigError",
    "RigPlugin",
    "RunnerOptions",
    "SimConfig",
    "SimulatedRig",
    "SkinBlock",
    "StreamItem",
    "TopicMap",
    "Viewer",
    "WrittenRecording",
    "check_object_poses",
    "check_rig_ready",
    "declare_objects",
    "find_rig",
    "generate_dataset",
    "import_bag",
    "is_exclusive",
    "load_actions",
    "load_objects",
    "load_rig_config",
    "load_topic_map",
    "plan_dataset",
    "record_action",
    "recording_path",
    "refuse_sections",
    "refuse_unrecordable",
    "register_rig",
    "rig_factory",
    "rig_names",
    "set_aside_stale_parts",
    "software_version",
    "stale_parts",
    "write_index",
]
