"""Subcommands of ``atikt-replay`` that learn: ``features``, ``learn`` and ``study``."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import difflib
import hashlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

import polars as pl
from rich.console import Console
from rich.markup import escape

from atikt import transfer_strategy
from atikt.kernels import COMBINATIONS, PART_KERNELS
from replay.cli._main import WORKERS, arg, command, progress_bar
from replay.cli._options import learner_args, learner_from_args, parse_parts
from replay.errors import ReplayError
from replay.learning._budget import LIVE_TEST_TRIALS, budget_line, held_out_trials
from replay.learning._cachedir import feature_cache_path
from replay.learning._datasets import check_names, dataset_roles
from replay.learning._executors import FeatureLookup, PoolExecutor, Split
from replay.learning._features import FEATURE_POLICIES, FeatureTable, build_features
from replay.learning._parallel import scheduler_warning
from replay.learning._run_history import HISTORY_NAME, SETTINGS_NAME
from replay.learning._session import (
    TRANSFER_MODES,
    RunSpec,
    borrow_pairs,
    fit_priors,
    prior_data,
    run_learning,
    run_offline,
)
from replay.studies._fusion_prior import (
    FUSION_PRIORS,
    HYPERPARAMETERS,
    action_parameter_names,
    kernel_record,
    load_hyperparameters,
)
from replay.studies._registry import STUDIES
from replay.studies._running import (
    StudyConfig,
    StudyDoesNotApplyError,
    dataset_actions,
    prior_groups,
)
from schemas import atomic_write, atomic_write_text, cli, dataset_recordings

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

    from rich.progress import Progress

    from atikt import LearnerOptions

_CONSOLE = Console(stderr=True)


def _progress(description: str, unit: str = "") -> tuple[Progress, Callable[[int, int], None]]:
    """Return a rich progress bar on stderr and a ``(done, total)`` callback that drives it.

    ``unit``: what is counted (``recordings``, ``tasks``), printed after the count.
    """
    bar = progress_bar(_CONSOLE)
    task = bar.add_task(description, total=None, unit=unit)

    def update(done: int, total: int) -> None:
        bar.update(task, completed=done, total=total)

    return bar, update


def _dataset(path: Path | None, workers: int) -> Path:
    """Return the dataset to use: the given one, else the default simulated dataset."""
    from replay.live import (  # noqa: PLC0415 (rerun and the simulator on use, not with the command line)
        default_dataset_ready,
        ensure_default_dataset,
    )

    if path is not None:
        if not path.is_dir():
            msg = f"{path}: not a directory; give a dataset directory (atikt-record dataset)"
            raise ReplayError(msg)
        return path
    if default_dataset_ready():
        return ensure_default_dataset(workers=workers)
    bar, update = _progress("recording the default simulated dataset", "recordings")
    with bar:
        return ensure_default_dataset(workers=workers, on_progress=update)


def _check_names_early(root: Path, args: argparse.Namespace) -> None:
    """Check ``--new``, ``--priors`` and ``--actions`` against the dataset's file layout.

    ``<root>/<object>/<action>/<trial>.mcap`` names the objects and actions before any
    feature is extracted; the feature table is checked again after (a recording may be
    quarantined).

    Raises:
        ReplayError: A name is not in the dataset, or an option names no id.
    """
    for option, text in (
        ("--new", args.new),
        ("--priors", args.priors),
        ("--actions", getattr(args, "actions", None)),
    ):
        if text is not None and not _ids(text):  # not the default: a slip
            msg = f"{option} {text!r}: no id; give comma-separated ids, or leave {option} out"
            raise ReplayError(msg)
    parts = [p.relative_to(root).parts for p in dataset_recordings(root)]
    objects = sorted({p[0] for p in parts if len(p) == 3})  # noqa: PLR2004 (the layout)
    actions = sorted({p[1] for p in parts if len(p) == 3})  # noqa: PLR2004
    # --priors names the other dataset's objects with --prior-recordings (checked there)
    other = getattr(args, "prior_recordings", None) is not None
    # a live run records its new objects: they need not be in the priors' dataset (the
    # object catalog and the rig's poses are checked before anything moves)
    objects = sorted({*objects, *_live_new(args)})
    for option, names, known in (
        ("--new", _ids(args.new), objects),
        ("--priors", None if other else _ids(args.priors), objects),
        ("--actions", _ids(getattr(args, "actions", None)), actions),
    ):
        _refuse_unknown(root, option, names or [], known)
    if objects:
        _ = dataset_roles(root, objects, _ids(args.new), None if other else _ids(args.priors))
    if actions and (chosen := _ids(getattr(args, "actions", None))):
        _ = check_names("--actions", chosen, actions)


def _live_new(args: argparse.Namespace) -> list[str]:
    """Return ``--new`` of a live run or of its replay (``--session``), else [].

    A live run records its new objects, and its replay reads them from its session: they
    need not be in the priors' dataset.
    """
    if getattr(args, "rig", None) is None and getattr(args, "session", None) is None:
        return []
    return list(_ids(args.new) or [])


def _refuse_unknown(root: Path, option: str, names: Sequence[str], known: Sequence[str]) -> None:
    """Refuse names the dataset does not have, naming the dataset and the closest known name.

    Raises:
        ReplayError: One line: the unknown names, the dataset, what it has, the closest name.
    """
    if not known or not (unknown := [name for name in names if name not in known]):
        return
    close = difflib.get_close_matches(unknown[0], list(known), n=1)
    guess = f"; did you mean {close[0]}?" if close else ""
    msg = (
        f"{option} {','.join(unknown)}: not in the dataset; it has {', '.join(known)} "
        f"({root}){guess}"
    )
    raise ReplayError(msg)


def _features(root: Path, workers: int) -> FeatureTable:
    """Build or update a dataset's feature cache with a progress bar."""
    bar, update = _progress(f"features of {root}", "recordings")
    with bar:
        table = build_features(root, workers=workers, on_progress=update)
    if table.discarded:
        _CONSOLE.print(f"[yellow]{escape(table.discarded)}", highlight=False, soft_wrap=True)
    for path, reason in table.quarantined.iter_rows():
        _CONSOLE.print(
            f"[yellow]quarantined[/] {escape(f'{path}: {reason}')}", highlight=False, soft_wrap=True
        )
    return table


