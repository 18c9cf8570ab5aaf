"""Object and action catalogs: data files users extend without touching code."""

from __future__ import annotations

import math
import tomllib
from dataclasses import dataclass, fields
from importlib import resources
from typing import TYPE_CHECKING, Any, TypeAlias

from recorder.errors import CatalogError
from schemas import MAX_TRIAL, VOCABULARY, ContractError, check_id, load_toml, loads_toml

if TYPE_CHECKING:
    from pathlib import Path

ActionKind: TypeAlias = str
"""An action kind's name, one of ``schemas.VOCABULARY.kinds`` (the contract's list)."""


@dataclass(frozen=True, slots=True)
class ActionSpec:
    """One exploratory action of the catalog.

    Attributes:
        id: Catalog id, e.g. ``"P1"``.
        kind: Press, slide or static contact.
        duration_s: Duration of the execute phase, s.
        depth_m: Press depth beyond light contact, m (press and static; else 0).
        force_n: Normal force while sliding, N (slide; else 0).
        speed_m_s: Sliding speed, m/s (slide; else 0).
        trials: Default number of trials in dataset generation.
        description: One line for people.
    """

    id: str
    kind: ActionKind
    duration_s: float
    depth_m: float = 0.0
    force_n: float = 0.0
    speed_m_s: float = 0.0
    trials: int = 20
    description: str = ""

    def parameters(self) -> dict[str, float]:
        """Return the numeric parameters, SI units, for metadata and annotations."""
        return {
            "depth_m": self.depth_m,
            "force_n": self.force_n,
            "speed_m_s": self.speed_m_s,
            "duration_s": self.duration_s,
        }


def _kind(value: object) -> ActionKind:
    if value not in VOCABULARY.kinds:
        msg = f"unknown kind {value!r}"
        raise ValueError(msg)
    return str(value)


def _trials(value: object) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_TRIAL:
        msg = f"trials = {value!r} is not a number of trials 1..{MAX_TRIAL}"
        raise ValueError(msg)
    return value


def _catalog_id(name: str, what: str, value: str) -> str:
    """Return a catalog key if it follows the id rule (it names a directory of datasets).

    Raises:
        CatalogError: It does not; the message names the file, the id and the rule.
    """
    try:
        return check_id(what, value)
    except ContractError as err:
        msg = f"{name}: {err}; rename the entry"
        raise CatalogError(msg) from err


def read_toml(path: Path | None, default_name: str) -> tuple[str, dict[str, Any]]:
    """Read a catalog file, the packaged default when ``path`` is None.

    Returns:
        The file's name for messages and its parsed content.

    Raises:
        CatalogError: The file is missing or is not valid TOML.
    """
    if path is None:
        source = resources.files(__package__).joinpath("data", default_name)
        return f"<packaged {default_name}>", loads_toml(source.read_text("utf-8"))
    try:
        return str(path), load_toml(path)
    except OSError as err:
        msg = f"{path}: cannot read the catalog ({err.strerror}); check the path"
        raise CatalogError(msg) from err
    except UnicodeDecodeError as err:
        msg = f"{path}: the catalog is not UTF-8 (byte {err.start}); save it as UTF-8"
        raise CatalogError(msg) from err
    except tomllib.TOMLDecodeError as err:
        msg = f"{path}: not valid TOML ({err}); fix the file's syntax"
        raise CatalogError(msg) from err


