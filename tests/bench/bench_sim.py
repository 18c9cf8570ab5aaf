"""Benchmark of the simulated rig: simulation speed as a multiple of real time, per action.

Usage::

    python tests/bench/bench_sim.py [--repeats 5] [--separability] [--spread 60] [--seed 0]

For every action it simulates each catalog object ``repeats`` times (different trials) and
prints the median wall time of one execution, the simulated duration and their ratio (how many
times faster than real time one core simulates). It then projects the simulation time of the
thesis dataset (15 objects x (P1, P2, S1-S4 x 20 + C1 x 10) = 1950 executions). The target is
at least 300x real time, so that simulation plus MCAP writing stays above 50x.

``--separability`` also checks the data's quality: the thesis features of every execution
(20 trials per object and action), an RBF SVC and a 3-NN classifier trained on 10 trials and
tested on the other 10 per object; it prints the 15-class accuracy per action and with all
actions stacked.

``--spread N`` prints the trial-to-trial spread of static contact (C1) over N trials beside
the real heated-probe data (shared/data/thermal-ambiguity-toh, 90 trials per material): the
drop of the cell-averaged temperature 5 s after the total force exceeds 1 N, the temperature
at that instant, and the force 5 s later (recorder/_sim/CALIBRATION.md).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "atikt"))

from atikt_synthetic import thesis_features

from recorder import (
    Modality,
    PhaseEvent,
    SimConfig,
    SimulatedRig,
    SkinBlock,
    load_actions,
    load_objects,
)

if TYPE_CHECKING:
    from collections.abc import Callable

    from recorder import ActionSpec, StreamItem
    from recorder._catalog import ObjectSpec


def _objects(count: int | None) -> list[ObjectSpec]:
    """Return the catalog's objects, the first ``count`` of them if given (``--quick``)."""
    return list(load_objects().values())[:count]


def _time_action(
    rig: SimulatedRig, action: ActionSpec, repeats: int, count: int | None
) -> tuple[float, float]:
    """Return the median wall time of one execution and the median simulated duration, s."""
    walls, durations = [], []
    for trial in range(repeats):
        for obj in _objects(count):
            start = time.perf_counter()
            items = list(rig.perform(obj, action, trial))
            walls.append(time.perf_counter() - start)
            durations.append(items[-1].receive_ns / 1e9)
    return statistics.median(walls), statistics.median(durations)


def bench_speed(repeats: int, count: int | None = None) -> None:
    """Print the speed table and the dataset projection (over ``count`` objects if given)."""
    actions = load_actions()
    n_objects = len(load_objects())
    total_wall = total_real = 0.0
    print(f"{'action':8s} {'median wall':>12s} {'duration':>9s} {'x real time':>12s}")
    with SimulatedRig(0) as rig:
        list(rig.perform(next(iter(load_objects().values())), actions["P1"], 0))  # warm up
        for action in actions.values():
            wall, duration = _time_action(rig, action, repeats, count)
            print(f"{action.id:8s} {wall * 1e3:10.1f} ms {duration:8.1f}s {duration / wall:11.0f}x")
            total_wall += wall * action.trials * n_objects
            total_real += duration * action.trials * n_objects
    print(
        f"dataset ({n_objects} objects, catalog trial counts): {total_real / 60:.0f} min of "
        f"recordings simulated in {total_wall:.0f} s on one core = {total_real / total_wall:.0f}x"
    )


def _window(items: list[StreamItem], modality: Modality) -> np.ndarray:
    """Return one modality's samples of the execute phase, (samples, cells, channels)."""
    events = {item.phase: item.stamp_ns for item in items if isinstance(item, PhaseEvent)}
    blocks = [item for item in items if isinstance(item, SkinBlock) and item.modality is modality]
    data = np.concatenate([block.data for block in blocks])
    times = np.concatenate([b.stamp_ns + b.period_ns * np.arange(b.data.shape[0]) for b in blocks])
    keep = (times >= events["execute"]) & (times < events["retract"])
    result: np.ndarray = data[keep]
    return result