def _too_few_priors(learner: LearnerOptions, priors: Sequence[str]) -> None:
    """Refuse fewer old objects than the transfer strategy needs.

    Raises:
        ReplayError: The run has too few, naming the strategy and the fix.
    """
    needs = learner.transfer.min_old_objects
    if not learner.transfer.transfers or len(priors) >= needs:
        return
    fewer = [m for m in TRANSFER_MODES if transfer_strategy(m).min_old_objects < needs]
    msg = (
        f"--transfer {learner.transfer.name} needs >= {needs} old objects; the run has "
        f"{len(priors)} ({', '.join(priors) or 'none'}); use --transfer "
        f"{' or '.join(m for m in fewer if m != 'none')}, or give more --priors"
    )
    raise ReplayError(msg)


def _ids(text: str | None) -> list[str] | None:
    """Split a comma-separated option."""
    return None if text is None else [part for part in text.split(",") if part]


_DATASET = arg(
    "--recordings",
    type=Path,
    default=None,
    help="dataset directory (default: the simulated dataset, recorded on first use)",
)
_SEED = arg("--seed", type=cli.seed, default=0, help="seed of every random choice (default: 0)")
_FEATURES = arg(
    "--features",
    default="thesis",
    choices=FEATURE_POLICIES,
    help="feature blocks per action: the thesis's per kind, or all the recording's sensors "
    "give (default: thesis)",
)
_FUSION_PRIOR = arg(
    "--fusion-prior",
    default="others",
    metavar="{" + ",".join(FUSION_PRIORS) + ",FILE}",
    help="fusion study: centre the multi-modal kernel's hyperparameters on those fitted on the "
    "objects outside each group, or where there are none, weight the modalities by their "
    "spread over their sensors' declared noise (others); always the latter (noise); on those "
    f"an earlier fusion study saved in FILE (its {HYPERPARAMETERS}, e.g. of another session "
    "of the same rig); or maximum likelihood on the group alone, as the thesis (none) "
    "(default: others)",
)
_FUSION_KERNEL = arg(
    "--fusion-kernel",
    default="sum",
    choices=COMBINATIONS,
    help="fusion study: combine the per-modality kernels by a weighted sum (the thesis) or a "
    "product (default: sum)",
)
_FUSION_PARTS = arg(
    "--fusion-parts",
    default="",
    metavar="BLOCK=KERNEL,..",
    help=f"fusion study: kernel per feature block, of {', '.join(PART_KERNELS)} (default: rbf "
    "for every block), e.g. texture=matern52",
)
_ROLES = (
    arg("--new", default=None, help="new objects (default: those the dataset declares new)"),
    arg("--priors", default=None, help="old objects to draw priors from (default: the others)"),
    arg("--actions", default=None, help="actions (default: all of the dataset)"),
)


