"""Where a live run writes: its own directory, made at once, resumed, never replaced.

A live run's recordings are made at a robot: they go straight into ``<out>/session/`` as they
are recorded (no temporary directory that an error would remove). ``<out>/live.json`` names
the run when it starts: objects, actions, seed, learner, the rig's configuration as the rig
describes itself (its content, not the file's name: an edited file is another configuration, the
same file named another way is not) and the priors (a digest of the prior objects' recordings:
a moved copy of the dataset is the same priors, a changed one is not). Running the same command
again resumes it (the recordings on disk are reused), and a run of other settings is refused,
as ``atikt-record session`` refuses a dataset of another rig configuration: one run, one rig
configuration. A larger ``--budget`` continues a run, finished or not: the learner's choices do
not depend on the budget, so the steps made are the first steps of the longer run, and only the
new ones move the arm.
"""

from __future__ import annotations

import contextlib
import json
import os
from pathlib import Path
from typing import Any

from replay.errors import ReplayError
from replay.learning._run_history import HISTORY_NAME, SETTINGS_NAME
from schemas import atomic_write_text, cli

#: The file naming a live run's settings (written when it starts).
LIVE_NAME = "live.json"
#: The directory of a live run that holds its recordings (beside ``live.json``).
SESSION_DIR = "session"
#: The one setting a rerun may change: a larger budget continues the run.
BUDGET = "learner.budget"
#: The rig's configuration in the settings (``rig.<setting>`` leaves).
RIG = "rig"
#: The priors in the settings (``priors.<leaf>``); ``priors.dataset`` only names them.
PRIORS = "priors"
#: Leaves that name a setting for messages but are not compared (a moved dataset resumes).
_NAMES = frozenset({f"{PRIORS}.dataset"})
#: Keys of a ``live.json`` written before the rig was identified by its configuration.
_OLD_KEYS = frozenset({"rig_config", "rig_options"})


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


def release_unused_claim(target: Path, settings: dict[str, Any]) -> bool:
    """Take back a new run's claim of ``target`` when the run recorded nothing; say whether.

    A run that claimed a fresh directory and then could not start (the rig did not connect,
    Ctrl-C before its first recording) leaves nothing to resume; its claim would only refuse
    the corrected command (another controller address is another rig configuration). Only the
    claim file and the empty directories in ``target`` are removed (``target`` stays: an empty
    directory is a valid ``--out``), and only when the claim is this run's (the same settings)
    and no other file lies in ``target``: nothing recorded is ever touched (``rmdir`` cannot
    remove a directory that holds anything).
    """
    path = target / LIVE_NAME
    try:
        if json.loads(path.read_text("utf-8")) != json.loads(json.dumps(settings)):
            return False
    except (OSError, ValueError):
        return False
    others = [p for p in target.rglob("*") if p != path and not p.is_dir()]
    if others:
        return False
    path.unlink()
    for directory in sorted(target.rglob("*"), key=lambda p: len(p.parts), reverse=True):
        with contextlib.suppress(OSError):  # empty (checked above); anything in it: it stays
            directory.rmdir()
    return True


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
    if _OLD_KEYS & theirs.keys() and not _OLD_KEYS & settings.keys():
        msg = (
            f"{path}: written by an earlier version, which named the rig configuration file "
            f"({theirs.get('rig_config')!r}), not the rig's settings, so a resumed run could "
            "mix two configurations; replay its recordings offline (learn --session "
            f"{target / 'session'}), or give another --out"
        )
        raise ReplayError(msg)
    ours, held = _leaves(settings), _leaves(theirs)
    differ = _conflicts(ours, held)
    if differ:
        raise ReplayError(_refusal(target, differ, ours, held))
    if (target / HISTORY_NAME).exists() and not _larger(ours.get(BUDGET), _finished_budget(target)):
        msg = (
            f"{target}: this live run is finished ({HISTORY_NAME}); give a larger --budget to "
            "continue it (its steps are reused), or another --out"
        )
        raise ReplayError(msg)
    return True


