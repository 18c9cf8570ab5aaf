"""The learner's options on the command line: one set of arguments, one builder.

``learn`` and ``study`` take the same learner arguments (:data:`LEARNER_ARGS`); both build one
:class:`atikt.LearnerOptions` with :func:`learner_from_args`, from the project's default
learner, a file (``--learner-config``: a TOML table of options, or the ``run.json`` /
``study.json`` a run or study wrote, so that it can be repeated), and the flags given, in that
order.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from atikt import FEATURE_BLOCKS, AtiktError, LearnerOptions
from atikt.kernels import PART_KERNELS
from atikt.options import METRIC_CHECKS
from atikt.strategies import strategy_options
from replay.errors import ReplayError
from replay.learning._session import DEFAULT_LEARNER, TRANSFER_MODES
from schemas import TomlLimitError, load_toml
from schemas._cli import arg

if TYPE_CHECKING:
    from schemas._cli import Argument

#: Most bytes of a ``--learner-config`` JSON file (a run.json is a few kB).
MAX_JSON_BYTES = 1 << 20
_DEFAULT = DEFAULT_LEARNER


def _sd(text: str) -> float | None:
    """``none`` (maximum likelihood, the thesis) or a number."""
    if text.strip().lower() == "none":
        return None
    try:
        return float(text)
    except ValueError:
        msg = f"{text!r}: give a positive standard deviation (e.g. 5) or none"
        raise argparse.ArgumentTypeError(msg) from None


def _count(text: str) -> int | None:
    """``none`` or a positive integer."""
    if text.strip().lower() == "none":
        return None
    if not text.strip().isdigit() or int(text) < 1:
        msg = f"{text!r}: give a number of observations (1 or more) or none"
        raise argparse.ArgumentTypeError(msg)
    return int(text)


def parse_parts(text: str, option: str) -> tuple[tuple[str, str], ...]:
    """Parse ``BLOCK=KERNEL,..`` (``--fusion-parts``, ``--kernel-parts``).

    Raises:
        ReplayError: A malformed pair, an unknown block or kernel, in one line.
    """
    pairs = []
    for item in filter(None, (p.strip() for p in text.split(","))):
        block, _, kind = item.partition("=")
        if block not in FEATURE_BLOCKS or kind not in PART_KERNELS:
            msg = (
                f"{option} {text!r}: {item!r} is not BLOCK=KERNEL with a block of "
                f"{', '.join(FEATURE_BLOCKS)} and a kernel of {', '.join(PART_KERNELS)}"
            )
            raise ReplayError(msg)
        pairs.append((block, kind))
    return tuple(pairs)


def _transfer_arg(*, baseline: bool) -> Argument:
    """``--transfer``: every registered strategy (``learn``), or those that transfer."""
    modes = [m for m in TRANSFER_MODES if baseline or m != "none"]
    return arg(
        "--transfer",
        default=argparse.SUPPRESS,
        choices=modes,
        help="transfer strategy (prediction: the thesis's model prediction; optimization: rho "
        "by marginal likelihood; density: open-set relatedness; evidence: dependent GP "
        f"evidence gain{'; none: the baseline' if baseline else ''}) (default: "
        f"{_DEFAULT.transfer.name})",
    )


def learner_args(*, baseline: bool) -> tuple[Argument, ...]:
    """The learner's arguments (``baseline``: ``--transfer none`` allowed)."""
    return (
        arg(
            "--learner-config",
            type=Path,
            default=argparse.SUPPRESS,
            metavar="FILE",
            help="learner options from a TOML file (keys as in a run.json's learner table) "
            "or from a run.json / study.json to repeat that run; flags given override it",
        ),
        arg(
            "--budget",
            type=int,
            default=argparse.SUPPRESS,
            help=f"actively collected observations (default: {_DEFAULT.budget})",
        ),
        _transfer_arg(baseline=baseline),
        arg(
            "--max-sources",
            type=int,
            default=argparse.SUPPRESS,
            help="old objects transferred at once per new object and action (1: the thesis; "
            "prediction, density, evidence) (default: 1)",
        ),
        arg(
            "--hyper-sd",
            type=_sd,
            default=argparse.SUPPRESS,
            metavar="SD|none",
            help="sd of a Gaussian prior on the classifiers' log hyperparameters around the "
            f"initial kernel; none: maximum likelihood as in the thesis (default: "
            f"{_DEFAULT.hyper_sd})",
        ),
        arg(
            "--metric-sd",
            type=_sd,
            default=argparse.SUPPRESS,
            metavar="SD|none",
            help="metric transfer: the new objects' classifiers start from the old objects' "
            "kernel, with a Gaussian prior of this sd around it; none: as in the thesis "
            f"(default: {_DEFAULT.metric_sd})",
        ),
        arg(
            "--metric-check",
            default=argparse.SUPPRESS,
            choices=METRIC_CHECKS,
            help="when the old objects' kernel is used: the new objects' evidence is at least "
            "as large there (evidence), it separates them at least as well (separation), "
            f"either, or always (none) (default: {_DEFAULT.metric_check})",
        ),
        arg(
            "--metric-until",
            type=_count,
            default=argparse.SUPPRESS,
            metavar="N|none",
            help="the old objects' kernel centres a new object's hyperprior while it has at "
            "most N observations of the action; none: always (default: "
            f"{_DEFAULT.metric_until})",
        ),
        arg(
            "--transfer-from",
            type=int,
            default=argparse.SUPPRESS,
            metavar="N",
            help="a new object borrows no old object's observations until it has N "
            "observations of the action; 1: from the first, as in the thesis (default: "
            f"{_DEFAULT.transfer_from})",
        ),
        arg(
            "--kernel-parts",
            default=argparse.SUPPRESS,
            metavar="BLOCK=KERNEL,..",
            help="the learners' kernel per feature block "
            f"({', '.join(PART_KERNELS)}; RBF where not named, the thesis)",
        ),
    )


