"""The contract's vocabulary as typed data, loaded once from ``schemas/contract.toml``.

Modalities, robot and event channels, phases, sources and action kinds are data: this module
turns the TOML file into frozen dataclasses and mappings, and nothing else in the project lists
them. The loader checks the file's own consistency (every kind needs and uses known
modalities and features), so a mistake in an edit of the contract fails at import with one
line naming the key.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from importlib import resources
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from schemas._toml import loads_toml
from schemas.errors import ContractError

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

CONTRACT_FILE = "contract.toml"


@dataclass(frozen=True, slots=True)
class ModalitySpec:
    """One skin modality of the contract.

    Attributes:
        name: Modality name, e.g. ``"force"``.
        msgtype: Full ROS 2 type of its blocks, e.g. ``tactile_msgs/msg/SkinForce``.
        topic: Topic of its channel.
        units: Units of the values.
        value: What one value of a cell is (``"sensor"`` or ``"axis"``).
        values: Names of the values of the thesis's skin (the default width).
        rate_hz: Default sample rate (the simulated skin's).
        block_samples: Samples per message written by the simulated rig.
        feature: Name of the atikt feature block computed from it ("" for none).
        property: The object property it measures, as objects name what they share with a
            related object ("" for none).
        description: One line for people.
        noise: Declared noise of one sample (standard deviation, or the resolution where
            that is all a datasheet gives), in ``units``; 0: not declared. The fusion study's
            prior on the modality weights compares each feature's spread with it.
        controlled_by: The action parameter that sets this modality's values when an action
            states it (``force_n``: a force-controlled action), so that its feature then
            measures the rig's controller, not the object; "" for none.
    """

    name: str
    msgtype: str
    topic: str
    units: str
    value: str
    values: tuple[str, ...]
    rate_hz: float
    block_samples: int
    feature: str
    property: str
    description: str
    noise: float = 0.0
    controlled_by: str = ""

    def value_names(self, width: int) -> tuple[str, ...]:
        """Return names of ``width`` values per cell: the default names, or numbered ones."""
        if width == len(self.values):
            return self.values
        return tuple(f"{self.value}{i}" for i in range(width))


@dataclass(frozen=True, slots=True)
class ChannelSpec:
    """A robot or annotation channel of the contract.

    Attributes:
        name: Name in the contract (``joint_states``, ``tcp_pose``, ``events``).
        msgtype: Full ROS 2 type.
        topic: Topic name.
        units: Units of the payload.
        frame: Frame id written into the headers.
        rate_hz: Nominal rate (0 for events).
        description: One line for people.
    """

    name: str
    msgtype: str
    topic: str
    units: str
    frame: str
    rate_hz: float
    description: str


@dataclass(frozen=True, slots=True)
class KindSpec:
    """An action kind.

    Attributes:
        name: Kind name, e.g. ``"press"``.
        needs: Skin modalities a recording of this kind must hold.
        features: Feature blocks the thesis assigns to the kind, in order.
        parameters: Action parameters every action of the kind must state.
        description: One line for people.
    """

    name: str
    needs: tuple[str, ...]
    features: tuple[str, ...]
    parameters: tuple[str, ...]
    description: str

    def missing(self, held: Iterable[str]) -> tuple[str, ...]:
        """Return the modalities this kind needs that ``held`` lacks, in the kind's order.

        The one rule for "can this skin record this action": the reader applies it to a
        recording's channels, the recorder to a rig's skin before anything moves.
        """
        have = set(held)
        return tuple(modality for modality in self.needs if modality not in have)


@dataclass(frozen=True, slots=True)
class SourceSpec:
    """What a source of recordings promises.

    Attributes:
        name: ``recorder``, ``import`` or ``salvage``.
        phases: Phases every recording of this source holds.
        description: One line for people.
    """

    name: str
    phases: tuple[str, ...]
    description: str


@dataclass(frozen=True, slots=True)
class LegacySpec:
    """How a recording of an earlier schema version maps to the current one.

    Attributes:
        version: The earlier schema version.
        topics: Earlier topic -> current topic.
        dropped_metadata: Metadata keys of that version that are read and ignored.
    """

    version: int
    topics: Mapping[str, str]
    dropped_metadata: tuple[str, ...]


@dataclass(frozen=True, slots=True)
class Vocabulary:
    """The whole vocabulary of the contract (see ``schemas/contract.toml``)."""

    schema_version: int
    message_version: int
    metadata_record: str
    modalities: Mapping[str, ModalitySpec]
    robot: Mapping[str, ChannelSpec]
    events: ChannelSpec
    phases: tuple[str, ...]
    sources: Mapping[str, SourceSpec]
    kinds: Mapping[str, KindSpec]
    legacy: Mapping[int, LegacySpec]

    @property
    def properties(self) -> tuple[str, ...]:
        """Return the object properties the modalities measure, in modality order."""
        return tuple(m.property for m in self.modalities.values() if m.property)

    @property
    def features(self) -> tuple[str, ...]:
        """Return the feature blocks of all modalities, in modality order."""
        return tuple(m.feature for m in self.modalities.values() if m.feature)

    def modality_of_feature(self, feature: str) -> ModalitySpec:
        """Return the modality a feature block is computed from.

        Raises:
            ContractError: No modality feeds that feature.
        """
        for modality in self.modalities.values():
            if modality.feature == feature:
                return modality
        msg = f"no modality feeds the feature {feature!r}; known: {', '.join(self.features)}"
        raise ContractError(msg)

    def kind(self, name: str) -> KindSpec:
        """Return an action kind by name.

        Raises:
            ContractError: Unknown kind; the message lists the known ones.
        """
        try:
            return self.kinds[name]
        except KeyError:
            msg = f"unknown action kind {name!r}; use one of {', '.join(self.kinds)}"
            raise ContractError(msg) from None


def _table(data: Mapping[str, Any], key: str) -> Mapping[str, Any]:
    value = data.get(key)
    if not isinstance(value, dict):
        msg = f"{CONTRACT_FILE}: [{key}] is missing or not a table"
        raise ContractError(msg)
    return value


def _modality(name: str, row: Mapping[str, Any], package: str) -> ModalitySpec:
    return ModalitySpec(
        name=name,
        msgtype=f"{package}/msg/{row['msgtype']}",
        topic=str(row["topic"]),
        units=str(row["units"]),
        value=str(row["value"]),
        values=tuple(str(v) for v in row["values"]),
        rate_hz=float(row["rate_hz"]),
        block_samples=int(row["block_samples"]),
        feature=str(row["feature"]),
        property=str(row.get("property", "")),
        description=str(row["description"]),
        noise=float(row.get("noise", 0.0)),
        controlled_by=str(row.get("controlled_by", "")),
    )


def _channel(name: str, row: Mapping[str, Any], package: str) -> ChannelSpec:
    msgtype = str(row["msgtype"])
    return ChannelSpec(
        name=name,
        msgtype=msgtype if "/" in msgtype else f"{package}/msg/{msgtype}",
        topic=str(row["topic"]),
        units=str(row["units"]),
        frame=str(row["frame"]),
        rate_hz=float(row.get("rate_hz", 0.0)),
        description=str(row["description"]),
    )


def _kind(name: str, row: Mapping[str, Any]) -> KindSpec:
    return KindSpec(
        name=name,
        needs=tuple(row["needs"]),
        features=tuple(row["features"]),
        parameters=tuple(row["parameters"]),
        description=str(row["description"]),
    )


def _check(vocabulary: Vocabulary) -> None:
    """Check the vocabulary's own consistency.

    Raises:
        ContractError: A kind names an unknown modality or feature, or a source a phase.
    """
    for kind in vocabulary.kinds.values():
        for modality in kind.needs:
            if modality not in vocabulary.modalities:
                msg = f"{CONTRACT_FILE}: [kinds.{kind.name}] needs unknown modality {modality!r}"
                raise ContractError(msg)
        for feature in kind.features:
            if feature not in vocabulary.features:
                msg = f"{CONTRACT_FILE}: [kinds.{kind.name}] uses unknown feature {feature!r}"
                raise ContractError(msg)
    for source in vocabulary.sources.values():
        if unknown := set(source.phases) - set(vocabulary.phases):
            msg = f"{CONTRACT_FILE}: [sources.{source.name}] names unknown phases {unknown}"
            raise ContractError(msg)


def parse_vocabulary(text: str, package: str) -> Vocabulary:
    """Parse the contract's TOML text into a :class:`Vocabulary`.

    Raises:
        ContractError: The text is not a consistent contract.
    """
    try:
        data = loads_toml(text)
        contract = _table(data, "contract")
        vocabulary = Vocabulary(
            schema_version=int(contract["schema_version"]),
            message_version=int(contract["message_version"]),
            metadata_record=str(contract["metadata_record"]),
            modalities=MappingProxyType(
                {k: _modality(k, v, package) for k, v in _table(data, "modalities").items()}
            ),
            robot=MappingProxyType(
                {k: _channel(k, v, package) for k, v in _table(data, "robot").items()}
            ),
            events=_channel("events", _table(data, "events"), package),
            phases=tuple(_table(data, "phases")["order"]),
            sources=MappingProxyType(
                {
                    k: SourceSpec(k, tuple(v["phases"]), str(v["description"]))
                    for k, v in _table(data, "sources").items()
                }
            ),
            kinds=MappingProxyType({k: _kind(k, v) for k, v in _table(data, "kinds").items()}),
            legacy=MappingProxyType(
                {
                    int(k): LegacySpec(
                        int(k),
                        MappingProxyType(dict(v["topics"])),
                        tuple(v["dropped_metadata"]),
                    )
                    for k, v in _table(data, "legacy").items()
                }
            ),
        )
    except (tomllib.TOMLDecodeError, KeyError, TypeError, ValueError) as err:
        msg = f"{CONTRACT_FILE}: not a valid contract ({err!r}); restore it from the release"
        raise ContractError(msg) from err
    _check(vocabulary)
    return vocabulary


def load_vocabulary(package: str) -> Vocabulary:
    """Load the packaged contract (``schemas/contract.toml``)."""
    text = resources.files(__package__).joinpath(CONTRACT_FILE).read_text("utf-8")
    return parse_vocabulary(text, package)
