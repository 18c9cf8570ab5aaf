"""Record exploratory actions of a UR10 with a multimodal skin into MCAP files."""

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
    write_index,
)
from recorder._rig import Accounting, Connecting, Presenting, Rig
from recorder._rigconfig import (
    ENTRY_POINT_GROUP,
    SIM_RIG,
    ConfiguredRig,
    FrozenTable,
    RigConfig,
    RigPlugin,
    find_rig,
    is_exclusive,
    load_rig_config,
    refuse_sections,
    register_rig,
    rig_factory,
    rig_names,
)
from recorder.bagimport._importer import import_bag
from recorder.bagimport._report import ImportReport
from recorder.bagimport._topicmap import TopicMap, load_topic_map
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


def __getattr__(name: str) -> Any:  # noqa: ANN401 (the simulator's classes)
    """Import the simulator on first use (it loads scipy; bag imports never need it)."""
    if name in {"SimConfig", "SimulatedRig"}:
        from recorder import _sim  # noqa: PLC0415

        return getattr(_sim, name)
    if name == "SIMULATOR_VERSION":
        from recorder._sim import rig  # noqa: PLC0415

        return rig.SIMULATOR_VERSION
    msg = f"module 'recorder' has no attribute {name!r}"
    raise AttributeError(msg)


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
    "register_rig",
    "rig_factory",
    "rig_names",
    "software_version",
    "write_index",
]
