"""Where a live run writes: its own directory, made at once, resumed, never replaced.

A live run's recordings are made at a robot: they go straight into ``<out>/session/`` as they
are recorded (no temporary directory that an error would remove). ``<out>/live.json`` names
the run (objects, actions, seed, learner, rig) when it starts; running the same command again
resumes it (the recordings on disk are reused), and a run of other settings is refused. A
larger ``--budget`` continues a run, finished or not: the learner's choices do not depend on
the budget, so the steps made are the first steps of the longer run, and only the new ones
move the arm.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from replay.errors import ReplayError
from replay.learning._run_history import HISTORY_NAME, SETTINGS_NAME
from schemas import atomic_write_text, cli

#: The file naming a live run's settings (written when it starts).
LIVE_NAME = "live.json"
#: The one setting a rerun may change: a larger budget continues the run.
BUDGET = "learner.budget"


def live_output(out: Path | None, default: Path, *, force: bool) -> Path:
    """Return a live run's directory: ``--out`` (resumed if it is this run's), or a new one.

    Raises:
        ReplayError: ``--out`` holds something else, or ``--force`` would replace recordings.
    """
    if out is None:
        return cli.numbered_directory(default)
    out = Path(out)
    if not out.exists():
        return out
    if (out / LIVE_NAME).exists():
        if force:
            msg = (
                f"--force {out}: a live run's recordings are never deleted; run the same "
                "command without --force to resume it, or give another --out"
            )
            raise ReplayError(msg)
        return out
    if out.is_dir() and not any(out.iterdir()):
        return out
    msg = f"--out {out}: exists and is not a live run; give a new directory"
    raise ReplayError(msg)


def claim_live_run(target: Path, settings: dict[str, Any]) -> bool:
    """Start the live run in ``target``, or resume it; return True when resuming.

    The settings file is created exclusively: two runs never share a directory.

    Raises:
        ReplayError: The directory holds a finished run or a run of other settings.
    """
    target.mkdir(parents=True, exist_ok=True)
    path = target / LIVE_NAME
    text = json.dumps(settings, indent=1, sort_keys=True) + "\n"
    try:
        with path.open("x", encoding="utf-8") as stream:
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
    except FileExistsError:
        pass
    else:
        return False
    resumes = check_live_run(target, settings)
    if json.loads(path.read_text("utf-8")) != json.loads(text):  # a larger budget: now this one
        atomic_write_text(path, text)
    return resumes


def check_live_run(target: Path, settings: dict[str, Any]) -> bool:
    """Say whether a live run of ``settings`` in ``target`` would resume; writes nothing.

    Returns:
        True when ``target`` holds this run, unfinished (it resumes); False for a new run.

    Raises:
        ReplayError: The directory holds a finished run or a run of other settings.
    """
    path = target / LIVE_NAME
    if not path.exists():
        return False
    try:
        theirs = json.loads(path.read_text("utf-8"))
    except (OSError, ValueError) as err:
        msg = f"{path}: unreadable ({err}); give another --out"
        raise ReplayError(msg) from err
    ours, held = _leaves(settings), _leaves(theirs)
    differ = sorted(k for k in {*ours, *held} if ours.get(k) != held.get(k))
    if differ and not (differ == [BUDGET] and _larger(ours.get(BUDGET), held.get(BUDGET))):
        shown = ", ".join(f"{k}={held.get(k)!r} (now {ours.get(k)!r})" for k in differ)
        fix = "give another --out"
        if differ == [BUDGET]:  # a smaller budget only: the run's own budget continues it
            fix = f"give --budget {held.get(BUDGET)} or more to continue it, or another --out"
        msg = f"{target}: holds a live run of other settings ({shown}); {fix}"
        raise ReplayError(msg)
    if (target / HISTORY_NAME).exists() and not _larger(ours.get(BUDGET), _finished_budget(target)):
        msg = (
            f"{target}: this live run is finished ({HISTORY_NAME}); give a larger --budget to "
            "continue it (its steps are reused), or another --out"
        )
        raise ReplayError(msg)
    return True


def _larger(budget: object, than: object) -> bool:
    """Say whether ``budget`` is a larger step budget than ``than`` (both integers)."""
    return isinstance(budget, int) and isinstance(than, int) and budget > than


def _finished_budget(target: Path) -> object:
    """Return the budget the finished run's history was written for (None: not known)."""
    try:
        written = json.loads((target / SETTINGS_NAME).read_text("utf-8"))
    except (OSError, ValueError):
        return None
    return _leaves(written).get(BUDGET)


def _leaves(settings: Any, prefix: str = "") -> dict[str, Any]:  # noqa: ANN401 (JSON)
    """Flatten nested settings to ``{"learner.budget": 2, ...}``: a difference names its leaf."""
    if not isinstance(settings, dict):
        return {prefix: settings}
    flat: dict[str, Any] = {}
    for key, value in settings.items():
        flat |= _leaves(value, f"{prefix}{key}" if not prefix else f"{prefix}.{key}")
    return flat


def free_file(path: Path) -> Path:
    """Return ``path``, or the first free of ``<stem>-2<suffix>``, ``<stem>-3<suffix>``..."""
    candidate, number = path, 1
    while candidate.exists():
        number += 1
        candidate = path.with_name(f"{path.stem}-{number}{path.suffix}")
    return candidate