def load_actions(path: Path | None = None) -> dict[str, ActionSpec]:
    """Load the action catalog, ordered as in the file.

    Args:
        path: A TOML catalog; the packaged thesis catalog when None.

    Raises:
        CatalogError: An entry is malformed; the message names the file and the entry.
    """
    name, table = read_toml(path, "actions.toml")
    actions: dict[str, ActionSpec] = {}
    for action_id, entry in table.items():
        _catalog_id(name, "action", action_id)
        try:
            actions[action_id] = ActionSpec(
                id=action_id,
                kind=_kind(entry["kind"]),
                duration_s=float(entry["duration_s"]),
                depth_m=float(entry.get("depth_m", 0.0)),
                force_n=float(entry.get("force_n", 0.0)),
                speed_m_s=float(entry.get("speed_m_s", 0.0)),
                trials=_trials(entry.get("trials", 20)),
                description=str(entry.get("description", "")),
            )
        except (KeyError, ValueError, TypeError) as err:
            msg = (
                f"{name}: action [{action_id}] is malformed ({err!r}); it needs kind "
                f"({'|'.join(VOCABULARY.kinds)}), duration_s and the kind's parameters in SI units"
            )
            raise CatalogError(msg) from err
        if problem := _motion_problem(actions[action_id]):
            # checked here, before anything moves: a rig would act on it (a press of depth
            # nan or -1 mm, a hold of 1e9 s) and only the recording's metadata refused it
            msg = f"{name}: action [{action_id}] {problem}"
            raise CatalogError(msg)
    return actions


#: The longest action a catalog may declare, s (an hour; the thesis's longest hold is 15 s).
MAX_DURATION_S = 3600.0


def _motion_problem(action: ActionSpec) -> str:
    """Return what makes an action's motion impossible (empty: nothing)."""
    for key in ("duration_s", "depth_m", "force_n", "speed_m_s"):
        value = getattr(action, key)
        if not math.isfinite(value) or value < 0:
            return f"{key} = {value}: give a finite number >= 0 (SI units)"
    if not 0 < action.duration_s <= MAX_DURATION_S:
        return f"duration_s = {action.duration_s}: give 0 < duration_s <= {MAX_DURATION_S:g} s"
    return ""


PROPERTIES = VOCABULARY.properties
"""Properties an object can share with a related one (those the modalities measure)."""


@dataclass(frozen=True, slots=True)
class ObjectPhysics:
    """The physical parameters of an object, as the simulator needs them (not its identity).

    Lengths in m, forces in N, times in s, effusivity in W s^0.5 m^-2 K^-1. The defaults
    describe a rigid, smooth, wood-like block, so a user only states what differs.

    Attributes:
        height_m: Height of the top face above the table.
        length_m: Extent of the top face along the object's x axis.
        width_m: Extent of the top face along the object's y axis.
        flatness_m: RMS height irregularity of the top face under each skin cell.
        curvature_1_m: Curvature of the top face (positive: convex, a dome), 1/m.
        reflectance: Infrared reflectance of the surface (0, 1], seen by the proximity sensors.
        stiffness_n_m: Contact stiffness of the surface under the whole skin patch (small
            depths), N/m; large (1e6) for rigid objects, whose deflection the skin cover takes.
        layer_thickness_m: Thickness of a compliant (foam) top layer; 0 for none.
        yield_strain: Strain of the layer where the foam's elastic range ends and its
            plateau begins (0: linear, no plateau).
        plateau_ratio: Stiffness on the plateau relative to ``stiffness_n_m``.
        densification_strain: Strain where the layer densifies and stiffens without bound
            (0: never); a thin foam layer on a hard base (sponge over marble) reaches it.
        relaxation: Fraction of the force that relaxes during a long hold at constant depth.
        relaxation_time_s: Time constant of that relaxation.
        effusivity: Thermal effusivity sqrt(k rho c) of the surface material.
        base_effusivity: Effusivity of what lies under a thin surface layer (0: same).
        thermal_layer_s: Time heat takes to cross the surface layer, d^2/alpha (0: no layer).
        texture_period_m: Dominant spatial period of the surface texture.
        texture_amplitude_m: Peak height of that texture.
        anisotropy: 0 for an isotropic random texture, 1 for parallel ridges (a grating).
        grain_angle_deg: Direction of the ridges' normal relative to the object's x axis.
        fine_roughness_m: RMS of the micro-roughness that makes friction noise.
        friction_static: Static friction coefficient against the skin cover.
        friction_kinetic: Kinetic friction coefficient (stick-slip where much lower than static).
        variability: Relative spread of stiffness, texture depth and roughness from spot to
            spot (sponges and box lids vary more than glass).
    """

    height_m: float = 0.05
    length_m: float = 0.15
    width_m: float = 0.1
    flatness_m: float = 0.0
    curvature_1_m: float = 0.0
    reflectance: float = 0.5
    stiffness_n_m: float = 1e6
    layer_thickness_m: float = 0.0
    yield_strain: float = 0.0
    plateau_ratio: float = 1.0
    densification_strain: float = 0.0
    relaxation: float = 0.0
    relaxation_time_s: float = 1.0
    effusivity: float = 450.0
    base_effusivity: float = 0.0
    thermal_layer_s: float = 0.0
    texture_period_m: float = 1e-3
    texture_amplitude_m: float = 0.0
    anisotropy: float = 0.0
    grain_angle_deg: float = 0.0
    fine_roughness_m: float = 0.0
    friction_static: float = 0.5
    friction_kinetic: float = 0.4
    variability: float = 0.1


