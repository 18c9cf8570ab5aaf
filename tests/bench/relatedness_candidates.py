"""Transfer estimates on the simulated dataset: counterpart choice and gains, 95 % intervals.

Every new object of the catalog names its designed counterpart among the old objects
(``related_to`` in recorder/data/objects.toml). For each transfer mode this runs, with the
protocol and seeds of the studies in replay/studies/ (ATIKT and the no-transfer baseline on
the same splits):

- the ``priors`` study's runs (random groups of 3, 5, 7, 10 prior objects);
- the ``negative`` study's runs (the 3 old objects least like the new ones);
- ``related``: the same runs with the 3 old objects most like the new ones (the same
  similarity, ``replay/studies/_relatedness.py``);
- ``single-action``: the ``single-action`` study's runs (groups of 3, one action at a time);

and prints the mean gain (ATIKT minus baseline, points; at step 0 and over steps 1..budget)
with a paired 95 % bootstrap interval over prior groups, and how often a step's transfer
choice for the explored object is its counterpart (when the counterpart is among the priors),
any other old object, or nothing.

``related`` runs on the ``negative`` study's splits (the same seeds): with both, the script
also prints related minus dissimilar, paired run by run, and rho (the transfer weight a step
gave the explored object's classifier; 0: no prior admitted) by the number of observations
of that object and action after the step, for each group. ``--recordings DIR --new a,b,..``
runs the same on a lab's dataset (its features extracted or updated first); objects without
a catalogued counterpart are left out of the choice rates. Where relatedness is known rather
than estimated, ``--related-priors a,b --dissimilar-priors c,d`` name the two groups and
``--counterparts new=old,..`` each new object's relative (e.g. the iCub grasps: the same
bottle or can at another fill level).

Run: ``python tests/bench/relatedness_candidates.py --modes prediction density density+3
[--trials 5] [--groups 10] [--workers 2]`` (``+3``: at most 3 sources at once;
``@name=value``: a learner option, e.g. ``density@eps_density=0.05``; ``@hyper_sd=none``:
maximum likelihood learners, as in the thesis, instead of the tool's default hyperprior).
``--quick``: the first mode, the two similarity groups, one run each of budget 2 on the
committed recordings (a check that the script runs).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import sys
import tomllib
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # this checkout's packages

from replay.learning._cachedir import feature_cache_path
from replay.learning._datasets import dataset_roles
from replay.learning._features import build_features
from replay.learning._parallel import run_tasks
from replay.learning._session import DEFAULT_LEARNER, learner_options
from replay.studies._negative import similarity_tasks
from replay.studies._priors import priors_tasks
from replay.studies._running import StudyConfig, dataset_actions
from replay.studies._transfer import run_transfer_task, transfer_tasks

ROOT = Path(__file__).resolve().parents[2]
STUDY_NAMES = ("priors", "negative", "related", "single-action")
BY = {"priors": ["n_priors"], "single-action": ["actions"]}
"""The columns a study's gains are reported by (besides the prior group)."""
SIM = Path.home() / ".cache/atikt/sim2-seed0-schema2-v0.2.0/features.parquet"


def counterparts() -> dict[str, str]:
    """New object id -> its designed counterpart among the old objects."""
    with (ROOT / "recorder/data/objects.toml").open("rb") as handle:
        catalog = tomllib.load(handle)
    return {
        k: v["related_to"] for k, v in catalog.items() if isinstance(v, dict) and "related_to" in v
    }


def run(args: tuple[Any, dict[str, float | str | None]]) -> pl.DataFrame:
    """One study task with the mode's options (``max_sources``, ``eps_density``, ``hyper_sd``,
    ...) over the study's learner; the baseline keeps the options that are not the strategy's.
    """
    task, options = args
    settings = {
        k: int(v) if k == "max_sources" and isinstance(v, float) else v for k, v in options.items()
    }
    sources = int(settings.pop("max_sources", 1) or 1)
    learner = learner_options(task.learner.transfer.name, max_sources=sources, **settings)
    return run_transfer_task(replace(task, learner=replace(learner, budget=task.learner.budget)))


def value(text: str) -> float | str | None:
    """An option's value: ``none`` -> None, a number, else the text (``metric_check=either``)."""
    if text == "none":
        return None
    try:
        return float(text)
    except ValueError:
        return text