_FORCE = arg(
    "--force", action="store_true", help="replace an existing --out (written aside, then swapped)"
)
_PRIOR_RECORDINGS = arg(
    "--prior-recordings",
    type=Path,
    default=None,
    metavar="DIR",
    help="cross-rig transfer: the old objects' recordings come from this dataset (another rig "
    "or session), through the feature blocks both datasets' actions share; --priors then "
    "names its objects (default: all of them)",
)


def _pairs(text: str) -> dict[str, str]:
    """``T=S,...``: action T borrows the priors' recordings of action S."""
    pairs = {}
    for part in (p.strip() for p in text.split(",") if p.strip()):
        target, sep, origin = part.partition("=")
        if not sep or not target.strip() or not origin.strip():
            msg = f"{part!r}: give ACTION=SOURCE_ACTION pairs, e.g. C1=P1,S3=S1"
            raise argparse.ArgumentTypeError(msg)
        pairs[target.strip()] = origin.strip()
    return pairs


_PRIOR_ACTIONS = arg(
    "--prior-actions",
    type=_pairs,
    default=None,
    metavar="T=S,...",
    help="cross-action transfer: action T's priors are the old objects' recordings of action "
    "S (same feature blocks, e.g. C1=P1,S3=S1); with --prior-recordings, S is an action of "
    "that dataset (default there: the same id, else the first of the same kind)",
)


def _dataset_input(path: Path | None) -> tuple[str, Path]:
    """Return the dataset a command reads, for :func:`schemas.cli.refuse_overlap`."""
    from replay.live import (  # noqa: PLC0415 (rerun and the simulator on use, not with the command line)
        default_dataset_dir,
    )

    if path is not None:
        return ("dataset", path)
    return ("default dataset", default_dataset_dir())


def _output(out: Path | None, default: Path, *, force: bool) -> Path:
    """Return ``--out`` (refused if it exists, unless ``--force``), else a free ``default``."""
    if out is None:
        return cli.numbered_directory(default)
    cli.refuse_existing(out, force=force)
    return out


@command(
    "features",
    "extract (or update) the feature cache of a dataset",
    arg("dataset", type=Path, help="dataset directory"),
    WORKERS,
)
def _features_command(args: argparse.Namespace) -> int:
    table = _features(
        _dataset(args.dataset, cli.worker_count(args.workers)), cli.worker_count(args.workers)
    )
    print(  # noqa: T201 (the command's output)
        f"{table.frame.height} recordings ({table.extracted} extracted, "
        f"{table.quarantined.height} quarantined) -> {feature_cache_path(table.root)}"
    )
    return 0 if table.quarantined.height == 0 else 1


def _step_line(row: dict[str, Any]) -> str:
    """Return the printed line of one learning step."""
    if row["step"] == 0:
        return f"step  0  initial observations           accuracy {100 * row['accuracy']:5.1f} %"
    prior = f"{row['prior']} rho={row['rho']:.2f}" if row["prior"] else "no prior"
    how = "explore" if row["explored"] else "exploit"
    return (
        f"step {row['step']:2d}  {row['object']:>14s} {row['action']:<3s} ({how})  "
        f"{prior:<24s} accuracy {100 * row['accuracy']:5.1f} %"
    )


