"""Message definitions of the tactile recording contract (ROS 2 ``.msg``, CDR encoded)."""

from schemas._layout import (
    PART_SUFFIX,
    RECORDING_SUFFIX,
    RECOVERED_SUFFIX,
    dataset_recordings,
    is_recording,
)
from schemas._topics import CHANNELS, Channel, channel_for_topic
from schemas._typestore import (
    CUSTOM_TYPES,
    PACKAGE,
    SCHEMA_VERSION,
    build_typestore,
    full_type_name,
    msg_definition,
)

__all__ = [
    "CHANNELS",
    "CUSTOM_TYPES",
    "PACKAGE",
    "PART_SUFFIX",
    "RECORDING_SUFFIX",
    "RECOVERED_SUFFIX",
    "SCHEMA_VERSION",
    "Channel",
    "build_typestore",
    "channel_for_topic",
    "dataset_recordings",
    "full_type_name",
    "is_recording",
    "msg_definition",
]
