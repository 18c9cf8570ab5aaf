"""Count how often control crosses between the project's modules in a study task and a run.

Traces (``sys.setprofile``: Python 3.11 has no ``sys.monitoring``) one study task
(``run_transfer_task`` on a small ``TransferTask`` from the cached default dataset) and one
offline run (``run_offline``), and prints how control moves between the modules of the
project's packages (``schemas``, ``recorder``, ``replay``, ``atikt``).

Definitions (every count is over Python frames; C functions are not seen):

- A frame's *module* is the dotted name of its source file when that file lies in one of the
  project's packages (e.g. ``replay.learning._executors``). Any other frame (standard library,
  numpy, polars, a dataclass's generated ``__init__``) is *folded into its caller*: it counts
  as part of the project module that called it, so a project callback run by a library (the
  ``__post_init__`` under a generated ``__init__``) is a call from the module that called the
  library.
- A *stay* is a maximal stretch of execution inside one project module. Each stay begins with
  an *entry* (a call from another module: the caller's module -> this one) or a *return*
  (a callee in another module returns and control comes back here). Hence, per module,
  ``stays = entries + returns``; the first stay is an entry from ``(outside)``, the tracing
  harness.
- *Back-and-forth* of a module is its returns: each one is a stay that resumes after the
  module handed control to another module and got it back. A study task flowing one way
  down (caller passes what the callee needs, callee never comes back) still has one return
  per call it makes; what a refactor can remove is the calls and the returns they cause.
- A *call back up* (``up`` in the tables) is an entry into a module that is already on the
  call stack below the caller (A calls B, B calls back into A, directly or through a third
  module), e.g. ``atikt.optimize`` calling the objective of ``atikt.gpc`` that called it. A
  callback handed down as an object into a module not on the stack (the learner's ``observe``
  into ``replay.learning._executors``, by design) is an ordinary entry.
- *Edges* are the distinct (caller module -> callee module) pairs with their number of calls;
  the returns along an edge equal its calls (every call returns, also by an exception).
- *Distinct* counts the same transitions once per (caller function, callee function)
  pair, so that a loop run 40 times counts once: it does not grow with the budget or the
  trials, and is the number to compare with a reading of the code.

``--packages replay`` follows only ``replay``'s modules (``atikt`` and ``schemas`` are then
folded into their callers: the learner's callbacks into the executor count as calls from
``replay.learning._session``, which runs the learner).

Each traced call runs once untraced first (imports, caches, compiled regexes warmed up), so the
counts do not depend on what an earlier call loaded; with the same arguments they are the same
on every run.

Run (from the checkout to measure; its packages must come first on the path)::

    PYTHONPATH=$PWD python tests/bench/call_flow.py [--budget 4] [--trials 1] [--json FILE]

``--quick`` traces a budget of 2 on the committed recordings (``recordings/data``) instead of
the default dataset: a check that the script runs.

The entry points are given by dotted names so the script survives code moving between
modules: ``--tasks`` (a function ``(frame, config) -> list of tasks``), ``--run`` (a function
``(task) -> table``), ``--config`` (the study options class, built with ``out``, ``groups``,
``trials``, ``budget``, ``new``, ``old``, ``actions``), ``--offline`` (a function
``(frame, spec) -> result``) and ``--spec`` (the run options class, built with
``new_objects``, ``prior_objects``, ``actions``, ``budget``, ``seed``).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import dataclasses
import importlib
import json
import sys
import tempfile
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from types import FrameType

#: The project's packages; frames of any other code are folded into their caller.
PACKAGES = ("schemas", "recorder", "replay", "atikt")
#: The module of the tracing harness (where the traced call comes from and returns to).
OUTSIDE = "(outside)"


def _package_roots(packages: Sequence[str]) -> dict[str, str]:
    """Return each package's directory (with a trailing separator) as imported."""
    roots = {}
    for name in packages:
        package = importlib.import_module(name)
        roots[name] = str(Path(package.__path__[0]).resolve()) + os.sep
    return roots


@dataclass
class Flow:
    """Transitions between project modules seen by one trace.

    Attributes:
        entries: (caller module, callee module) -> calls.
        ups: (caller module, callee module) -> calls into a module already on the stack.
        returns: (callee module, caller module) -> returns from the callee to the caller.
        distinct: (kind, from module, from function, to module, to function) -> how often
            that transition happened (kind ``call`` or ``return``).
    """

    entries: Counter[tuple[str, str]] = field(default_factory=Counter)
    ups: Counter[tuple[str, str]] = field(default_factory=Counter)
    returns: Counter[tuple[str, str]] = field(default_factory=Counter)
    distinct: Counter[tuple[str, str, str, str, str]] = field(default_factory=Counter)


