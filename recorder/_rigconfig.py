"""Rigs are plug-ins, found by name and made from a typed configuration.

A rig plug-in (:class:`RigPlugin`) builds a rig, not yet connected, from a seed and the whole
rig configuration (:class:`RigConfig`), and says whether the rig is exclusive hardware (one
action at a time, in the main process, never in a pool of workers). A rig is found by name:

1. the project's own rigs: ``sim`` (the simulator), ``ur`` (a UR arm, ``recorder.ur``) and
   ``sim-ur10`` (the simulated UR10 under the action runner, ``recorder.virtuallab``);
2. installed packages' entry points in the group ``atikt.rigs``; an entry point names a
   :class:`RigPlugin` or a bare builder ``builder(seed, options) -> Rig``::

       [project.entry-points."atikt.rigs"]
       lab = "lab_rigs:PLUGIN"

3. rigs registered at run time with :func:`register_rig`.

A configuration file names the rig, its flat options, and any tables the rig's builder reads
(and refuses when it does not know them)::

    rig = "sim"            # a rig found by name
    [options]
    room_c = 21.0          # the simulated rig takes the fields of SimConfig
    location_spread_m = 0.005
    cells = 3              # the skin's shape: a 3-cell fingertip (default 7, layout "hex")

``--rig-option key=value`` on the command line overrides the file (values in TOML syntax:
``room_c=21.0``, ``host="192.168.1.10"``; a bare word is a string).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import importlib.metadata
import tomllib
from collections.abc import Callable, Collection, Iterator, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeAlias, TypeGuard

from recorder.errors import RecorderError, RigError
from schemas import ContractError, RigValue, check_rig, load_toml, loads_toml

if TYPE_CHECKING:
    from collections.abc import Sequence
    from pathlib import Path

    from recorder._rig import Rig
    from recorder._sim import SimulatedRig

#: Entry point group of installed rig plug-ins.
ENTRY_POINT_GROUP = "atikt.rigs"
#: Builds a rig (not yet connected) from a seed and its flat options (a bare builder).
RigBuilder: TypeAlias = "Callable[[int, Mapping[str, RigValue]], Rig]"
#: Makes a rig (not yet connected) from a seed: a builder with its configuration bound.
RigFactory: TypeAlias = "Callable[[int], Rig]"


class FrozenTable(Mapping[str, Any]):
    """A read-only mapping that pickles (``types.MappingProxyType`` does not).

    Written by hand: the standard library has no frozen dict, and rig configurations travel
    to worker processes.
    """

    __slots__ = ("_data",)

    def __init__(self, data: Mapping[str, Any] | None = None) -> None:
        """Copy ``data`` (nested tables and arrays are frozen too)."""
        self._data = {str(key): _freeze(value) for key, value in (data or {}).items()}

    def __getitem__(self, key: str) -> Any:  # noqa: ANN401 (values of a TOML table)
        """Return the value of ``key``."""
        return self._data[key]

    def __iter__(self) -> Iterator[str]:
        """Iterate over the keys in file order."""
        return iter(self._data)

    def __len__(self) -> int:
        """Return the number of keys."""
        return len(self._data)

    def __repr__(self) -> str:
        """Return the table as a dict literal."""
        return repr(self._data)

    def __reduce__(self) -> tuple[type[FrozenTable], tuple[dict[str, Any]]]:
        """Pickle as the class and its dict."""
        return (FrozenTable, (self._data,))


def _freeze(value: object) -> object:
    """Return ``value`` with every table a :class:`FrozenTable` and every array a tuple."""
    if isinstance(value, Mapping):
        return FrozenTable(value)
    if isinstance(value, list | tuple):
        return tuple(_freeze(item) for item in value)
    return value


def thaw(value: object) -> Any:  # noqa: ANN401 (a TOML value)
    """Return a configuration value as tomllib gives it: plain dicts and lists (a copy).

    A rig's builder hands its tables to code that checks TOML as parsed (``dict``, ``list``).
    """
    if isinstance(value, Mapping):
        return {str(key): thaw(item) for key, item in value.items()}
    if isinstance(value, list | tuple):
        return [thaw(item) for item in value]
    return value


@dataclass(frozen=True, slots=True)
class RigConfig:
    """Which rig records, and how it is set up.

    Attributes:
        name: The rig's name (``sim`` is the embedded simulated rig).
        options: The rig's flat settings: the file's ``[options]``, then ``--rig-option``s;
            each rig checks its own, and they go into the recordings' metadata.
        sections: Every other table of the configuration file (``[limits]``, ``[arm]``,
            ``[objects.<id>]``, ...), as parsed; the rig's builder refuses tables it does not
            know.
        source: The configuration file, for error messages (empty: none).
    """

    name: str = "sim"
    options: Mapping[str, RigValue] = field(default_factory=FrozenTable)
    sections: Mapping[str, Any] = field(default_factory=FrozenTable)
    source: str = ""

    def __post_init__(self) -> None:
        """Freeze the tables (a plain dict given by a caller is copied)."""
        object.__setattr__(self, "options", FrozenTable(self.options))
        object.__setattr__(self, "sections", FrozenTable(self.sections))


@dataclass(frozen=True, slots=True)
class RigPlugin:
    """A kind of rig: how to build one, and whether it is exclusive hardware.

    Attributes:
        build: ``build(seed, config)`` returns a rig, not yet connected; it checks
            ``config.options`` and ``config.sections`` and refuses unknown ones in one line.
            A module-level function, so that worker processes can be sent it.
        exclusive: The rig is one piece of hardware: one action at a time, in the main
            process, never in a pool of workers.
        description: One line for listings.
    """

    build: Callable[[int, RigConfig], Rig]
    exclusive: bool = False
    description: str = ""


def refuse_sections(config: RigConfig, known: Sequence[str] = ()) -> None:
    """Refuse tables of the configuration that the rig does not read.

    Raises:
        RecorderError: A table other than ``known``; the message names it and the file.
    """
    if unknown := [name for name in config.sections if name not in known]:
        takes = ", ".join(f"[{name}]" for name in ("options", *known))
        msg = (
            f"{config.source or 'rig configuration'}: unknown tables "
            f"{', '.join(f'[{name}]' for name in unknown)}; rig {config.name!r} takes {takes}"
        )
        raise RecorderError(msg)


def sim_rig(seed: int, options: Mapping[str, RigValue]) -> SimulatedRig:
    """Build the simulated rig; ``options`` are fields of :class:`recorder.SimConfig`.

    Raises:
        RecorderError: An unknown option or a value of the wrong type.
    """
    from recorder._sim import SimConfig, SimulatedRig  # noqa: PLC0415 (imports never load it)

    known = {f.name: f for f in dataclasses.fields(SimConfig)}
    values: dict[str, float | int | str] = {}
    for key, value in options.items():
        if key not in known:
            msg = f"rig option {key!r}: the sim rig takes {', '.join(known)}"
            raise RecorderError(msg)
        values[key] = _sim_value(key, value, str(known[key].type))
    return SimulatedRig(seed, SimConfig(**values))  # type: ignore[arg-type]


def _sim_value(key: str, value: RigValue, kind: str) -> float | int | str:
    """Return one sim option as its field's type (``kind``: ``float``, ``int`` or ``str``).

    Raises:
        RecorderError: The value has the wrong type; one line with an example.
    """
    if kind == "str":
        if not isinstance(value, str):
            msg = f"rig option {key}={value!r}: give a word (e.g. {key}=hex)"
            raise RecorderError(msg)
        return value
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            msg = f"rig option {key}={value!r}: give a whole number (e.g. {key}=3)"
            raise RecorderError(msg)
        return value
    if isinstance(value, bool) or not isinstance(value, int | float):
        msg = f"rig option {key}={value!r}: give a number (e.g. {key}=1.0)"
        raise RecorderError(msg)
    return float(value)


def _build_sim(seed: int, config: RigConfig) -> SimulatedRig:
    """Build the simulated rig from its configuration (options only, no tables)."""
    refuse_sections(config)
    return sim_rig(seed, config.options)


#: The simulated rig: a physics-based UR10 with a skin, 7 cells unless ``cells`` says otherwise
#: (many may run in parallel).
SIM_RIG = RigPlugin(_build_sim, description="physics-based simulated UR10 with a 7-cell skin")


def _with_options(builder: RigBuilder, seed: int, config: RigConfig) -> Rig:
    """Call a bare builder ``builder(seed, options)``; it reads no tables.

    Raises:
        RecorderError: The configuration has tables other than ``[options]``.
    """
    refuse_sections(config)
    return builder(seed, config.options)


def as_plugin(value: object) -> RigPlugin | None:
    """Return ``value`` as a plug-in: itself, or a bare builder wrapped (not exclusive)."""
    if isinstance(value, RigPlugin):
        return value
    if callable(value):
        return RigPlugin(functools.partial(_with_options, value))
    return None


#: The project's own rigs: a plug-in, or where to import it from (loaded on first use).
BUILTIN_RIGS: Mapping[str, RigPlugin | str] = FrozenTable(
    {"sim": SIM_RIG, "ur": "recorder.ur:PLUGIN", "sim-ur10": "recorder.virtuallab:SIM_UR10"}
)
#: Rigs registered at run time (:func:`register_rig`): a plug-in or a bare builder.
_BUILDERS: dict[str, RigPlugin | RigBuilder] = {}


def _entry_points() -> dict[str, importlib.metadata.EntryPoint]:
    """Return the installed ``atikt.rigs`` entry points by name (the first of each name)."""
    found: dict[str, importlib.metadata.EntryPoint] = {}
    for entry in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP):
        found.setdefault(entry.name, entry)
    return found


def _origin(entry: importlib.metadata.EntryPoint) -> str:
    """Return where an entry point comes from, for messages."""
    dist = entry.dist.name if entry.dist is not None else "an installed package"
    return f"entry point {entry.name} = {entry.value!r} of {dist} in group {ENTRY_POINT_GROUP}"


def _load(name: str, entry: importlib.metadata.EntryPoint, origin: str, fix: str) -> RigPlugin:
    """Import a plug-in named by ``module:attribute``.

    Raises:
        RecorderError: The import failed or the object is no plug-in; one line with the fix.
    """
    try:
        value = entry.load()
    except Exception as err:  # a broken plug-in may raise anything on import
        msg = f"rig {name!r} could not be loaded ({type(err).__name__}: {err}; {origin}); {fix}"
        raise RecorderError(msg) from err
    plugin = as_plugin(value)
    if plugin is None:
        msg = (
            f"rig {name!r} could not be loaded ({origin} is a {type(value).__name__}, not a "
            f"recorder.RigPlugin or a builder(seed, options)); {fix}"
        )
        raise RecorderError(msg)
    return plugin


def find_rig(name: str) -> RigPlugin:
    """Return the plug-in of rig ``name``: the project's, an installed one, or a registered one.

    Raises:
        RecorderError: No rig of that name, or its plug-in cannot be loaded.
    """
    if name in BUILTIN_RIGS:
        builtin = BUILTIN_RIGS[name]
        if isinstance(builtin, RigPlugin):
            return builtin
        entry = importlib.metadata.EntryPoint(name, builtin, ENTRY_POINT_GROUP)
        fix = "install the project with this rig's dependencies, or choose another --rig"
        return _load(name, entry, f"the project's rig {builtin}", fix)
    if (installed := _entry_points().get(name)) is not None:
        fix = "reinstall or fix the package that provides it, or choose another --rig"
        return _load(name, installed, _origin(installed), fix)
    if name in _BUILDERS:
        plugin = as_plugin(_BUILDERS[name])
        if plugin is not None:
            return plugin
    msg = (
        f"--rig {name}: unknown rig; known rigs: {', '.join(rig_names())}; install the "
        f"package that provides it (entry point group {ENTRY_POINT_GROUP}) or register it "
        "with recorder.register_rig"
    )
    raise RecorderError(msg)


def register_rig(name: str, builder: RigBuilder | RigPlugin) -> None:
    """Make a rig available by name (``--rig NAME``), in this process and its workers.

    Args:
        name: The rig's name; not one of the project's rigs or of an installed plug-in.
        builder: A :class:`RigPlugin`, or a bare builder ``builder(seed, options)`` (not
            exclusive). It is sent to worker processes with the work, so define it at the
            top level of an importable module.

    Raises:
        RecorderError: The name is taken, or ``builder`` is neither.
    """
    if name in BUILTIN_RIGS or name in _entry_points():
        msg = f"register_rig({name!r}): the name is taken by a rig found first; choose another"
        raise RecorderError(msg)
    if as_plugin(builder) is None:
        msg = f"register_rig({name!r}): give a recorder.RigPlugin or a builder(seed, options)"
        raise RecorderError(msg)
    _BUILDERS[name] = builder


def rig_names() -> tuple[str, ...]:
    """Return the names of every rig: the project's, installed ones, registered ones."""
    names = [*BUILTIN_RIGS, *sorted(_entry_points()), *_BUILDERS]
    return tuple(dict.fromkeys(names))