def parse(name: str) -> tuple[str, dict[str, float | str | None]]:
    """``"density+3@eps_density=0.05"`` -> ("density", {"max_sources": 3, "eps_density": 0.05})."""
    head, *settings = name.split("@")
    mode, _, sources = head.partition("+")
    options: dict[str, float | str | None] = {"max_sources": float(sources or 1)}
    options |= {k: value(v) for k, v in (s.split("=") for s in settings)}
    return mode, options


def bootstrap(values: np.ndarray, rng: np.random.Generator, n: int = 4000) -> tuple[float, float]:
    """95 % percentile interval of the mean of ``values``."""
    means = rng.choice(values, size=(n, values.shape[0])).mean(axis=1)
    return float(np.percentile(means, 2.5)), float(np.percentile(means, 97.5))


def gains(frame: pl.DataFrame, by: list[str], budget: int) -> pl.DataFrame:
    """Per prior group (and ``by``): initial and mean-over-steps gain in points."""
    runs = frame.group_by([*by, "group", "trial", "method"]).agg(
        pl.col("accuracy").filter(pl.col("step") == 0).first().alias("initial"),
        pl.col("accuracy").filter(pl.col("step").is_between(1, budget)).mean().alias("mean"),
    )
    wide = runs.pivot(on="method", index=[*by, "group", "trial"], values=["initial", "mean"])
    paired = wide.with_columns(
        ((pl.col(f"{c}_ATIKT") - pl.col(f"{c}_baseline")) * 100).alias(c)
        for c in ("initial", "mean")
    )
    means = paired.group_by([*by, "group"]).agg(pl.col("initial").mean(), pl.col("mean").mean())
    return means.sort([*by, "group"])  # group_by keeps no order: the bootstrap needs one


def choices(frame: pl.DataFrame, related: dict[str, str]) -> dict[str, float]:
    """Rates of the explored object's transfer choice after each step (ATIKT runs).

    A step row names the explored new object (``object``), the old object transferred to its
    classifier (``prior``, empty for none) and the run's prior objects (``priors``).
    """
    steps = frame.filter(
        (pl.col("method") == "ATIKT") & (pl.col("step") >= 1) & pl.col("object").is_in(related)
    )
    counts = {"counterpart": 0, "other": 0, "none": 0, "absent_other": 0, "absent_none": 0}
    for row in steps.select("object", "prior", "priors").iter_rows(named=True):
        priors = row["priors"].split(",")
        target = related[row["object"]]
        chosen = row["prior"] or None
        if target in priors:
            key = "none" if chosen is None else ("counterpart" if chosen == target else "other")
        else:
            key = "absent_none" if chosen is None else "absent_other"
        counts[key] += 1
    present = counts["counterpart"] + counts["other"] + counts["none"]
    absent = counts["absent_other"] + counts["absent_none"]
    return {
        "counterpart chosen": counts["counterpart"] / max(present, 1),
        "other chosen (counterpart present)": counts["other"] / max(present, 1),
        "nothing (counterpart present)": counts["none"] / max(present, 1),
        "something chosen (counterpart absent)": counts["absent_other"] / max(absent, 1),
        "steps with counterpart present": present,
        "steps with counterpart absent": absent,
    }


def report(name: str, frame: pl.DataFrame, by: list[str], budget: int, rng: Any) -> None:
    """Print the gains with intervals per ``by``."""
    table = gains(frame, by, budget)
    keys = sorted(set(table[by[0]])) if by else [None]
    for key in keys:
        part = table if key is None else table.filter(pl.col(by[0]) == key)
        cells = []
        for column in ("initial", "mean"):
            values = part[column].to_numpy()
            low, high = bootstrap(values, rng)
            cells.append(f"{column} {values.mean():+.1f} [{low:+.1f}, {high:+.1f}]")
        label = "" if key is None else f"{by[0]}={key} "
        print(f"  {name} {label}({part.height} groups): " + ", ".join(cells))


