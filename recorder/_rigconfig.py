"""Rigs plug in by name with a typed configuration (a TOML file and/or command-line options).

A rig is registered with a *builder* ``builder(seed, options) -> Rig``; ``options`` are flat
values (host, device, calibration file, the simulator's settings...) that the builder checks
and turns into its own typed configuration, refusing unknown or malformed ones in one line.
A configuration file names the rig and its options::

    rig = "sim"            # a registered rig
    [options]
    room_c = 21.0          # the simulated rig takes the fields of SimConfig
    location_spread_m = 0.005

``--rig-option key=value`` on the command line overrides the file (values in TOML syntax:
``room_c=21.0``, ``host="192.168.1.10"``; a bare word is a string).
"""

from __future__ import annotations

import dataclasses
import functools
import tomllib
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, TypeAlias

from recorder.errors import RecorderError
from schemas import ContractError, RigValue, check_rig, load_toml, loads_toml

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence
    from pathlib import Path

    from recorder._rig import Rig
    from recorder._sim import SimulatedRig

#: Builds a rig (not yet connected) from a seed and its options.
RigBuilder: TypeAlias = "Callable[[int, Mapping[str, RigValue]], Rig]"
#: Makes a rig (not yet connected) from a seed: a builder with its options bound.
RigFactory: TypeAlias = "Callable[[int], Rig]"


@dataclass(frozen=True, slots=True)
class RigConfig:
    """Which rig records, and how it is set up.

    Attributes:
        name: A registered rig (``sim`` is the embedded simulated rig).
        options: The rig's settings, flat values; each rig checks its own.
    """

    name: str = "sim"
    options: Mapping[str, RigValue] = field(default_factory=lambda: MappingProxyType({}))


def sim_rig(seed: int, options: Mapping[str, RigValue]) -> SimulatedRig:
    """Build the simulated rig; ``options`` are fields of :class:`recorder.SimConfig`.

    Raises:
        RecorderError: An unknown option or a value of the wrong type.
    """
    from recorder._sim import SimConfig, SimulatedRig  # noqa: PLC0415 (imports never load it)

    known = {f.name: f for f in dataclasses.fields(SimConfig)}
    values: dict[str, float] = {}
    for key, value in options.items():
        if key not in known:
            msg = f"rig option {key!r}: the sim rig takes {', '.join(known)}"
            raise RecorderError(msg)
        if isinstance(value, bool) or not isinstance(value, int | float):
            msg = f"rig option {key}={value!r}: give a number (e.g. {key}=1.0)"
            raise RecorderError(msg)
        values[key] = float(value)
    return SimulatedRig(seed, SimConfig(**values))


_BUILDERS: dict[str, RigBuilder] = {"sim": sim_rig}


def register_rig(name: str, builder: RigBuilder) -> None:
    """Make a rig available by name (``--rig NAME``); ``builder(seed, options)`` makes one."""
    _BUILDERS[name] = builder


def rig_names() -> tuple[str, ...]:
    """Return the names of the registered rigs."""
    return tuple(_BUILDERS)


def _build(name: str, options: Mapping[str, RigValue], seed: int) -> Rig:
    return _BUILDERS[name](seed, options)


def rig_factory(config: RigConfig | str) -> RigFactory:
    """Return the factory of a configured rig: ``factory(seed)`` makes a new rig.

    The factory is a plain partial of module-level functions, so it pickles into workers.

    Raises:
        RecorderError: No rig of that name.
    """
    config = RigConfig(config) if isinstance(config, str) else config
    if config.name not in _BUILDERS:
        known = ", ".join(_BUILDERS) or "none"
        msg = f"--rig {config.name}: unknown rig; registered rigs: {known}"
        raise RecorderError(msg)
    return functools.partial(_build, config.name, dict(config.options))


def _option(text: str) -> tuple[str, RigValue]:
    """Parse ``key=value`` (a TOML value, or a bare word as a string).

    Raises:
        RecorderError: No ``=`` or an empty key.
    """
    key, sep, raw = text.partition("=")
    if not sep or not key.strip():
        msg = f"--rig-option {text!r}: give key=value (e.g. room_c=21.0)"
        raise RecorderError(msg)
    try:
        value: Any = loads_toml(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return key.strip(), value


def load_rig_config(
    path: Path | None = None, name: str | None = None, options: Sequence[str] = ()
) -> RigConfig:
    """Return the rig configuration: the file's, then ``name`` and ``options`` over it.

    Args:
        path: A TOML file with ``rig = NAME`` and an ``[options]`` table (optional).
        name: ``--rig``; overrides the file's rig.
        options: ``--rig-option key=value`` entries; override the file's options.

    Raises:
        RecorderError: The file is unreadable or malformed, or an option is not flat.
    """
    table: dict[str, Any] = {}
    if path is not None:
        try:
            table = load_toml(path)
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
            msg = f"{path}: cannot read the rig configuration ({err}); fix the file or the path"
            raise RecorderError(msg) from err
        if unknown := sorted(set(table) - {"rig", "options"}):
            msg = f"{path}: unknown keys {unknown}; a rig configuration has rig and [options]"
            raise RecorderError(msg)
    chosen = name or table.get("rig", "sim")
    merged = dict(table.get("options", {})) | dict(_option(text) for text in options)
    try:
        checked = check_rig(merged)
    except ContractError as err:
        msg = f"{path or '--rig-option'}: {err}; rig options are flat values"
        raise RecorderError(msg) from err
    if not isinstance(chosen, str):
        msg = f'{path}: rig = {chosen!r} must name a rig (e.g. rig = "sim")'
        raise RecorderError(msg)
    return RigConfig(chosen, checked)