@dataclass(frozen=True, slots=True)
class ConfiguredRig:
    """A rig factory: a plug-in and its configuration; ``factory(seed)`` makes a new rig.

    It carries the plug-in itself (its builder pickles by reference), so worker processes
    make rigs without looking the name up again (where a run-time registration is unknown).

    Attributes:
        config: The rig's configuration.
        plugin: The rig's plug-in.
    """

    config: RigConfig
    plugin: RigPlugin

    @property
    def exclusive(self) -> bool:
        """Return whether the rig is exclusive hardware (never in a pool of workers)."""
        return self.plugin.exclusive

    def __call__(self, seed: int) -> Rig:
        """Build a new rig, not yet connected."""
        return self.plugin.build(seed, self.config)


def check_object_poses(config: RigConfig, catalog: Collection[str]) -> None:
    """Refuse an ``[objects.<id>]`` table whose id is no object of the command's catalog.

    A misspelled id (``[objects.foam_blok]``) is otherwise taken silently: the pose goes
    unused and the real object is then "placed by hand", or refused by ``--yes``, with
    nothing pointing at the typo.

    Args:
        config: The rig configuration (its ``objects`` section, and its file for messages).
        catalog: The object ids of the catalog the command was given.

    Raises:
        RigError: One line naming the file, the table, the closest known id and the ids.
    """
    tables = config.sections.get("objects")
    if not isinstance(tables, Mapping):
        return  # absent, or not a table: the rig's own reading of it says what is wrong
    where = config.source or "<rig options>"
    for object_id in tables:
        if object_id in catalog:
            continue
        close = difflib.get_close_matches(str(object_id), list(catalog), n=1)
        guess = f"; did you mean {close[0]}?" if close else ""
        msg = (
            f"{where}: [objects.{object_id}] names no object of the object catalog{guess} "
            f"(known: {', '.join(catalog)}); fix the id, or remove the table"
        )
        raise RigError(msg)