@command(
    "learn",
    "one active-learning run, offline over recordings or live on a rig",
    arg(
        "--recordings",
        type=Path,
        default=None,
        help="dataset directory; live, where the prior objects' recordings come from "
        "(default: the simulated dataset, recorded on first use)",
    ),
    arg("--rig", default=None, help="run live on this rig (e.g. sim) instead of recordings"),
    arg("--rig-config", type=Path, default=None, help="live: rig TOML (rig = NAME, [options])"),
    arg(
        "--rig-option",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="live: a rig setting over the file's (repeatable)",
    ),
    arg(
        "--new",
        default=None,
        help="new objects, comma-separated (default: those the dataset declares new)",
    ),
    arg(
        "--priors",
        default=None,
        help="prior objects, comma-separated (default: 3 of the others, by seed)",
    ),
    arg("--actions", default=None, help="actions, comma-separated (default: all of the dataset)"),
    _FEATURES,
    *learner_args(baseline=True),
    _PRIOR_RECORDINGS,
    _PRIOR_ACTIONS,
    arg(
        "--test-trials",
        type=cli.trials,
        default=None,
        help=f"live: held-out trials per object/action (default: {LIVE_TEST_TRIALS})",
    ),
    arg("--session", type=Path, default=None, help="replay the split of a recorded live session"),
    arg(
        "--dry-run",
        action="store_true",
        help="live: check everything the run would (the run directory, the objects' poses, "
        "the limits, the disk; connected: the arm's state and a second of the arm's and the "
        "skin's streams) and say what it would do; nothing moves, nothing is written",
    ),
    arg(
        "--view",
        nargs="?",
        const="",
        default=None,
        metavar="FILE.rrd",
        help="live: show each recording in rerun as it is made (a viewer; with FILE.rrd, "
        "write a file instead)",
    ),
    arg(
        "--foxglove",
        nargs="?",
        const="127.0.0.1:8765",
        default=None,
        metavar="HOST:PORT",
        help="live: serve the signals to Foxglove as they arrive (WebSocket, default "
        "127.0.0.1:8765)",
    ),
    arg(
        "--out",
        type=Path,
        default=None,
        help="output directory, never overwritten (default: the first free of "
        "runs/learn-<seed>, runs/learn-<seed>-2, ...)",
    ),
    _FORCE,
    _SEED,
    WORKERS,
)
def _learn_command(args: argparse.Namespace) -> int:
    from replay.live import (  # noqa: PLC0415 (rerun and the simulator on use, not with the command line)
        live_output,
    )

    workers = cli.worker_count(args.workers)
    learner = learner_from_args(args)  # before any work: refused in one line
    _check_live_options(args)
    args.test_trials = held_out_trials(
        args.test_trials, live=args.rig is not None, session=args.session
    )
    if args.rig is not None:  # live: recordings go straight into the run; it resumes
        target = live_output(args.out, Path("runs") / f"learn-{args.seed}", force=args.force)
    else:
        target = _output(args.out, Path("runs") / f"learn-{args.seed}", force=args.force)
    inputs = [_dataset_input(args.recordings), ("--session", args.session)]
    cli.refuse_overlap(target, [*inputs, ("--rig-config", args.rig_config)])
    if args.rig is None:  # a live run resumes into its own recordings (never replaced)
        cli.refuse_irreplaceable(target)
    prior_root = _dataset(args.recordings, workers)  # live: the priors' recordings
    _check_names_early(prior_root, args)
    named = _ids(args.priors) if args.prior_recordings is None else None
    if named is not None:
        _too_few_priors(learner, named)  # before the features
    table = _features(prior_root, workers)
    other = _other_rig(args, workers) if args.prior_recordings is not None else None
    roles = dataset_roles(
        prior_root,
        [*table.frame["object_id"].to_list(), *_live_new(args)],
        _ids(args.new),
        None if other is not None else _ids(args.priors),
    )
    known_actions = dataset_actions(table.frame)
    actions = _ids(args.actions)
    priors = roles.old if other is None else other.objects
    if other is None and args.priors is None and learner.transfer.transfers:
        if not roles.old:
            msg = (
                f"{prior_root}: no old objects to transfer from (all are new); give --priors "
                "or --transfer none"
            )
            raise ReplayError(msg)
        priors = prior_groups(roles.old, min(3, len(roles.old)), 1, args.seed)[0]
    _too_few_priors(learner, priors)
    spec = RunSpec(
        new_objects=roles.new,
        prior_objects=tuple(priors) if other is None else other.labels,
        actions=check_names("--actions", actions, known_actions) if actions else known_actions,
        learner=learner,
        seed=args.seed,
        features=args.features,
    )
    if args.rig is not None:
        ready = _learn_at_rig(args, _Priors(table, prior_root, other), spec, target)
        if args.dry_run:
            return 0 if ready else 1
    else:
        with cli.publish_directory(target, force=args.force) as out:
            _learn_into(args, table, spec, prior_root, out, other=other)
    print(f"history -> {target / HISTORY_NAME}, plot -> {target / 'learning_curve.png'}")  # noqa: T201
    return 0


class _Counted(Protocol):
    """A live view that counts what it could not show (the Foxglove view)."""

    @property
    def dropped(self) -> int:
        """Items not shown."""
        ...

    def behind_line(self) -> str:
        """The line that says which clients missed messages ('': none did)."""
        ...


@dataclass(frozen=True, slots=True)
class _Priors:
    """Where a run's priors come from: the dataset's table, its directory, another rig's."""

    table: FeatureTable
    root: Path
    other: _OtherRig | None

    def identity(self, spec: RunSpec) -> dict[str, object]:
        """Return what identifies the priors: a digest of the prior objects' recordings.

        Their paths in the dataset and their sha256 (the feature table has both, so nothing
        is read again): a moved copy of the dataset is the same priors, a recording changed,
        added or removed is not.
        """
        table, root, objects = self.table, self.root, spec.prior_objects
        if self.other is not None:
            table, root, objects = self.other.table, self.other.root, self.other.objects
        rows = table.frame.filter(pl.col("object_id").is_in(list(objects)))
        digest = hashlib.sha256()
        for path, sha256 in rows.select("path", "sha256").sort("path").iter_rows():
            digest.update(f"{path}\t{sha256}\n".encode())
        return {"dataset": str(root), "recordings": rows.height, "sha256": digest.hexdigest()}