class Tracer:
    """A ``sys.setprofile`` function that follows the project module of the running code.

    The stack holds, per live frame, its effective module (its own for a project frame, its
    caller's for any other) and the project function it belongs to.
    """

    def __init__(self, packages: Sequence[str] = PACKAGES) -> None:
        """Find the followed packages as imported (the checkout on the path first)."""
        self._roots = _package_roots(packages)
        self._modules: dict[str, str | None] = {}
        self._stack: list[tuple[str, str]] = [(OUTSIDE, OUTSIDE)]
        self.flow = Flow()

    def _module(self, filename: str) -> str | None:
        """Return the dotted project module of a source file, or None outside the project."""
        if filename in self._modules:
            return self._modules[filename]
        module = None
        resolved = str(Path(filename).resolve()) if filename.endswith(".py") else ""
        for name, root in self._roots.items():
            if resolved.startswith(root):
                parts = Path(resolved[len(root) :]).with_suffix("").parts
                module = ".".join((name, *parts)).removesuffix(".__init__")
        self._modules[filename] = module
        return module

    def __call__(self, frame: FrameType, event: str, _arg: object) -> None:
        """Record a transition when a call or return changes the effective module."""
        if event == "call":
            module = self._module(frame.f_code.co_filename)
            here = self._stack[-1]
            if module is None:
                self._stack.append(here)
                return
            function = frame.f_code.co_qualname
            if module != here[0]:
                pair = (here[0], module)
                self.flow.entries[pair] += 1
                if any(m == module for m, _ in self._stack):
                    self.flow.ups[pair] += 1
                self.flow.distinct["call", *here, module, function] += 1
            self._stack.append((module, function))
        elif event == "return":
            left = self._stack.pop()
            here = self._stack[-1]
            if left[0] != here[0]:
                self.flow.returns[left[0], here[0]] += 1
                self.flow.distinct["return", *left, *here] += 1


def trace(function: Callable[..., Any], *args: Any, packages: Sequence[str] = PACKAGES) -> Flow:
    """Call ``function(*args)`` once untraced, then once traced; return the traced flow.

    Args:
        function: The call to trace.
        *args: Its arguments.
        packages: The packages followed; code of any other is folded into its caller.
    """
    function(*args)
    tracer = Tracer(packages)
    sys.setprofile(tracer)
    try:
        function(*args)
    finally:
        sys.setprofile(None)
    return tracer.flow


def summary(flow: Flow) -> dict[str, Any]:
    """Return the counts of a flow: per module, totals, edges and distinct transitions."""
    modules = sorted({m for pair in flow.entries for m in pair} - {OUTSIDE})
    per_module = {}
    for module in modules:
        entries = sum(n for (_, to), n in flow.entries.items() if to == module)
        returns = sum(n for (_, to), n in flow.returns.items() if to == module)
        per_module[module] = {
            "entries": entries,
            "returns": returns,
            "stays": entries + returns,
            "back_and_forth": returns,
            "up": sum(n for (_, to), n in flow.ups.items() if to == module),
            "distinct_entries": sum(1 for t in flow.distinct if t[0] == "call" and t[3] == module),
            "distinct_returns": sum(
                1 for t in flow.distinct if t[0] == "return" and t[3] == module
            ),
        }
    totals = {
        key: sum(row[key] for row in per_module.values())
        for key in ("entries", "returns", "stays", "up", "distinct_entries", "distinct_returns")
    }
    edges = [
        {"caller": a, "callee": b, "calls": n, "returns": flow.returns[b, a], "up": flow.ups[a, b]}
        for (a, b), n in sorted(flow.entries.items())
    ]
    distinct = [
        {"kind": kind, "from": f"{a}:{f}", "to": f"{b}:{g}", "count": n}
        for (kind, a, f, b, g), n in sorted(flow.distinct.items())
    ]
    return {"modules": per_module, "totals": totals, "edges": edges, "distinct": distinct}


def _short(module: str) -> str:
    """Drop the ``replay.`` prefix (the tables' most common)."""
    return module.removeprefix("replay.")


def print_summary(title: str, counts: dict[str, Any], *, show_distinct: bool) -> None:
    """Print the per-module table, totals and edges of one trace."""
    print(f"\n## {title}\n")
    head = ("module", "entries", "returns", "stays", "up", "d.entries", "d.returns")
    print(f"{head[0]:<34} " + " ".join(f"{h:>9}" for h in head[1:]))
    keys = ("entries", "returns", "stays", "up", "distinct_entries", "distinct_returns")
    for module, row in counts["modules"].items():
        print(f"{_short(module):<34} " + " ".join(f"{row[k]:>9}" for k in keys))
    totals = counts["totals"]
    print(f"{'total':<34} " + " ".join(f"{totals[k]:>9}" for k in keys))
    print("\nedges (caller -> callee: calls, returns back up, calls back up)")
    for edge in counts["edges"]:
        caller, callee = _short(edge["caller"]), _short(edge["callee"])
        line = f"  {caller} -> {callee}: {edge['calls']} calls, {edge['returns']} returns"
        print(line + (f", {edge['up']} back up" if edge["up"] else ""))
    if show_distinct:
        print("\ndistinct transitions (kind: from -> to: times)")
        for item in counts["distinct"]:
            line = f"  {item['kind']}: {_short(item['from'])} -> {_short(item['to'])}"
            print(f"{line}: {item['count']}")