#: The flags of :func:`learner_args` and the option each sets.
_FLAGS = {
    "budget": "--budget",
    "transfer": "--transfer",
    "max_sources": "--max-sources",
    "hyper_sd": "--hyper-sd",
    "metric_sd": "--metric-sd",
    "metric_check": "--metric-check",
    "metric_until": "--metric-until",
    "transfer_from": "--transfer-from",
    "kernel_parts": "--kernel-parts",
}


def _check_flags(given: dict[str, Any]) -> None:
    """Refuse flag values out of range, naming the flag (before any work).

    Raises:
        ReplayError: One line naming the flag, the value and the fix.
    """
    budget, sources = given.get("budget"), given.get("max_sources")
    if budget is not None and budget < 0:
        msg = f"--budget {budget}: give 0 or more observations"
        raise ReplayError(msg)
    if sources is not None and sources < 1:
        msg = f"--max-sources {sources}: give 1 (the thesis) or more"
        raise ReplayError(msg)
    start = given.get("transfer_from")
    if start is not None and start < 1:
        msg = f"--transfer-from {start}: give 1 (from the first observation) or more"
        raise ReplayError(msg)
    for name in ("hyper_sd", "metric_sd"):
        value = given.get(name)
        if value is not None and not 0 < value < math.inf:
            msg = f"{_FLAGS[name]} {value}: give a positive standard deviation, e.g. 5, or none"
            raise ReplayError(msg)


def read_learner_file(path: Path) -> dict[str, Any]:
    """The learner options of a TOML file (top level or ``[learner]``) or a run/study JSON.

    Raises:
        ReplayError: Unreadable, malformed, or without a learner table; one line.
    """
    try:
        if path.suffix == ".json":
            with path.open("rb") as file:
                raw = file.read(MAX_JSON_BYTES + 1)
            if len(raw) > MAX_JSON_BYTES:
                msg = f"--learner-config {path}: over {MAX_JSON_BYTES} bytes; give a run.json"
                raise ReplayError(msg)
            table = json.loads(raw)
        else:
            table = load_toml(path)
    except (OSError, UnicodeDecodeError, ValueError, TomlLimitError) as err:
        msg = f"--learner-config {path}: cannot read it ({err}); give a TOML or run.json file"
        raise ReplayError(msg) from err
    if isinstance(table, dict) and isinstance(table.get("learner"), dict):
        table = table["learner"]
    if not isinstance(table, dict):
        msg = f"--learner-config {path}: no table of learner options (a run.json has one)"
        raise ReplayError(msg)
    return table


def learner_from_args(args: argparse.Namespace) -> LearnerOptions:
    """Build the learner's options once: the default, then ``--learner-config``, then flags.

    The flags are declared with ``default=argparse.SUPPRESS``: a flag not given is absent.

    Raises:
        ReplayError: A flag or file option out of range or unknown; one line naming it.
    """
    given = {name: getattr(args, name) for name in _FLAGS if hasattr(args, name)}
    _check_flags(given)
    if isinstance(given.get("kernel_parts"), str):
        given["kernel_parts"] = parse_parts(given["kernel_parts"], "--kernel-parts")
    path = getattr(args, "learner_config", None)
    values = {} if path is None else read_learner_file(path)
    try:
        base = DEFAULT_LEARNER.replace(**values) if values else DEFAULT_LEARNER
    except AtiktError as err:
        msg = f"--learner-config {path}: {err}"
        raise ReplayError(msg) from err
    try:
        return _with_flags(base, given)
    except AtiktError as err:
        flags = " ".join(f"{_FLAGS[k]} {v}" for k, v in given.items())
        msg = f"{flags}: {err}"
        raise ReplayError(msg) from err


def _with_flags(base: LearnerOptions, given: dict[str, Any]) -> LearnerOptions:
    """``base`` with the flags' options.

    Another ``--transfer`` than the base's keeps the base strategy's options it also has
    (e.g. ``max_sources`` from ``prediction`` to ``density``).
    """
    changes = dict(given)
    transfer = changes.pop("transfer", None)
    if transfer is not None and transfer != base.transfer.name:
        owners = strategy_options()
        kept = {k: v for k, v in base.transfer.options().items() if transfer in owners[k]}
        base = base.replace(transfer=transfer, **kept)
    return base.replace(**changes) if changes else base
