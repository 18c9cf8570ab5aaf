"""The recording contract: its vocabulary as data, message definitions, metadata and layout.

``VOCABULARY`` (from ``schemas/contract.toml``) lists the skin modalities, robot and event
channels, phases, sources and action kinds; nothing else in the project lists them.
"""

from schemas import _cli as cli
from schemas import cdr
from schemas._atomic import (
    atomic_file,
    atomic_path,
    atomic_write,
    atomic_write_text,
    create_exclusive,
    publish_temporary,
    temporary_name,
)
from schemas._layout import (
    INCOMPLETE_RECORD,
    INCOMPLETE_SUFFIX,
    PART_SUFFIX,
    RECORDING_SUFFIX,
    RECOVERED_SUFFIX,
    SET_ASIDE_DIR,
    check_inside,
    dataset_recordings,
    is_incomplete,
    is_recording,
    recording_path,
)
from schemas._metadata import (
    MAX_CELLS,
    MAX_SEED,
    MAX_TRIAL,
    RecordingMetadata,
    RigValue,
    check_id,
    check_parameters,
    check_rig,
    parse_metadata,
    software_version,
)
from schemas._parquet import ParquetMismatchError, read_checked_parquet, rows_allowed
from schemas._sources import (
    SOURCES_RECORD,
    SourceStats,
    encode_source_stats,
    lost_samples,
    parse_source_stats,
)
from schemas._toml import MAX_TOML_BYTES, MAX_TOML_DEPTH, TomlLimitError, load_toml, loads_toml
from schemas._topics import CHANNELS, Channel, channel_for_topic
from schemas._typestore import (
    CUSTOM_TYPES,
    MESSAGE_VERSION,
    PACKAGE,
    SCHEMA_VERSION,
    VOCABULARY,
    build_typestore,
    full_type_name,
    msg_definition,
)
from schemas._vocabulary import (
    ChannelSpec,
    KindSpec,
    LegacySpec,
    ModalitySpec,
    SourceSpec,
    Vocabulary,
    parse_vocabulary,
)
from schemas.errors import CdrError, ContractError

__all__ = [
    "CHANNELS",
    "CUSTOM_TYPES",
    "INCOMPLETE_RECORD",
    "INCOMPLETE_SUFFIX",
    "MAX_CELLS",
    "MAX_SEED",
    "MAX_TOML_BYTES",
    "MAX_TOML_DEPTH",
    "MAX_TRIAL",
    "MESSAGE_VERSION",
    "PACKAGE",
    "PART_SUFFIX",
    "RECORDING_SUFFIX",
    "RECOVERED_SUFFIX",
    "SCHEMA_VERSION",
    "SET_ASIDE_DIR",
    "SOURCES_RECORD",
    "VOCABULARY",
    "CdrError",
    "Channel",
    "ChannelSpec",
    "ContractError",
    "KindSpec",
    "LegacySpec",
    "ModalitySpec",
    "ParquetMismatchError",
    "RecordingMetadata",
    "RigValue",
    "SourceSpec",
    "SourceStats",
    "TomlLimitError",
    "Vocabulary",
    "atomic_file",
    "atomic_path",
    "atomic_write",
    "atomic_write_text",
    "build_typestore",
    "cdr",
    "channel_for_topic",
    "check_id",
    "check_inside",
    "check_parameters",
    "check_rig",
    "cli",
    "create_exclusive",
    "dataset_recordings",
    "encode_source_stats",
    "full_type_name",
    "is_incomplete",
    "is_recording",
    "load_toml",
    "loads_toml",
    "lost_samples",
    "msg_definition",
    "parse_metadata",
    "parse_source_stats",
    "parse_vocabulary",
    "publish_temporary",
    "read_checked_parquet",
    "recording_path",
    "rows_allowed",
    "software_version",
    "temporary_name",
]