def _load(dotted: str) -> Any:
    """Return the object named ``package.module:attribute``."""
    module, _, attribute = dotted.partition(":")
    return getattr(importlib.import_module(module), attribute)


def _budget(options: Any, budget: int) -> dict[str, Any]:
    """The budget as the options class takes it: a field, or inside its learner options."""
    names = {f.name for f in dataclasses.fields(options)}
    if "budget" in names:  # the code before the learner's options were one object
        return {"budget": budget}
    from replay.learning._session import DEFAULT_LEARNER  # noqa: PLC0415 (the checkout's)

    return {"learner": DEFAULT_LEARNER.replace(budget=budget)}


def _inputs(args: argparse.Namespace) -> tuple[Any, Any, Any]:
    """Return the feature table, the study options and the run options."""
    from replay.learning._datasets import dataset_roles  # noqa: PLC0415 (the checkout's)
    from replay.learning._features import build_features  # noqa: PLC0415
    from replay.live import ensure_default_dataset  # noqa: PLC0415

    if args.quick:  # the committed recordings instead of the default dataset
        import polars as pl  # noqa: PLC0415
        from _quick import RECORDINGS, quick_features  # noqa: PLC0415

        root, frame = RECORDINGS, pl.read_parquet(quick_features())
    else:
        root = ensure_default_dataset()
        frame = build_features(root).frame
    roles = dataset_roles(root, frame["object_id"].to_list())
    new, old = roles.new[: args.new], roles.old[: args.old]
    actions = tuple(args.actions.split(","))
    frame = frame.filter(frame["object_id"].is_in([*new, *old]) & frame["action_id"].is_in(actions))
    config = _load(args.config)(
        out=Path(tempfile.gettempdir()) / "call_flow",
        groups=1,
        trials=args.trials,
        new=new,
        old=old,
        actions=actions,
        **_budget(_load(args.config), args.budget),
    )
    spec = _load(args.spec)(
        new_objects=new,
        prior_objects=old,
        actions=actions,
        seed=args.seed,
        **_budget(_load(args.spec), args.budget),
    )
    return frame, config, spec


def main() -> int:
    """Trace a study task and an offline run; print the tables (and write JSON)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n", 1)[0])
    parser.add_argument("--tasks", default="replay.studies._transfer:transfer_tasks")
    parser.add_argument("--run", default="replay.studies._transfer:run_transfer_task")
    parser.add_argument("--config", default="replay.studies._running:StudyConfig")
    parser.add_argument("--offline", default="replay.learning._session:run_offline")
    parser.add_argument("--spec", default="replay.learning._session:RunSpec")
    parser.add_argument("--new", type=int, default=3, help="declared new objects used")
    parser.add_argument("--old", type=int, default=3, help="declared old objects used")
    parser.add_argument("--actions", default="P1,S2", help="comma-separated action ids")
    parser.add_argument("--budget", type=int, default=4)
    parser.add_argument("--trials", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--packages",
        default=",".join(PACKAGES),
        help="comma-separated packages to follow (others are folded into their callers)",
    )
    parser.add_argument("--distinct", action="store_true", help="list distinct transitions")
    parser.add_argument("--json", type=Path, default=None, help="write the counts here")
    parser.add_argument(
        "--quick", action="store_true", help="the committed recordings, budget 2 (a check)"
    )
    args = parser.parse_args()
    if args.quick:
        args.budget = min(args.budget, 2)
    frame, config, spec = _inputs(args)
    task = _load(args.tasks)(frame, config)[0]
    packages = tuple(args.packages.split(","))
    results = {
        "study task": summary(trace(_load(args.run), task, packages=packages)),
        "offline run": summary(trace(_load(args.offline), frame, spec, packages=packages)),
    }
    options = {k: v for k, v in vars(args).items() if k != "json"}
    print(f"# call flow ({', '.join(f'{k}={v}' for k, v in options.items())})")
    for title, counts in results.items():
        print_summary(title, counts, show_distinct=args.distinct)
    if args.json is not None:
        args.json.write_text(json.dumps({"options": options} | results, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
