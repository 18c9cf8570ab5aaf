"""Record exploratory actions of a UR10 with a multimodal skin into MCAP files."""

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
from recorder._rig import Rig
from recorder._rigconfig import (
    RigConfig,
    load_rig_config,
    register_rig,
    rig_factory,
    rig_names,
)
from recorder._sim import SimConfig, SimulatedRig
from recorder.bagimport._importer import ImportReport, import_bag
from recorder.bagimport._topicmap import TopicMap, load_topic_map
from recorder.errors import (
    BagImportError,
    CatalogError,
    OutputExistsError,
    RecorderError,
    RigError,
)
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
    record_action,
)
from schemas import software_version

__all__ = [
    "ActionKind",
    "ActionSpec",
    "BagImportError",
    "CatalogError",
    "ImportReport",
    "JointSample",
    "Modality",
    "ObjectPhysics",
    "ObjectSpec",
    "OutputExistsError",
    "Phase",
    "PhaseEvent",
    "PoseSample",
    "RecorderError",
    "RecordingInfo",
    "RecordingTask",
    "RecordingWriter",
    "Rig",
    "RigConfig",
    "RigError",
    "SimConfig",
    "SimulatedRig",
    "SkinBlock",
    "StreamItem",
    "TopicMap",
    "WrittenRecording",
    "declare_objects",
    "generate_dataset",
    "import_bag",
    "load_actions",
    "load_objects",
    "load_rig_config",
    "load_topic_map",
    "plan_dataset",
    "record_action",
    "recording_path",
    "register_rig",
    "rig_factory",
    "rig_names",
    "software_version",
    "write_index",
]
