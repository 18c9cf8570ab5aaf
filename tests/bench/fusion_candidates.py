"""Modality fusion candidates against the best single modality, per action and training size.

The protocol of ``atikt-replay study fusion`` (replay/studies/_fusion.py): per action, random
groups of objects x repetitions (a random half of each object's trials held out for testing), a
classifier fitted on 1, 2, 3, 5, 7, 10 training samples per object, test accuracy. Every
candidate and every single modality is fitted on the same splits with the same seeds.

Data:

- ``--data sim``: the simulated dataset's feature cache (the study's own groups and seeds,
  ``fusion_tasks``), default ``~/.cache/atikt/sim2-seed0-schema2-v0.2.0/features.parquet``;
- ``--data real``: the heated-probe study of Bhattacharjee et al. (shared/data/
  thermal-ambiguity-toh, 3 materials x 90 trials, static contact); features from the heated
  thermistor and the force over 6 s from force onset (> 1 N). A "group" is a seed of the
  random split (the 3 classes are always all used).

Printed: per action and training size the mean accuracy of every candidate and of each single
modality, the candidate minus the best single modality (points) with a paired 95 % bootstrap
interval over groups, and the fit time per candidate.

Run: ``python tests/bench/fusion_candidates.py --data real`` or ``--data sim [--groups 10]``;
``--quick``: one group of 3 objects, one repetition, P1, on the committed recordings (a check
that the script runs).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's packages

from atikt import MultiModalGPC, RawFeatures, extract_features
from replay.learning._executors import FeatureLookup
from replay.learning._parallel import run_tasks
from replay.studies._fusion import FUSION_SIZES, fusion_splits, fusion_tasks
from replay.studies._fusion_prior import NOISE_OTHER_SD, declared_noise, reference_theta
from replay.studies._running import StudyConfig, dataset_actions
from replay.studies._running import derive_seed as _seed

CANDIDATES: dict[str, dict[str, Any]] = {
    "fused": {"selection": "fused"},
    "fused-thesis": {"selection": "fused", "amplitude": False},
    "evidence": {"selection": "evidence"},
    "evidence-all": {"selection": "evidence-all"},
    "shared": {"selection": "fused", "shared": True},
    "shared-evidence": {"selection": "evidence-all", "shared": True},
    "prior1": {"selection": "fused", "prior_sd": 1.0},
    "shared-prior1": {"selection": "fused", "shared": True, "prior_sd": 1.0},
    "shared-prior2": {"selection": "fused", "shared": True, "prior_sd": 2.0},
    # Hyperparameters of a model of the other objects (outside the group) of the action: the
    # starting point (ref-start), the prior's centre with sd 1 or 0.5 (ref-prior1, ref-prior05).
    "ref-start": {"selection": "fused", "initial_theta": "reference"},
    "ref-prior1": {"selection": "fused", "initial_theta": "reference", "prior_sd": 1.0},
    "ref-prior05": {"selection": "fused", "initial_theta": "reference", "prior_sd": 0.5},
    # The study's fallback without other objects: modality weights from the sensors' declared
    # noise (contract `noise`; the probe's force is set by its controller, `controlled_by`),
    # length scales and signal variance a prior of sd 1 around the initial kernel.
    "noise": {"selection": "fused", "sensor_noise": "declared", "prior_sd": NOISE_OTHER_SD},
    "product": {"selection": "fused", "combination": "product", "prior_sd": NOISE_OTHER_SD},
}
SIM = Path.home() / ".cache/atikt/sim2-seed0-schema2-v0.2.0/features.parquet"
REAL = Path("/work/shared/data/thermal-ambiguity-toh/robot_study.npz")


def real_features(path: Path, seconds: float = 6.0) -> tuple[list[RawFeatures], np.ndarray]:
    """Static-contact features of the heated-probe trials and their material labels."""
    data = np.load(path)
    force, heated, material = data["force_n"], data["heated_c"], data["material"]
    rate = 1.0 / float(np.diff(data["t_s"][:2])[0])
    n = round(seconds * rate)
    observations = []
    for trial in range(force.shape[0]):
        onset = int(np.argmax(force[trial] > 1.0))
        window = slice(onset, onset + n)
        observations.append(
            extract_features(
                "static",
                {
                    "force": (force[trial, window, None, None].astype(np.float64), rate),
                    "thermal": (heated[trial, window, None].astype(np.float64), rate),
                },
            )
        )
    classes = sorted(set(material))
    return observations, np.array([classes.index(m) for m in material])


def fit_rows(  # noqa: PLR0917 - one training set and its test set
    train: list[RawFeatures],
    labels: list[int],
    test: list[RawFeatures],
    test_labels: np.ndarray,
    modalities: tuple[str, ...],
    seed: int,
    names: list[str],
    reference: np.ndarray | None = None,
    controlled: tuple[str, ...] = (),
) -> list[dict[str, Any]]:
    """Accuracy and fit time of every candidate and single modality on one training set.

    ``reference``: the other objects' fused hyperparameters, for the ``ref-*`` candidates
    (skipped without it).
    """
    rows = []
    subsets: dict[str, dict[str, Any]] = {}
    for n in names:
        options = dict(CANDIDATES[n])
        if options.get("initial_theta") == "reference":
            if reference is None:
                continue
            options["initial_theta"] = reference
        if options.get("sensor_noise") == "declared":
            options |= {"sensor_noise": declared_noise(), "controlled": controlled}
        subsets[n] = options
    subsets |= {m: {"modalities": (m,), "selection": "fused", "shared": False} for m in modalities}
    subsets |= {
        f"{m}/shared": {"modalities": (m,), "selection": "fused", "shared": True}
        for m in modalities
    }
    for name, options in subsets.items():
        start = time.perf_counter()
        model = MultiModalGPC(random_state=seed, **options).fit(train, labels)
        seconds = time.perf_counter() - start
        accuracy = float(np.mean(model.predict(test) == test_labels))
        rows.append({"modalities": name, "accuracy": accuracy, "seconds": seconds})
    return rows


def sim_task(args: tuple[Any, list[str]]) -> pl.DataFrame:
    """One fusion task of the simulated dataset (the study's protocol), all candidates."""
    task, names = args
    lookup = FeatureLookup(task.frame)
    modalities = lookup.blocks[task.action]
    reference = reference_theta(lookup, task.action, task.objects, task.seed)
    rows = []
    for split in fusion_splits(task, lookup):
        label = {"action": task.action, "group": task.group, "samples": split.size}
        rows += [
            label | r
            for r in fit_rows(
                split.train,
                split.labels,
                split.test,
                np.asarray(split.test_labels),
                modalities,
                split.seed,
                names,
                reference,
                task.controlled,
            )
        ]
    return pl.DataFrame(rows)


def real_task(args: tuple[int, int, list[str]]) -> pl.DataFrame:
    """One group of the real probe data: ``repetitions`` random half splits."""
    group, repetitions, names = args
    observations, labels = real_features(REAL)
    rows = []
    for repetition in range(repetitions):
        seed = _seed(0, "real", group, repetition)
        rng = np.random.default_rng(seed)
        train_pool, test = [], []
        for c in np.unique(labels):
            order = rng.permutation(np.flatnonzero(labels == c))
            test += list(order[: len(order) // 2])
            train_pool.append(order[len(order) // 2 :])
        test_obs = [observations[i] for i in test]
        for size in FUSION_SIZES:
            chosen = [i for p in train_pool for i in p[:size]]
            train = [observations[i] for i in chosen]
            label = {"action": "real-static", "group": group, "samples": size}
            rows += [
                label | r
                for r in fit_rows(
                    train,
                    [int(labels[i]) for i in chosen],
                    test_obs,
                    labels[test],
                    ("force", "thermal"),
                    seed,
                    names,
                    controlled=("force",),  # the probe's controller sets the force (4.5 N)
                )
            ]
    return pl.DataFrame(rows)


def bootstrap(values: np.ndarray, rng: np.random.Generator, n: int = 2000) -> tuple[float, float]:
    """95 % percentile interval of the mean of ``values`` (resampled with replacement)."""
    means = rng.choice(values, size=(n, values.shape[0])).mean(axis=1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def report(frame: pl.DataFrame, names: list[str]) -> None:
    """Print the tables: accuracies, candidate minus best single, fit times."""
    rng = np.random.default_rng(0)
    per_group = frame.group_by("action", "group", "samples", "modalities").agg(
        pl.col("accuracy").mean()
    )
    singles = [
        f"{m}{v}"
        for m in ("force", "texture", "thermal")
        for v in ("", "/shared")
        if f"{m}{v}" in set(frame["modalities"])
    ]
    for action in sorted(set(frame["action"])):
        part = per_group.filter(pl.col("action") == action)
        present = [m for m in singles if m in set(part["modalities"])]
        print(f"\n## {action}\n")
        print(
            "| samples | "
            + " | ".join(names + present)
            + " | best single | "
            + " | ".join(f"{n} - best" for n in names)
            + " |"
        )
        print("|---" * (2 + len(names) * 2 + len(present)) + "|")
        totals: dict[str, list[float]] = defaultdict(list)
        for size in sorted(set(part["samples"])):
            wide = (
                part.filter(pl.col("samples") == size)
                .pivot(on="modalities", index="group", values="accuracy")
                .sort("group")
            )
            means = {c: float(wide[c].mean()) for c in names + present}  # type: ignore[arg-type]
            best = max(present, key=lambda m: means[m])
            cells = [f"{100 * means[c]:.1f}" for c in names + present] + [best]
            for n in names:
                diff = 100 * (wide[n].to_numpy() - wide[best].to_numpy())
                low, high = bootstrap(diff, rng)
                cells.append(f"{diff.mean():+.1f} [{low:+.1f}, {high:+.1f}]")
                totals[n].append(float(diff.mean()))
            print(f"| {size} | " + " | ".join(cells) + " |")
        worst = {n: min(v) for n, v in totals.items()}
        print(
            "worst size, candidate - best single (points): "
            + ", ".join(f"{n} {v:+.1f}" for n, v in worst.items())
        )
    study = (
        frame.group_by("action", "modalities")
        .agg(pl.col("accuracy").mean())
        .pivot(on="modalities", index="action", values="accuracy")
        .sort("action")
    )
    print("\nmean over training sizes (the study table), %:")
    print("| action | " + " | ".join(names + singles) + " |")
    for row in study.iter_rows(named=True):
        cells = [f"{100 * row[c]:.1f}" if row.get(c) is not None else "-" for c in names + singles]
        print(f"| {row['action']} | " + " | ".join(cells) + " |")
    seconds = frame.group_by("modalities").agg(pl.col("seconds").sum()).sort("modalities")
    print(
        "\nfit time, s (all fits): " + ", ".join(f"{r[0]} {r[1]:.1f}" for r in seconds.iter_rows())
    )


def main() -> None:
    """Run the candidates on the chosen data and print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", choices=("real", "sim"), default="real")
    parser.add_argument("--features", type=Path, default=SIM)
    parser.add_argument("--groups", type=int, default=10)
    parser.add_argument("--repetitions", type=int, default=10)
    parser.add_argument("--objects", type=int, default=5, help="objects per group (sim)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--actions", nargs="*", default=None)
    parser.add_argument("--candidates", nargs="*", default=list(CANDIDATES))
    parser.add_argument("--out", type=Path, default=None, help="write the rows as parquet")
    parser.add_argument(
        "--rows", type=Path, default=None, help="report rows written before, or a study's results"
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="one group and repetition of one action on the committed recordings (a check)",
    )
    args = parser.parse_args()
    if args.quick:
        from _quick import quick_features  # noqa: PLC0415

        args.data, args.features, args.groups, args.repetitions = "sim", quick_features(), 1, 1
        args.workers, args.actions, args.objects = 1, args.actions or ["P1"], 3
    names = list(args.candidates)
    if args.rows is not None:
        rows = pl.read_parquet(args.rows)
        if "seconds" not in rows.columns:  # a fusion study's results.parquet
            rows = rows.with_columns(pl.lit(0.0).alias("seconds"))
            names = ["multi-modal"]
        report(rows, names)
        return
    if args.data == "real":
        tasks: list[Any] = [(g, args.repetitions, names) for g in range(args.groups)]
        frames = run_tasks(real_task, tasks, workers=args.workers)
    else:
        frame = pl.read_parquet(args.features)
        objects = tuple(sorted(set(frame["object_id"])))
        config = StudyConfig(
            out=Path(),
            fusion_groups=args.groups,
            fusion_repetitions=args.repetitions,
            fusion_objects=args.objects,
            new=objects,
            actions=dataset_actions(frame),
        )
        study = fusion_tasks(frame, config)
        if args.actions:
            study = [t for t in study if t.action in args.actions]
        frames = run_tasks(sim_task, [(t, names) for t in study], workers=args.workers)
    rows = pl.concat(frames)
    if args.out is not None:
        rows.write_parquet(args.out)
    report(rows, names)


if __name__ == "__main__":
    main()