def _learn_at_rig(args: argparse.Namespace, priors: _Priors, spec: RunSpec, target: Path) -> bool:
    """Check, claim and run a live run (or only check it: ``--dry-run``).

    What a run would refuse before anything moves (the objects' poses, the actions against
    the skin, the Foxglove address) is refused before it claims ``target``: a refused run
    leaves no ``live.json`` that would refuse its corrected command.

    Returns:
        Whether the rig was ready (a dry run's answer; True after a run).
    """
    from replay.live import (  # noqa: PLC0415 (rerun and the simulator on use, not with the command line)
        check_plan,
        claim_live_run,
        configured_rig,
        foxglove_view,
        release_unused_claim,
        rig_configuration,
    )

    config = configured_rig(args.rig_config, args.rig, args.rig_option)
    rig = rig_configuration(config, spec.seed)
    settings = _live_settings(args, spec, rig, priors.identity(spec))
    if args.dry_run:
        return _dry_run(args, spec, target, settings)
    check_plan(config, spec)
    with contextlib.ExitStack() as stack:
        fox = None
        if args.foxglove is not None:
            fox = foxglove_view(args.foxglove)
            stack.callback(fox.__exit__, None, None, None)
            print(f"foxglove: live on {fox.url}", file=sys.stderr, flush=True)  # noqa: T201
        resumes = claim_live_run(target, settings)
        try:
            _learn_into(args, priors.table, spec, priors.root, target, other=priors.other, fox=fox)
        except BaseException:
            if not resumes:  # nothing recorded (e.g. the rig did not connect): no claim kept
                release_unused_claim(target, settings)
            raise
    return True


@dataclass(frozen=True, slots=True)
class _OtherRig:
    """The old objects of ``--prior-recordings``: their ids there and their labels in a run.

    Attributes:
        root: The other dataset.
        table: Its feature table.
        objects: The old objects' ids in that dataset.
        labels: The same as ``<dataset directory name>:<id>`` (the run's prior names, so
            that an object of the same id in both datasets is not taken for a new one).
    """

    root: Path
    table: FeatureTable
    objects: tuple[str, ...]
    labels: tuple[str, ...]


def _check_live_options(args: argparse.Namespace) -> None:
    """Settle the live options (the rig named by ``--rig-config``) before any work.

    Raises:
        ReplayError: An unknown rig, or a live-only option without a rig (one line).
    """
    from replay.live import check_rig, configured_rig  # noqa: PLC0415

    if args.rig is None and args.rig_config is not None:
        args.rig = configured_rig(args.rig_config, None, args.rig_option).name
    if args.rig is not None:
        check_rig(args.rig)
    for given, what in (
        (args.view is not None, "--view shows a live run's recordings as they are made"),
        (args.dry_run, "--dry-run checks a live run before anything moves"),
    ):
        if given and args.rig is None:
            msg = f"{what}; give --rig too"
            raise ReplayError(msg)
    if args.view:
        cli.check_new_file(Path(args.view), force=args.force, option="--view")
        cli.refuse_irreplaceable(Path(args.view), "--view")


def _dry_run(
    args: argparse.Namespace, spec: RunSpec, target: Path, settings: dict[str, Any]
) -> bool:
    """Say what a live run would do and whether its rig is ready; move and write nothing.

    Returns:
        False when a source lost samples during the check or sent nothing though its rate
        says it should have (the run's recordings would fail ``check``), else True.
    """
    from replay.live import SESSION_DIR, check_live, check_live_run, configured_rig  # noqa: PLC0415

    resumes = check_live_run(target, settings)
    config = configured_rig(args.rig_config, args.rig, args.rig_option)
    found = check_live(config, spec, target / SESSION_DIR, test_trials=args.test_trials)
    run = f"resumes the run in {target}" if resumes else f"a new run into {target}"
    print(  # noqa: T201
        f"dry run of live learning: {run}; {found.test} held-out recordings, then "
        f"{found.initial} first observations and up to {found.budget} the learner chooses; "
        f"{found.on_disk} on disk (reused); nothing moved, nothing written"
    )
    if found.stale:
        print(  # noqa: T201
            f"{len(found.stale)} unfinished recordings of stopped recorders would be set aside "
            f"(e.g. {found.stale[0]})"
        )
    for line in found.rig.lines():
        print(line)  # noqa: T201
    return found.rig.ready