def observations(frame: pl.DataFrame) -> pl.DataFrame:
    """ATIKT step rows with ``n``: the explored object's observations of the action after it.

    Every new object starts with one observation per action (the initial round); each step
    adds one to the object and action it explored.
    """
    run = [c for c in ("group", "trial", "repetition") if c in frame.columns]
    steps = frame.filter((pl.col("method") == "ATIKT") & (pl.col("step") >= 1)).sort(*run, "step")
    return steps.with_columns(
        (pl.int_range(pl.len()).over([*run, "object", "action"]) + 2).alias("n")
    )


def rho_table(frames: dict[str, pl.DataFrame], counts: tuple[int, ...] = (2, 3, 5)) -> None:
    """Print rho by the number of observations after the step, per prior group."""
    print("rho of the explored object's classifier (0: no prior admitted), by observations n:")
    for name, frame in frames.items():
        rows = observations(frame)
        for n in counts:
            values = rows.filter(pl.col("n") == n)["rho"].to_numpy()
            if values.size == 0:
                continue
            admitted = values[values > 0]
            spread = (
                "median {:.2f} [{:.2f}, {:.2f}] (quartiles of admitted)".format(
                    *np.percentile(admitted, [50, 25, 75])
                )
                if admitted.size
                else "none admitted"
            )
            print(
                f"  {name:8s} n = {n}: {values.size:4d} steps, admitted "
                f"{admitted.size / values.size:5.1%}, {spread}"
            )


def paired_related(frames: dict[str, pl.DataFrame], budget: int, rng: Any) -> None:
    """Print related minus dissimilar (ATIKT on the same splits), paired by run."""
    related, negative = frames["related"], frames["negative"]
    base = [f.filter(pl.col("method") == "baseline").sort("group", "step") for f in frames.values()]
    same = base[0]["accuracy"].equals(base[1]["accuracy"])
    print(f"related minus dissimilar, ATIKT, paired by run (baselines identical: {same})")
    both = pl.concat(
        [
            frame.filter(pl.col("method") == "ATIKT").with_columns(pl.lit(name).alias("method"))
            for frame, name in ((negative, "baseline"), (related, "ATIKT"))
        ],
        how="diagonal_relaxed",
    )
    report("related-negative", both, [], budget, rng)


def compare(directory: Path, first: str, second: str, budget: int) -> None:
    """Print ``second`` minus ``first`` (ATIKT runs, same splits and seeds), paired by run."""
    rng = np.random.default_rng(0)
    for study in STUDY_NAMES:
        a, b = (directory / f"{study}-{m}.parquet" for m in (first, second))
        if not (a.exists() and b.exists()):
            continue
        both = pl.concat(
            [
                pl.read_parquet(path)
                .filter(pl.col("method") == "ATIKT")
                .with_columns(pl.lit(name).alias("method"))
                for path, name in ((a, "baseline"), (b, "ATIKT"))
            ],
            how="diagonal_relaxed",
        )
        print(f"{study}: {second} minus {first}, points [95 % bootstrap over groups]")
        report(study, both, BY.get(study, []), budget, rng)