@dataclass(frozen=True, slots=True)
class ObjectSpec:
    """One object: its identity, its default role, and (for simulation) its physics.

    Attributes:
        id: Catalog id, e.g. ``"wood"``.
        name: Human-readable name.
        description: One line for people.
        novel: The default role: True for a "new" object ATIKT learns, False for an "old"
            (prior) one; runs choose roles with ``--new``/``--priors``.
        related_to: For a new object, the id of the old object it resembles ("" if none).
        shared: The properties (stiffness, texture, thermal) it shares with ``related_to``.
        physics: Physical parameters for the simulator; None for an object that is only
            touched by real rigs (the simulator refuses it in one line).
    """

    id: str
    name: str
    description: str = ""
    novel: bool = False
    related_to: str = ""
    shared: tuple[str, ...] = ()
    physics: ObjectPhysics | None = None


_REQUIRED_OBJECT_KEYS = (
    "stiffness_n_m",
    "effusivity",
    "texture_period_m",
    "texture_amplitude_m",
    "friction_static",
    "friction_kinetic",
)
_POSITIVE_KEYS = (
    "height_m",
    "length_m",
    "width_m",
    "reflectance",
    "stiffness_n_m",
    "plateau_ratio",
    "relaxation_time_s",
    "effusivity",
    "texture_period_m",
    "friction_static",
)
_NON_NEGATIVE_KEYS = (
    "flatness_m",
    "layer_thickness_m",
    "base_effusivity",
    "thermal_layer_s",
    "texture_amplitude_m",
    "fine_roughness_m",
)
_FRACTION_KEYS = (
    "relaxation",
    "anisotropy",
    "reflectance",
    "yield_strain",
    "densification_strain",
    "variability",
)


def _object_from_entry(object_id: str, entry: dict[str, Any]) -> ObjectSpec:
    """Build one ObjectSpec from its TOML table (types converted, unknown keys refused).

    Raises:
        KeyError: A required key is missing.
        ValueError: A key is unknown or a value has the wrong type.
    """
    identity_keys = set(ObjectSpec.__dataclass_fields__) - {"id", "physics"}
    physics_keys = set(ObjectPhysics.__dataclass_fields__)
    if unknown := sorted(set(entry) - identity_keys - physics_keys):
        msg = f"unknown keys {unknown}"
        raise ValueError(msg)
    if "name" not in entry:
        raise KeyError("name")  # noqa: EM101 (the missing key is the message)
    values: dict[str, Any] = {}
    for key in identity_keys & set(entry):
        value = entry[key]
        if key == "novel":
            if not isinstance(value, bool):
                msg = "novel must be true or false"
                raise TypeError(msg)
            values[key] = value
        elif key == "shared":
            values[key] = tuple(str(item) for item in value)
        else:
            values[key] = str(value)
    given = physics_keys & set(entry)
    if given:  # an object for the simulator: its required physical keys
        if missing := [key for key in _REQUIRED_OBJECT_KEYS if key not in entry]:
            raise KeyError(", ".join(missing))
        values["physics"] = ObjectPhysics(**{key: float(entry[key]) for key in given})
    return ObjectSpec(id=object_id, **values)


