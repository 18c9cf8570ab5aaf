"""The recording's metadata record: one type, one encoder, one parser, strictly typed.

Every writer (recorder, bag import, salvage, migration) encodes a :class:`RecordingMetadata`
with :meth:`RecordingMetadata.encode`; every reader (replay's reader, the dataset index,
``info``) parses it with :func:`parse_metadata`. The parser checks every field's type and
range and refuses unknown keys: a key this schema version does not define means the file was
written by something else. A lab's own information goes into the ``rig`` field or into an MCAP
metadata record of another name, which readers keep and ignore.

Schema 1 records (atikt 0.1) are read too: their ``object_novel`` key (which objects are
priors, now chosen per run) must be a JSON boolean and is dropped.
"""

from __future__ import annotations

import functools
import json
import math
import re
from dataclasses import dataclass
from importlib import metadata as importlib_metadata
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from schemas.errors import ContractError

if TYPE_CHECKING:
    from collections.abc import Mapping

    from schemas._vocabulary import Vocabulary

#: Rig values: flat JSON scalars.
RigValue = str | int | float | bool

_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}")
_INT = re.compile(r"0|[1-9][0-9]*")
MAX_TRIAL = 999_999
#: The most cells a skin may have: a cell's samples are rows of the recording's arrays, and a
#: live layout's per-cell fields are built when the configuration is read (65,535 cells took
#: 5.6 s and 230 MB to read; a mistyped 100,000,000 would never finish).
MAX_CELLS = 65_535
MAX_SEED = 2**63 - 1
_KEYS = (
    "object_id",
    "object_name",
    "object_description",
    "action_id",
    "action_kind",
    "action_parameters",
    "trial",
    "rig",
    "seed",
    "source",
    "software_version",
    "schema_version",
)
_OPTIONAL_V1 = ("object_description", "source")


@dataclass(frozen=True, slots=True)
class RecordingMetadata:
    """What one recording is: the content of its metadata record.

    Attributes:
        object_id: Id of the explored object (a directory name of the dataset).
        object_name: Human-readable object name.
        object_description: One line about the object ("" if none).
        action_id: Id of the action (the thesis's P1..C1 or a lab's own).
        action_kind: Kind of the action, one of the contract's kinds.
        action_parameters: Parameters of the action, SI units; ``duration_s`` > 0 always.
        trial: Trial number of this (object, action), 1..999999.
        rig: The rig's name and configuration, flat JSON scalars.
        seed: Seed of the rig (0 for real rigs and imports), 0..2**63-1.
        source: ``recorder``, ``import`` or ``salvage`` (what the file promises).
        software_version: Version of the software that wrote the file.
        schema_version: Schema version of the file.
    """

    object_id: str
    object_name: str
    action_id: str
    action_kind: str
    action_parameters: Mapping[str, float]
    trial: int
    rig: Mapping[str, RigValue]
    seed: int
    source: str
    software_version: str
    schema_version: int
    object_description: str = ""

    def encode(self) -> dict[str, str]:
        """Return the record's key-value pairs (JSON with sorted keys for structured values)."""
        return {
            "object_id": self.object_id,
            "object_name": self.object_name,
            "object_description": self.object_description,
            "action_id": self.action_id,
            "action_kind": self.action_kind,
            "action_parameters": json.dumps(dict(self.action_parameters), sort_keys=True),
            "trial": str(self.trial),
            "rig": json.dumps(dict(self.rig), sort_keys=True),
            "seed": str(self.seed),
            "source": self.source,
            "software_version": self.software_version,
            "schema_version": str(self.schema_version),
        }


def check_id(what: str, value: object) -> str:
    """Return ``value`` if it is a valid object or action id.

    Raises:
        ContractError: Not a string of letters, digits and ``_.+-`` (1..64, no leading mark).
    """
    if not isinstance(value, str) or not _ID.fullmatch(value):
        msg = (
            f"{what} {value!r} is not an id: use 1-64 letters, digits and _ . + - "
            "(it names a directory of the dataset)"
        )
        raise ContractError(msg)
    return value


def _int(key: str, text: str, low: int, high: int) -> int:
    if not _INT.fullmatch(text) or not low <= int(text) <= high:
        msg = f"{key} {text!r} is not an integer in {low}..{high}"
        raise ContractError(msg)
    return int(text)


def _json_object(key: str, text: str) -> dict[str, Any]:
    try:
        value = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as err:
        msg = f"{key} is not JSON ({err})"
        raise ContractError(msg) from err
    if not isinstance(value, dict):
        msg = f"{key} {text[:60]!r} is not a JSON object"
        raise ContractError(msg)
    return value


def _number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)


def check_parameters(kind: str, parameters: Mapping[str, object], needed: tuple[str, ...]) -> None:
    """Check an action's parameters: finite numbers, the kind's needed ones present.

    Raises:
        ContractError: A parameter is missing, not a finite number, or duration_s <= 0.
    """
    for key, value in parameters.items():
        if not _number(value) or not math.isfinite(float(value)):  # type: ignore[arg-type]
            msg = f"action parameter {key}={value!r} is not a finite number"
            raise ContractError(msg)
    if missing := [key for key in needed if key not in parameters]:
        msg = f"a {kind!r} action needs the parameters {', '.join(missing)}; state them"
        raise ContractError(msg)
    duration = parameters.get("duration_s")
    if duration is not None and not float(duration) > 0:  # type: ignore[arg-type]
        msg = f"action parameter duration_s={duration!r} must be > 0"
        raise ContractError(msg)