def _other_rig(args: argparse.Namespace, workers: int) -> _OtherRig:
    """Read ``--prior-recordings`` and choose its old objects (``--priors``, else all).

    Raises:
        ReplayError: Not a dataset, or ``--priors`` names objects it does not have.
    """
    root = _dataset(args.prior_recordings, workers)
    table = _features(root, workers)
    known = sorted(set(table.frame["object_id"].to_list()))
    chosen = _ids(args.priors) or known
    objects = tuple(check_names("--priors", chosen, known))
    return _OtherRig(root, table, objects, tuple(f"{root.name}:{o}" for o in objects))


def _learn_into(
    args: argparse.Namespace,
    table: FeatureTable,
    spec: RunSpec,
    prior_root: Path,
    out: Path,
    *,
    other: _OtherRig | None = None,
    fox: _Counted | None = None,
) -> None:
    """Run the learning and write its history, settings and plot into ``out``.

    ``fox``: a live run's Foxglove view, started before the run claimed ``out``.
    """
    from replay.outputs._plots import plot_learning_curves  # noqa: PLC0415 (matplotlib on use)

    models = None
    if spec.transfers:
        lookup = FeatureLookup(table.frame, spec.features)
        rig = None if other is None else FeatureLookup(other.table.frame, spec.features)
        borrow = args.prior_actions
        if rig is not None:
            borrow = borrow_pairs(lookup, rig, args.prior_actions)
        objects = spec.prior_objects if other is None else other.objects
        data = prior_data(lookup, objects, spec.actions, source=rig, borrow=borrow)
        models = fit_priors(data, args.seed, spec.learner)
    on_step = lambda row: print(_step_line(row), flush=True)  # noqa: E731, T201
    if args.rig is not None:
        frame = _learn_live(args, spec, models, out, on_step, fox=fox)
    else:
        frame = _learn_offline(args, table, spec, models, on_step)
    if line := budget_line(frame, spec.learner, pool=args.rig is None and args.session is None):
        print(line)  # noqa: T201 (the run made fewer steps than its budget)
    try:
        atomic_write(out / HISTORY_NAME, frame.write_parquet)
    except pl.exceptions.PolarsError as err:  # ComputeError "underlying IO error" on a full disk
        msg = f"the run's {HISTORY_NAME} cannot be written ({cli.one_line(str(err))}); free space"
        raise ReplayError(msg) from err
    source = f"rig:{args.rig}" if args.rig else str(args.session or prior_root)
    priors_from = str(prior_root if other is None else other.root)
    settings = {
        "new_objects": list(spec.new_objects),
        "prior_objects": list(spec.prior_objects),
        "actions": list(spec.actions),
        "seed": spec.seed,
        "test_fraction": spec.test_fraction,
        "features": spec.features,
        "learner": spec.learner.as_dict(),  # --learner-config run.json repeats it
        "source": source,
        "priors_from": priors_from,
        "prior_actions": args.prior_actions,
    }
    atomic_write_text(out / SETTINGS_NAME, json.dumps(settings, indent=1) + "\n")
    method = f"ATIKT ({spec.learner.transfer.name})" if spec.transfers else "baseline"
    plot_learning_curves(
        frame.with_columns(pl.lit(method).alias("method")),
        out / "learning_curve.png",
        x="step",
        title=f"learning run, seed {spec.seed}",
    )


def _learn_offline(
    args: argparse.Namespace,
    table: FeatureTable,
    spec: RunSpec,
    models: Any,  # noqa: ANN401
    on_step: Callable[[dict[str, Any]], Any],
) -> pl.DataFrame:
    """Run offline over a dataset, or over a recorded live session with its own split."""
    if args.session is None:
        return run_offline(table.frame, spec, priors=models, on_step=on_step).frame()
    from replay.live import refuse_unfinished_replay  # noqa: PLC0415 (the recorder on use)

    split = Split.from_session(args.session)
    observations = sum(len(trials) for trials in split.pool.values())
    refuse_unfinished_replay(args.session, observations, spec.learner.budget)
    session = _features(args.session, cli.worker_count(args.workers))
    lookup = FeatureLookup(session.frame, spec.features)
    executor = PoolExecutor(lookup, spec.new_objects, split, like_rig=True)
    test = executor.test_set(spec.actions)
    return run_learning(spec, executor, test, models, on_step=on_step).frame()


