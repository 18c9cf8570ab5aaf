"""Regenerate the committed regression recordings and their golden summaries.

Run from the repository root::

    python recordings/regenerate.py

It deletes ``recordings/data``, records the selection below with the simulated rig
(``atikt-record dataset`` with fixed objects, actions, trials and seed), and writes beside
every recording ``<trial>.golden.json``: what the reader must decode from it (message and
sample counts, stamps, mean and standard deviation of every modality and robot signal,
phases, metadata). ``tests/replay/test_recordings.py`` replays the recordings against them.
It also runs a short learning session over the recordings and writes its decisions and
per-step accuracies to ``learn.golden.json`` (``tests/replay/test_learn_regression.py``).
"""

# ruff: noqa: INP001 (a script beside the data it makes, not a package)

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from recorder import load_actions, plan_dataset
from recorder._catalog import load_objects
from recorder._dataset import generate_dataset, rig_factory
from replay import read_recording
from replay.learning._features import build_features
from replay.learning._session import DEFAULT_LEARNER, RunSpec, run_offline
from replay.recording._container import read_summary

if TYPE_CHECKING:
    import polars as pl
    from numpy.typing import NDArray

    from replay import ActionRecording

#: Where the recordings live, relative to this file.
DATA = Path(__file__).resolve().parent / "data"
#: Old objects, then new objects related to them (each new one to an old one listed here).
OBJECTS = ("wood", "soft_sponge", "metal_toolbox", "pine_board", "foam_block", "aluminium_plate")
#: Every action of the catalog.
ACTIONS: tuple[str, ...] | None = None
#: Trials per (object, action), numbered from 1.
TRIALS = 2
#: Dataset seed.
SEED = 0
#: Suffix of a recording's golden summary, replacing ``.mcap``.
GOLDEN_SUFFIX = ".golden.json"
#: The regression learning run: more trials of two actions for the new objects, so that the
#: learner has a pool to choose from (old objects' recordings are its priors).
LEARN_NEW = ("aluminium_plate", "foam_block", "pine_board")
LEARN_PRIORS = ("metal_toolbox", "soft_sponge", "wood")
LEARN_ACTIONS = ("P2", "S2")
LEARN_TRIALS = 4
LEARN_BUDGET = 6
#: Decisions and per-step accuracies of the regression learning run.
LEARN_GOLDEN = DATA.parent / "learn.golden.json"


def _stats(values: NDArray[Any]) -> dict[str, Any]:
    """Return mean and standard deviation per trailing component (float64 accumulation)."""
    flat = values.reshape(values.shape[0], -1).astype(np.float64)
    return {"mean": flat.mean(axis=0).tolist(), "std": flat.std(axis=0).tolist()}


def _series(stamps: NDArray[np.int64], values: dict[str, NDArray[Any]]) -> dict[str, Any]:
    """Return the golden summary of one time series."""
    out: dict[str, Any] = {
        "samples": int(stamps.size),
        "first_ns": int(stamps[0]),
        "last_ns": int(stamps[-1]),
    }
    return out | {name: _stats(array) for name, array in values.items()}


def summarize(recording: ActionRecording) -> dict[str, Any]:
    """Return the golden summary of a decoded recording (JSON-ready).

    Args:
        recording: A recording read with :func:`replay.read_recording`.

    Returns:
        Metadata, message counts, per-channel sample counts and stamps, mean and standard
        deviation of every signal (per cell and channel), phases.
    """
    summary = read_summary(recording.path)
    meta = recording.metadata
    skin = {
        m: _series(s.stamps_ns, {"data": s.data}) | {"period_ns": s.period_ns}
        for m, s in recording.signals.items()
    }
    joints = recording.joints
    tcp = recording.tcp
    return {
        "metadata": {
            "object_id": meta.object_id,
            "object_name": meta.object_name,
            "object_description": meta.object_description,
            "action_id": meta.action_id,
            "action_kind": meta.action_kind,
            "action_parameters": dict(meta.action_parameters),
            "trial": meta.trial,
            "rig": dict(meta.rig),
            "seed": meta.seed,
            "source": meta.source,
            "schema_version": meta.schema_version,
        },
        "messages": {t: c.message_count for t, c in sorted(summary.channels.items())},
        "skin": skin,
        "joints": None
        if joints is None
        else _series(
            joints.stamps_ns,
            {"position": joints.position, "velocity": joints.velocity, "effort": joints.effort},
        )
        | {"names": list(joints.names)},
        "tcp": None
        if tcp is None
        else _series(tcp.stamps_ns, {"position": tcp.position, "orientation": tcp.orientation})
        | {"frame_id": tcp.frame_id},
        "phases": [[mark.phase, mark.start_ns] for mark in recording.phases],
    }


def golden_path(recording: Path) -> Path:
    """Return where the golden summary of a recording lives."""
    return recording.with_name(recording.name.removesuffix(".mcap") + GOLDEN_SUFFIX)


def regression_run(data: Path) -> pl.DataFrame:
    """Return the rows of the regression learning run over the recordings in ``data``."""
    with tempfile.TemporaryDirectory() as scratch:
        frame = build_features(data, cache=Path(scratch) / "features.parquet").frame
    spec = RunSpec(
        new_objects=LEARN_NEW,
        prior_objects=LEARN_PRIORS,
        actions=LEARN_ACTIONS,
        learner=DEFAULT_LEARNER.replace(budget=LEARN_BUDGET),
        seed=SEED,
        test_fraction=0.25,
    )
    return run_offline(frame, spec).frame()


def learn_summary(rows: pl.DataFrame) -> list[dict[str, Any]]:
    """Return what the regression learning run must reproduce: decisions and accuracies."""
    keep = ["step", "object", "action", "explored", "prior", "rho", "accuracy"]
    keep += sorted(c for c in rows.columns if c.startswith("accuracy_"))
    return rows.select(keep).to_dicts()


def regenerate(workers: int | None) -> None:
    """Delete and record the selection again, then write every golden summary."""
    if DATA.exists():
        shutil.rmtree(DATA)
    tasks = plan_dataset(
        load_objects(), load_actions(), object_ids=OBJECTS, action_ids=ACTIONS, trials=TRIALS
    )
    tasks += plan_dataset(
        load_objects(),
        load_actions(),
        object_ids=LEARN_NEW,
        action_ids=LEARN_ACTIONS,
        trials=LEARN_TRIALS,
    )
    report = generate_dataset(tasks, DATA, rig_factory("sim"), seed=SEED, workers=workers)
    for path in sorted(DATA.rglob("*.mcap")):
        text = json.dumps(summarize(read_recording(path)), indent=1, sort_keys=True)
        golden_path(path).write_text(text + "\n")
    text = json.dumps(learn_summary(regression_run(DATA)), indent=1, sort_keys=True)
    LEARN_GOLDEN.write_text(text + "\n")
    size = sum(p.stat().st_size for p in DATA.rglob("*") if p.is_file())
    print(f"{report.written} recordings and goldens in {DATA}, {size / 1e6:.1f} MB")  # noqa: T201


def main() -> None:
    """Parse the command line and regenerate."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--workers", type=int, help="worker processes (default: all cores)")
    regenerate(parser.parse_args().workers)


if __name__ == "__main__":
    main()