def _parameters(text: str, kind: str, vocabulary: Vocabulary) -> Mapping[str, float]:
    raw = _json_object("action_parameters", text)
    check_parameters(kind, raw, vocabulary.kind(kind).parameters)
    return MappingProxyType({str(k): float(v) for k, v in sorted(raw.items())})


def check_rig(rig: Mapping[str, object]) -> Mapping[str, RigValue]:
    """Return a rig description if every value is a flat JSON scalar (finite numbers).

    Raises:
        ContractError: A value is nested, null or not finite.
    """
    for key, value in rig.items():
        if not isinstance(value, str | int | float | bool):
            msg = f"rig {key}={value!r} is not a string, number or boolean (no nesting)"
            raise ContractError(msg)
        if isinstance(value, float) and not math.isfinite(value):
            msg = f"rig {key}={value!r} is not a finite number; give a finite value"
            raise ContractError(msg)
        if isinstance(value, int) and not isinstance(value, bool) and abs(value) > MAX_SEED:
            msg = f"rig {key}={value} is out of the 64-bit range"
            raise ContractError(msg)
    return MappingProxyType({str(k): rig[k] for k in sorted(rig)})  # type: ignore[misc]


def _version(record: Mapping[str, str], vocabulary: Vocabulary) -> int:
    text = record.get("schema_version")
    if text is None:
        msg = "the metadata record lacks schema_version"
        raise ContractError(msg)
    version = _int("schema_version", text, 0, 2**31)
    if version > vocabulary.schema_version:
        msg = (
            f"schema version {version} is newer than this software reads "
            f"({vocabulary.schema_version}); upgrade atikt ('pip install -U atikt')"
        )
        raise ContractError(msg)
    if version != vocabulary.schema_version and version not in vocabulary.legacy:
        msg = f"schema version {version} is not supported; read it with the release that wrote it"
        raise ContractError(msg)
    return version


def _legacy_keys(record: dict[str, str], version: int, vocabulary: Vocabulary) -> None:
    """Drop a schema-1 record's retired keys after checking them (in place)."""
    for key in vocabulary.legacy[version].dropped_metadata:
        if key in record:
            value = record.pop(key)
            if value not in {"true", "false"}:
                msg = f"{key} {value!r} is not a JSON boolean (true or false)"
                raise ContractError(msg)
    record.setdefault("object_description", "")
    rig = _json_object("rig", record.get("rig", "{}"))
    record.setdefault("source", "import" if rig.get("kind") == "imported" else "recorder")


def _text(key: str, value: str, *, empty: bool) -> str:
    if (not value and not empty) or any(ord(c) < 32 for c in value) or len(value) > 1000:  # noqa: PLR2004
        msg = f"{key} {value[:60]!r} must be one line of at most 1000 characters"
        raise ContractError(msg)
    return value


def parse_metadata(
    record: Mapping[str, str], vocabulary: Vocabulary | None = None
) -> RecordingMetadata:
    """Parse and check a metadata record (every field's type and range; no unknown keys).

    Args:
        record: The MCAP metadata record's key-value pairs.
        vocabulary: The contract (kinds, sources, schema versions); default: the packaged one.

    Returns:
        The typed, immutable metadata.

    Raises:
        ContractError: The first violation, naming the key, the value and the rule.
    """
    if vocabulary is None:
        from schemas._typestore import VOCABULARY  # noqa: PLC0415 (loaded once, at import)

        vocabulary = VOCABULARY
    version = _version(record, vocabulary)
    values = dict(record)
    if version != vocabulary.schema_version:
        _legacy_keys(values, version, vocabulary)
    if unknown := sorted(set(values) - set(_KEYS)):
        msg = f"the metadata record has unknown keys {', '.join(unknown)} (schema {version})"
        raise ContractError(msg)
    if missing := [key for key in _KEYS if key not in values]:
        msg = f"the metadata record lacks {', '.join(missing)}"
        raise ContractError(msg)
    kind = vocabulary.kind(values["action_kind"]).name
    if values["source"] not in vocabulary.sources:
        msg = f"source {values['source']!r} is not one of {', '.join(vocabulary.sources)}"
        raise ContractError(msg)
    return RecordingMetadata(
        object_id=check_id("object_id", values["object_id"]),
        object_name=_text("object_name", values["object_name"], empty=False),
        object_description=_text("object_description", values["object_description"], empty=True),
        action_id=check_id("action_id", values["action_id"]),
        action_kind=kind,
        action_parameters=_parameters(values["action_parameters"], kind, vocabulary),
        trial=_int("trial", values["trial"], 1, MAX_TRIAL),
        rig=check_rig(_json_object("rig", values["rig"])),
        seed=_int("seed", values["seed"], 0, MAX_SEED),
        source=values["source"],
        software_version=_text("software_version", values["software_version"], empty=False),
        schema_version=version,
    )


@functools.cache  # the distribution's metadata is read from disk: once per process
def software_version() -> str:
    """Return the installed version of the project's distribution ("unknown" if not installed)."""
    try:
        return importlib_metadata.version("atikt")
    except importlib_metadata.PackageNotFoundError:
        return "unknown"