def _learn_live(
    args: argparse.Namespace,
    spec: RunSpec,
    models: Any,  # noqa: ANN401
    out: Path,
    on_step: Callable[[dict[str, Any]], Any],
    *,
    fox: _Counted | None,
) -> pl.DataFrame:
    """Run live: record test trials first, then every requested observation."""
    from replay.live import (  # noqa: PLC0415 (rerun and the simulator on use, not with the command line)
        SESSION_DIR,
        LiveView,
        configured_rig,
        free_file,
        learn_live,
    )

    config = configured_rig(args.rig_config, args.rig, args.rig_option)
    with contextlib.ExitStack() as stack:
        viewers: list[Any] = [] if fox is None else [fox]
        view = None
        if args.view is not None:
            save = Path(args.view) if args.view else None
            view = LiveView(
                f"live run on {config.name}", save, fallback=free_file(out / "live.rrd")
            )
            if view.note:
                print(view.note, file=sys.stderr, flush=True)  # noqa: T201 (the run goes on)
            viewers.insert(0, stack.enter_context(view).sink)
        frame = learn_live(
            config,
            spec,
            models,
            out / SESSION_DIR,
            test_trials=args.test_trials,
            on_step=on_step,
            viewers=viewers,
        )
    for name, dropped in (
        ("--view", view and view.sink.dropped),
        ("--foxglove", fox and fox.dropped),
    ):
        if dropped:
            print(  # noqa: T201
                f"{name}: the viewer fell behind; {dropped} items were not shown "
                "(the recordings hold everything)",
                file=sys.stderr,
            )
    if fox is not None and (line := fox.behind_line()):
        print(line, file=sys.stderr)  # noqa: T201
    return frame


def _live_settings(
    args: argparse.Namespace,
    spec: RunSpec,
    rig: dict[str, object],
    priors: dict[str, object],
) -> dict[str, Any]:
    """Return what identifies a live run, so that a rerun resumes only the same run.

    ``rig``: the rig's configuration as it describes itself (its content, not the file's
    name); ``priors``: the priors' identity (:meth:`_Priors.identity`).
    """
    return {
        "new_objects": list(spec.new_objects),
        "prior_objects": list(spec.prior_objects),
        "actions": list(spec.actions),
        "seed": spec.seed,
        "features": spec.features,
        "learner": spec.learner.as_dict(),
        "test_trials": args.test_trials,
        "rig": rig,
        "priors": priors,
    }


@command(
    "study",
    f"run a study ({', '.join([*STUDIES, 'all'])})",
    arg("name", choices=[*STUDIES, "all"], help="which study"),
    _DATASET,
    arg(
        "--out",
        type=Path,
        default=None,
        help="output directory, never overwritten; with all, one directory per study inside "
        "it (default: the first free of studies/<name>, studies/<name>-2, ...)",
    ),
    _FORCE,
    arg("--quick", action="store_true", help="a reduced version for a first look"),
    arg(
        "--scheduler",
        default=None,
        metavar="ADDRESS",
        help="run on a Dask cluster (tls://host:8786 or tcp://...). Connect only to a scheduler "
        "you control: results come back pickled, so whoever runs the scheduler or a worker can "
        "run code in this process. tls:// uses Dask's TLS settings (distributed.comm.tls.ca-file, "
        ".client.cert, .client.key in ~/.config/dask/*.yaml or DASK_DISTRIBUTED__COMM__TLS__* "
        "variables); tcp:// is unencrypted and unauthenticated",
    ),
    *learner_args(baseline=False),
    *_ROLES,
    _FEATURES,
    _FUSION_PRIOR,
    _FUSION_KERNEL,
    _FUSION_PARTS,
    _PRIOR_RECORDINGS,
    _PRIOR_ACTIONS,
    _SEED,
    WORKERS,
)
def _study_command(args: argparse.Namespace) -> int:
    # all: a study of another rig's priors only with that rig's recordings
    from replay.outputs._study_report import run_study  # noqa: PLC0415 (matplotlib on use)

    every = [
        n
        for n, s in STUDIES.items()
        if not s.needs_prior_frame or args.prior_recordings is not None
    ]
    names = every if args.name == "all" else [args.name]
    parts = parse_parts(args.fusion_parts, "--fusion-parts")  # refused before any work
    learner = learner_from_args(args)
    if args.fusion_prior not in FUSION_PRIORS and "fusion" in names:
        # a bad file is refused before any work
        load_hyperparameters(Path(args.fusion_prior), kernel_record(args.fusion_kernel, parts))
    targets = {name: _study_output(args, name) for name in names}  # refused before any work
    prior = None if args.fusion_prior in FUSION_PRIORS else Path(args.fusion_prior)
    for target in targets.values():
        cli.refuse_overlap(target, [_dataset_input(args.recordings), ("--fusion-prior", prior)])
        cli.refuse_irreplaceable(target)
    workers = cli.worker_count(args.workers)
    if args.scheduler is not None and (warning := scheduler_warning(args.scheduler)):
        _CONSOLE.print(f"[yellow]{escape(warning)}", highlight=False, soft_wrap=True)
    root = _dataset(args.recordings, workers)
    _check_names_early(root, args)
    table = _features(root, workers)
    roles = dataset_roles(
        root, table.frame["object_id"].to_list(), _ids(args.new), _ids(args.priors)
    )
    known_actions = dataset_actions(table.frame)
    chosen = _ids(args.actions)
    actions = check_names("--actions", chosen, known_actions) if chosen else known_actions
    other = None
    if args.prior_recordings is not None:
        other = _features(_dataset(args.prior_recordings, workers), workers).frame
    base = StudyConfig(
        out=Path(),  # each study's own, below
        seed=args.seed,
        workers=workers,
        scheduler=args.scheduler,
        learner=learner,
        new=roles.new,
        old=roles.old,
        actions=tuple(actions),
        features=args.features,
        fusion_prior=args.fusion_prior,
        action_parameters=action_parameter_names(table.root, table.frame),
        fusion_kernel=args.fusion_kernel,
        fusion_parts=parts,
        prior_frame=other,
        prior_actions=tuple((args.prior_actions or {}).items()),
    )
    base = base.quick() if args.quick else base
    if args.name == "all":  # decided before any study runs
        for name in (n for n in STUDIES if n not in every):  # said, as any study left out
            _CONSOLE.print(
                f"[yellow]skipped[/] study {escape(name)}: it learns from another rig's priors; "
                "give them with --prior-recordings DIR (and --prior-actions)",
                highlight=False,
                soft_wrap=True,
            )
        targets = _studies_to_run(args, targets, table.frame, base)
    for name, target in targets.items():
        with cli.publish_directory(target, force=args.force) as out:
            bar, update = _progress(f"study {name}", "tasks")
            with bar:
                output = run_study(
                    name,
                    table.frame,
                    dataclasses.replace(base, out=out),
                    quarantined=table.quarantined,
                    on_progress=update,
                )
        print(output.text)  # noqa: T201 (the command's output)
        paths = (target / p.name for p in (output.results, output.plot, output.summary))
        print("results -> {}\nplot -> {}\nsummary -> {}".format(*paths))  # noqa: T201
    return 0