def arguments() -> argparse.Namespace:
    """Parse the command line (``--quick`` filled in)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--modes", nargs="+", default=["prediction", "density"])
    parser.add_argument("--features", type=Path, default=SIM)
    parser.add_argument("--groups", type=int, default=10)
    parser.add_argument("--trials", type=int, default=5)
    parser.add_argument("--budget", type=int, default=40)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--studies", nargs="+", choices=STUDY_NAMES, default=["priors", "negative"])
    parser.add_argument("--out", type=Path, default=None, help="directory for the rows")
    parser.add_argument(
        "--recordings", type=Path, default=None, help="a dataset instead of --features"
    )
    parser.add_argument("--new", default=None, help="comma-separated new objects (--recordings)")
    parser.add_argument("--related-priors", default=None, help="the related group, a,b,..")
    parser.add_argument("--dissimilar-priors", default=None, help="the dissimilar group, a,b,..")
    parser.add_argument(
        "--counterparts", default=None, help="each new object's relative: new=old,.."
    )
    parser.add_argument(
        "--compare", nargs=2, metavar=("FIRST", "SECOND"), help="modes whose rows --out holds"
    )
    parser.add_argument(
        "--quick", action="store_true", help="one run of budget 2 on the committed recordings"
    )
    args = parser.parse_args()
    if args.quick:
        from _quick import quick_features  # noqa: PLC0415

        args.features, args.groups, args.trials, args.budget = quick_features(), 1, 1, 2
        args.workers, args.modes = 1, args.modes[:1]
        args.studies = ["negative", "related"]  # the paired comparison and rho's table too
    return args


def study_tasks(
    study: str, frame: pl.DataFrame, config: StudyConfig, named: dict[str, tuple[str, ...]]
) -> list[Any]:
    """Return a study's tasks; the similarity groups' runs on the ``negative`` study's splits.

    ``named``: the ``related`` and ``negative`` groups where they are given, not estimated.
    """
    if study == "priors":
        return priors_tasks(frame, config)
    if study == "single-action":  # the study's groups, one action at a time
        return transfer_tasks(frame, config, single_action=True)
    nearest = study == "related"  # one group: runs are the resampling unit
    tasks = similarity_tasks(
        frame, config, study, nearest=nearest, splits_of="negative", priors=named.get(study)
    )
    return [replace(t, labels=t.labels | {"group": i}) for i, t in enumerate(tasks)]


def run_mode(name: str, frame: pl.DataFrame, config: StudyConfig, args: argparse.Namespace) -> None:
    """Run every study of ``--studies`` for one mode and print its tables."""
    mode, options = parse(name)
    config = replace(config, learner=DEFAULT_LEARNER.replace(budget=args.budget, transfer=mode))
    rng = np.random.default_rng(0)
    related = (
        dict(pair.split("=") for pair in args.counterparts.split(","))
        if args.counterparts
        else counterparts()
    )
    named = {
        study: tuple(group.split(","))
        for study, group in (("related", args.related_priors), ("negative", args.dissimilar_priors))
        if group
    }
    print(f"\n## transfer={mode}, {options}")
    frames: dict[str, pl.DataFrame] = {}
    for study in args.studies:
        tasks = study_tasks(study, frame, config, named)
        jobs = [(t, options) for t in tasks]
        rows = pl.concat(run_tasks(run, jobs, workers=args.workers), how="diagonal_relaxed")
        frames[study] = rows
        if args.out is not None:
            args.out.mkdir(parents=True, exist_ok=True)
            rows.write_parquet(args.out / f"{study}-{name}.parquet")
        if study not in {"priors", "single-action"}:
            print(f"{study}: priors {', '.join(tasks[0].priors)}")
        print(f"{study}: gain, points [95 % bootstrap over groups]")
        report(study, rows, BY.get(study, []), args.budget, rng)
        base = rows.filter(pl.col("method") == "baseline")
        first = float(base.filter(pl.col("step") == 0)["accuracy"].mean())  # type: ignore[arg-type]
        steps = pl.col("step").is_between(1, args.budget)
        later = float(base.filter(steps)["accuracy"].mean())  # type: ignore[arg-type]
        print(f"  baseline accuracy: step 0 {first:.1%}, mean 1..{args.budget} {later:.1%}")
        for key, value in choices(rows, related).items():
            print(f"  {key}: {value:.3f}" if isinstance(value, float) else f"  {key}: {value}")
    similar: dict[str, pl.DataFrame] = {
        k: frames[k] for k in ("negative", "related") if k in frames
    }
    if len(similar) == len(("negative", "related")):
        paired_related(similar, args.budget, rng)
    if similar:
        rho_table(similar)


def main() -> None:
    """Run the studies' tasks for every mode and print the tables."""
    args = arguments()
    if args.compare:
        first, second = args.compare
        compare(args.out, first, second, args.budget)
        return
    root = args.features.parent
    if args.recordings is not None:
        root = args.recordings
        build_features(root, workers=args.workers)
        args.features = feature_cache_path(root)
    frame = pl.read_parquet(args.features)
    new = args.new.split(",") if args.new else None
    roles = dataset_roles(root, sorted(set(frame["object_id"])), new=new)
    config = StudyConfig(
        out=Path(),
        groups=args.groups,
        trials=args.trials,
        learner=DEFAULT_LEARNER,
        new=roles.new,
        old=roles.old,
        actions=dataset_actions(frame),
    )
    for name in args.modes:  # "density", "density+3" (at most 3 sources), "density@key=value"
        run_mode(name, frame, config, args)


if __name__ == "__main__":
    main()
