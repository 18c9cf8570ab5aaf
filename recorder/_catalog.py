"""Object and action catalogs: data files users extend without touching code."""

from __future__ import annotations

import enum
import tomllib
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

from recorder.errors import CatalogError


class ActionKind(enum.StrEnum):
    """What an action does once in light contact."""

    PRESS = "press"
    SLIDE = "slide"
    STATIC = "static"


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


def read_toml(path: Path | None, default_name: str) -> tuple[str, dict[str, Any]]:
    """Read a catalog file, the packaged default when ``path`` is None.

    Returns:
        The file's name for messages and its parsed content.

    Raises:
        CatalogError: The file is missing or is not valid TOML.
    """
    if path is None:
        source = resources.files(__package__).joinpath("data", default_name)
        return f"<packaged {default_name}>", tomllib.loads(source.read_text("utf-8"))
    try:
        return str(path), tomllib.loads(Path(path).read_text("utf-8"))
    except OSError as err:
        msg = f"{path}: cannot read the catalog ({err.strerror}); check the path"
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
        try:
            actions[action_id] = ActionSpec(
                id=action_id,
                kind=ActionKind(entry["kind"]),
                duration_s=float(entry["duration_s"]),
                depth_m=float(entry.get("depth_m", 0.0)),
                force_n=float(entry.get("force_n", 0.0)),
                speed_m_s=float(entry.get("speed_m_s", 0.0)),
                trials=int(entry.get("trials", 20)),
                description=str(entry.get("description", "")),
            )
        except (KeyError, ValueError, TypeError) as err:
            msg = (
                f"{name}: action [{action_id}] is malformed ({err!r}); it needs kind "
                "(press|slide|static), duration_s and the kind's parameters in SI units"
            )
            raise CatalogError(msg) from err
    return actions


@dataclass(frozen=True, slots=True)
class ObjectSpec:
    """One object of the catalog (physical parameters are added by the simulator's catalog).

    Attributes:
        id: Catalog id, e.g. ``"wood"``.
        name: Human-readable name.
        description: One line for people.
        novel: True for the "new" objects ATIKT learns, False for the "old" prior objects.
    """

    id: str
    name: str
    description: str
    novel: bool