def _studies_to_run(
    args: argparse.Namespace, targets: dict[str, Path], frame: pl.DataFrame, base: StudyConfig
) -> dict[str, Path]:
    """Return the studies ``study all`` runs: those that apply and are not finished yet.

    A study the dataset does not fit (a one-action dataset has no cross-action pair) is
    skipped with its line; one already finished in ``--out`` with the same settings (its
    ``study.json``) is kept as it is, so that ``study all`` run again resumes where it
    stopped. A finished study of other settings is refused (``--force`` replaces it).

    Raises:
        ReplayError: A finished study in ``--out`` has other settings (without ``--force``).
    """
    from replay.outputs._study_report import study_options  # noqa: PLC0415 (matplotlib on use)

    chosen = {}
    for name, target in targets.items():
        study = STUDIES[name]
        config = dataclasses.replace(base, out=target)
        try:
            _ = study.tasks(frame, config)
        except StudyDoesNotApplyError as err:
            _CONSOLE.print(
                f"[yellow]skipped[/] {escape(cli.one_line(str(err)))}",
                highlight=False,
                soft_wrap=True,
            )
            continue
        if target.exists() and not args.force:
            if _finished_alike(target, study_options(study, config)):
                _CONSOLE.print(
                    f"study {escape(name)}: finished before with the same settings in "
                    f"{escape(str(target))}; kept",
                    highlight=False,
                    soft_wrap=True,
                )
                continue
            msg = (
                f"--out {target}: holds a {name} study of other settings (its study.json); "
                "give another --out, or --force to replace it"
            )
            raise ReplayError(msg)
        chosen[name] = target
    return chosen


def _finished_alike(target: Path, options: dict[str, Any]) -> bool:
    """Return whether ``target`` holds a finished study of these options (its ``study.json``)."""
    from replay.outputs._study_report import OPTIONS  # noqa: PLC0415 (matplotlib on use)

    try:
        saved = json.loads((target / OPTIONS).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return False
    return bool(saved == json.loads(json.dumps(options)))


def _study_output(args: argparse.Namespace, name: str) -> Path:
    """Return a study's output directory (``--out``, ``--out/<name>`` for all, or numbered)."""
    from replay.outputs._study_report import OPTIONS  # noqa: PLC0415 (matplotlib on use)

    if args.out is None:
        return cli.numbered_directory(Path("studies") / name)
    if args.name == "all" and (Path(args.out) / name / OPTIONS).is_file():
        return Path(args.out) / name  # a finished study: kept when its settings are this run's
    return _output(args.out / name if args.name == "all" else args.out, args.out, force=args.force)