def check_object(obj: ObjectPhysics) -> str | None:
    """Return what is physically wrong with an object's parameters, or None if nothing is."""
    layered = obj.yield_strain > 0 or obj.densification_strain > 0
    numbers = [f.name for f in fields(obj) if isinstance(getattr(obj, f.name), float)]
    problems = [
        *(f"{key} must be finite" for key in numbers if not math.isfinite(getattr(obj, key))),
        *(f"{key} must be > 0" for key in _POSITIVE_KEYS if not getattr(obj, key) > 0),
        *(f"{key} must lie in [0, 1]" for key in _FRACTION_KEYS if not 0 <= getattr(obj, key) <= 1),
        *(f"{key} must be >= 0" for key in _NON_NEGATIVE_KEYS if getattr(obj, key) < 0),
        *(
            ["friction_kinetic must lie in (0, friction_static]"]
            if not 0 < obj.friction_kinetic <= obj.friction_static
            else []
        ),
        *(
            ["yield_strain and densification_strain need layer_thickness_m > 0"]
            if layered and obj.layer_thickness_m <= 0
            else []
        ),
        *(
            ["densification_strain must exceed yield_strain"]
            if 0 < obj.densification_strain <= obj.yield_strain
            else []
        ),
    ]
    return problems[0] if problems else None


def _check_relation(obj: ObjectSpec, objects: dict[str, ObjectSpec]) -> str | None:
    """Return what is wrong with a new object's relation to an old one, or None.

    A relation is optional: a new object may resemble none of the old ones (then no prior
    should be transferred to it). When given, it names an old object and what they share.
    """
    if not obj.novel or (not obj.related_to and not obj.shared):
        return None
    related = objects.get(obj.related_to)
    if related is None or related.novel:
        return f"related_to = {obj.related_to!r} must name an old object of the catalog"
    bad = [name for name in obj.shared if name not in PROPERTIES]
    if not obj.shared or bad:
        return f"shared must list at least one of {PROPERTIES}"
    return None


def load_objects(path: Path | None = None) -> dict[str, ObjectSpec]:
    """Load the object catalog, ordered as in the file.

    A new (``novel``) object may name the old object it resembles (``related_to``) and the
    properties they share (``shared``); one that resembles none names neither.

    Args:
        path: A TOML catalog; the packaged thesis catalog (10 old, 5 new objects) when None.

    Returns:
        The objects by id.

    Raises:
        CatalogError: An entry is malformed, physically impossible or names an unknown
            related object; the message names the file, the entry and the fix.
    """
    name, table = read_toml(path, "objects.toml")
    objects: dict[str, ObjectSpec] = {}
    for object_id, entry in table.items():
        _catalog_id(name, "object", object_id)
        try:
            objects[object_id] = _object_from_entry(object_id, dict(entry))
        except (KeyError, ValueError, TypeError, AttributeError) as err:
            msg = (
                f"{name}: object [{object_id}] is malformed ({err}); it needs "
                f"name, and for the simulator {', '.join(_REQUIRED_OBJECT_KEYS)}; only the keys "
                "of ObjectSpec and ObjectPhysics, in SI units"
            )
            raise CatalogError(msg) from err
    for obj in objects.values():
        physical = check_object(obj.physics) if obj.physics is not None else None
        problem = physical or _check_relation(obj, objects)
        if problem is not None:
            msg = f"{name}: object [{obj.id}]: {problem}; fix the entry"
            raise CatalogError(msg)
    return objects