def _conflicts(ours: dict[str, Any], held: dict[str, Any]) -> list[str]:
    """Return the leaves in which a rerun conflicts with the run held (a larger budget: none)."""
    keys = {*ours, *held} - _NAMES
    differ = sorted(k for k in keys if ours.get(k) != held.get(k))
    if _larger(ours.get(BUDGET), held.get(BUDGET)):
        differ.remove(BUDGET)  # a larger budget continues the run
    return differ


def _refusal(target: Path, differ: list[str], ours: dict[str, Any], held: dict[str, Any]) -> str:
    """Return the one line refusing a rerun of other settings: each conflict, then the fix."""
    shown = [f"{k}={held.get(k)!r} (now {ours.get(k)!r})" for k in differ if not _priors(k)]
    if any(_priors(k) for k in differ):
        name = f"{PRIORS}.dataset"
        now = "changed since" if held.get(name) == ours.get(name) else f"now {ours.get(name)!r}"
        shown.append(f"priors={held.get(name)!r} ({now}: the prior objects' recordings differ)")
    what = "other settings"
    if all(k.startswith(f"{RIG}.") for k in differ):
        what = "another rig configuration"  # as atikt-record session says it
    elif all(_priors(k) for k in differ):
        what = "another priors dataset"
    fix = "give another --out"
    if differ == [BUDGET]:  # a smaller budget only: the run's own budget continues it
        fix = f"give --budget {held.get(BUDGET)} or more to continue it, or another --out"
    elif all(_priors(k) for k in differ):
        fix = f"give the priors {held.get(f'{PRIORS}.dataset')} to continue it, or another --out"
    return f"{target}: holds a live run of {what} ({', '.join(shown)}); {fix}"


def _priors(key: str) -> bool:
    """Say whether a settings leaf identifies the run's priors."""
    return key.startswith(f"{PRIORS}.")


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


def live_run_of(session: Path) -> Path | None:
    """Return the live run whose recordings ``session`` holds (``<out>/session``), else None."""
    out = Path(session).parent
    return out if Path(session).name == SESSION_DIR and (out / LIVE_NAME).is_file() else None


def refuse_unfinished_replay(session: Path, observations: int, budget: int) -> None:
    """Refuse an offline replay of more steps than an unfinished live run made.

    Args:
        session: The recorded session replayed (``learn --session``).
        observations: The learner's observations it holds (its manifest's ``pool`` rows).
        budget: The steps the replay asks for.

    Raises:
        ReplayError: ``session`` is an unfinished live run's and made fewer steps: one line
            saying how many it made, how to continue it and how to replay only those.
    """
    out = live_run_of(session)
    if out is None:
        return
    try:
        held = _leaves(json.loads((out / LIVE_NAME).read_text("utf-8")))
    except (OSError, ValueError):
        return  # not this check's to say: the live command says it
    finished = (out / HISTORY_NAME).exists()
    if finished and not _larger(held.get(BUDGET), _finished_budget(out)):
        return  # finished: the replay's own budget is checked against the pool
    first = len(held.get("new_objects") or []) * len(held.get("actions") or [])
    steps = observations - first  # the steps after step 0 (its first observations)
    if budget <= steps:
        return
    made = f"it made steps 0 to {steps}" if steps > 0 else "it made step 0 only"
    replay = f", or replay only the steps it made with --budget {steps}"
    if steps < 0:
        made, replay = "it stopped before step 0 was complete", ""
    msg = (
        f"{session}: the live run in {out} is unfinished ({made} of its budget of "
        f"{held.get(BUDGET)}); continue it with its live command (learn --rig or --rig-config "
        f"as before, --out {out}){replay}"
    )
    raise ReplayError(msg)


def free_file(path: Path) -> Path:
    """Return ``path``, or the first free of ``<stem>-2<suffix>``, ``<stem>-3<suffix>``..."""
    candidate, number = path, 1
    while candidate.exists():
        number += 1
        candidate = path.with_name(f"{path.stem}-{number}{path.suffix}")
    return candidate