def bench_separability(trials: int = 20, count: int | None = None) -> None:
    """Print the per-action and stacked 15-class accuracy of simple classifiers."""
    from sklearn.neighbors import KNeighborsClassifier  # noqa: PLC0415
    from sklearn.svm import SVC  # noqa: PLC0415

    from atikt.features import FeatureTransformer, RawFeatures  # noqa: PLC0415

    objects, actions = _objects(count), load_actions()
    features: dict[str, list[RawFeatures]] = {action_id: [] for action_id in actions}
    with SimulatedRig(0) as rig:
        for obj in objects:
            for action in actions.values():
                for trial in range(trials):
                    items = list(rig.perform(obj, action, trial))
                    features[action.id].append(
                        thesis_features(
                            action.kind,
                            _window(items, "force"),
                            _window(items, "acceleration"),
                            _window(items, "temperature")[..., 0],
                        )
                    )
    labels = np.repeat(np.arange(len(objects)), trials)
    train = np.tile(np.arange(trials) < trials // 2, len(objects))
    models: dict[str, Callable[[], Any]] = {
        "SVC": lambda: SVC(C=10.0, gamma="scale"),
        "3-NN": lambda: KNeighborsClassifier(min(3, trials // 2)),
    }
    stacked: list[tuple[np.ndarray, np.ndarray]] = []
    for action_id, observations in features.items():
        fitting = [obs for obs, keep in zip(observations, train, strict=True) if keep]
        testing = [obs for obs, keep in zip(observations, train, strict=True) if not keep]
        transformer = FeatureTransformer().fit(fitting)
        split = (transformer.transform(fitting), transformer.transform(testing))
        stacked.append(split)
        line = "  ".join(
            f"{name} {_accuracy(make(), split, labels, train):.2f}" for name, make in models.items()
        )
        print(f"{action_id:8s} {line}")
    both = (np.hstack([s[0] for s in stacked]), np.hstack([s[1] for s in stacked]))
    line = "  ".join(
        f"{name} {_accuracy(make(), both, labels, train):.2f}" for name, make in models.items()
    )
    print(f"{'stacked':8s} {line}")


def _accuracy(
    model: Any, split: tuple[np.ndarray, np.ndarray], labels: np.ndarray, train: np.ndarray
) -> float:
    """Fit ``model`` on the training rows and return its accuracy on the test rows."""
    model.fit(split[0], labels[train])
    return float((model.predict(split[1]) == labels[~train]).mean())


REAL_DROPS = {"wood": (0.48, 0.10), "aluminium": (2.40, 0.16), "cold wood": (2.64, 0.18)}
"""Real 5 s drops, mean and sd over 90 trials each (thermal-ambiguity-toh README), C."""
REAL_START_SD_C = 0.08
"""Real sd of the heated sensor's temperature when the force exceeds 1 N, C."""
REAL_FORCE_N = (4.49, 0.45)
"""Real force 5 s after the onset, mean and sd, N."""


def _series(items: list[StreamItem], modality: Modality) -> tuple[np.ndarray, np.ndarray]:
    """Return one modality's sample times (ns) and samples over the whole execution."""
    blocks = [item for item in items if isinstance(item, SkinBlock) and item.modality is modality]
    data = np.concatenate([block.data for block in blocks]).astype(np.float64)
    times = np.concatenate([b.stamp_ns + b.period_ns * np.arange(b.data.shape[0]) for b in blocks])
    return times, data


def _static_contact(items: list[StreamItem]) -> tuple[float, float, float]:
    """Return the 5 s drop from the 1 N onset, the temperature then and the force 5 s later."""
    t_force, force = _series(items, "force")
    total = force.sum(axis=(1, 2))
    onset = t_force[np.argmax(total > 1.0)]
    t_temp, temperature = _series(items, "temperature")
    mean = temperature[..., 0].mean(axis=1)
    start, later = np.searchsorted(t_temp, [onset, onset + 5e9])
    held = total[np.searchsorted(t_force, onset + 5e9)]
    return float(mean[start] - mean[later]), float(mean[start]), float(held)


def bench_spread(trials: int, seed: int) -> None:
    """Print the simulated spread of static contact beside the real probe's."""
    objects, action = load_objects(), load_actions()["C1"]
    cases = {
        "wood": ("wood", SimConfig()),
        "aluminium": ("aluminium_plate", SimConfig()),
        "cold wood": ("wood", SimConfig(room_c=15.7)),  # the probe study's cooled wood
    }
    print(f"C1, {trials} trials, seed {seed}: 5 s drop from the 1 N onset (real: 90 trials)")
    for name, (object_id, config) in cases.items():
        with SimulatedRig(seed, config) as rig:
            rows = np.array(
                [
                    _static_contact(list(rig.perform(objects[object_id], action, trial)))
                    for trial in range(trials)
                ]
            )
        drop, start, held = rows.T
        mean, sd = REAL_DROPS[name]
        print(
            f"{name:10s} drop {drop.mean():.3f} +- {drop.std(ddof=1):.3f} C (real {mean:.2f} +- "
            f"{sd:.2f}); start sd {start.std(ddof=1):.3f} C (real {REAL_START_SD_C:.2f}); "
            f"force {held.mean():.2f} +- {held.std(ddof=1):.2f} N (real {REAL_FORCE_N[0]:.2f} "
            f"+- {REAL_FORCE_N[1]:.2f})"
        )


def main() -> None:
    """Run the benchmark."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="trials per object and action")
    parser.add_argument("--separability", action="store_true", help="also classify objects")
    parser.add_argument("--spread", type=int, default=0, help="C1 trials of the spread table")
    parser.add_argument("--seed", type=int, default=0, help="rig seed of the spread table")
    parser.add_argument(
        "--quick", action="store_true", help="every table on 2 objects and 2 trials (untimed)"
    )
    args = parser.parse_args()
    if args.quick:
        bench_speed(1, count=2)
        bench_separability(trials=2, count=2)
        bench_spread(2, args.seed)
        return
    if args.spread:
        bench_spread(args.spread, args.seed)
        return
    bench_speed(args.repeats)
    if args.separability:
        bench_separability()


if __name__ == "__main__":
    main()