def rig_factory(config: RigConfig | str) -> ConfiguredRig:
    """Return the factory of a configured rig: ``factory(seed)`` makes a new rig.

    Raises:
        RecorderError: No rig of that name, or its plug-in cannot be loaded.
    """
    config = RigConfig(config) if isinstance(config, str) else config
    return ConfiguredRig(config, find_rig(config.name))


def is_exclusive(factory: RigFactory) -> TypeGuard[ConfiguredRig]:
    """Return whether a factory makes exclusive hardware (one action at a time, in-process)."""
    return isinstance(factory, ConfiguredRig) and factory.exclusive


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


def _read(path: Path) -> dict[str, Any]:
    """Return a configuration file's top-level table.

    Raises:
        RecorderError: The file is unreadable or malformed, or holds keys other than ``rig``
            outside a table.
    """
    try:
        table = load_toml(path)
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as err:
        msg = f"{path}: cannot read the rig configuration ({err}); fix the file or the path"
        raise RecorderError(msg) from err
    if unknown := sorted(k for k, v in table.items() if k != "rig" and not isinstance(v, dict)):
        msg = (
            f"{path}: unknown keys {unknown}; a rig configuration has rig = NAME and tables "
            "([options], and those the rig reads)"
        )
        raise RecorderError(msg)
    return table


def load_rig_config(
    path: Path | None = None, name: str | None = None, options: Sequence[str] = ()
) -> RigConfig:
    """Return the rig configuration: the file's, then ``name`` and ``options`` over it.

    Args:
        path: A TOML file with ``rig = NAME``, an ``[options]`` table and any tables the rig
            reads (optional).
        name: ``--rig``; overrides the file's rig.
        options: ``--rig-option key=value`` entries; override the file's options.

    Raises:
        RecorderError: The file is unreadable or malformed, or an option is not flat.
    """
    table = _read(path) if path is not None else {}
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
    sections = {key: value for key, value in table.items() if key not in {"rig", "options"}}
    return RigConfig(chosen, checked, sections, "" if path is None else str(path))
