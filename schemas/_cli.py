"""The tiny command-line toolkit that ``atikt-record`` and ``atikt-replay`` share.

``schemas`` holds the recording contract and, beside it, this toolkit: it imports nothing of
the project, so both command lines (the recorder and the replay, which must not depend on each
other) can use it. It gives

- a registry of subcommands (:class:`Registry`, :func:`arg`) and the parser built from it,
  whose usage errors are one line, whose ``--help`` shows every default, and ``--version``;
- :func:`run`: the top level that prints a project error as one line (no traceback) and lets
  any other exception, a bug, keep its traceback;
- :func:`workers`: the ``--workers`` type (an integer of at least 1) and :func:`worker_count`;
  :func:`seed`: the ``--seed`` type of a run (0..2**32-1);
- publishing outputs without overwriting: :func:`numbered_directory` (a fresh name when the
  user named none), :func:`publish_directory` (refuse an existing output unless ``--force``,
  which replaces it by writing a temporary directory and swapping it in), and
  :func:`check_new_file` for single files.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import math
import os
import shutil
import signal
import sys
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, NoReturn

import rich.console
from rich.progress import Progress, ProgressColumn

from schemas._atomic import create_exclusive, temporary_name
from schemas._metadata import MAX_SEED, MAX_TRIAL

if TYPE_CHECKING:
    from collections.abc import Callable, Collection, Iterable, Iterator, Sequence
    from types import FrameType, TracebackType

    from rich.console import Console
    from rich.progress import Task

    #: What ``signal.signal`` takes and returns.
    _Handler = Callable[[int, FrameType | None], Any] | int | signal.Handlers | None

#: Exit status of a refused input (a project error) and of a usage error.
ERROR_STATUS, USAGE_STATUS = 1, 2
#: Exit status after Ctrl-C (128 + SIGINT, as a shell reports it).
INTERRUPTED_STATUS = 130
#: Exit status after SIGTERM (128 + 15, as a shell reports a process ended by it).
TERMINATED_STATUS = 143
#: Exit status after SIGHUP (128 + 1): the terminal or the SSH connection of the run closed.
HUNG_UP_STATUS = 129
#: Exit status after Ctrl-Z (SIGTSTP, 128 + 20) ended a run while it moved an arm.
SUSPENDED_STATUS = 148
#: Exit status after Ctrl-\ (SIGQUIT, 128 + 3) ended a run while it moved an arm.
QUIT_STATUS = 131


class Terminated(KeyboardInterrupt):
    """SIGTERM ended the run: unwound like Ctrl-C (files kept, one line), exit status 143."""

    signal_name: ClassVar[str] = "SIGTERM"
    status: ClassVar[int] = TERMINATED_STATUS


class HungUp(Terminated):
    """SIGHUP ended the run (its terminal or SSH connection closed): as SIGTERM, exit 129.

    Without a handler SIGHUP ends a process at once: a session whose SSH connection dropped
    would leave the arm running its last program and the action's samples unsaved.
    """

    signal_name: ClassVar[str] = "SIGHUP"
    status: ClassVar[int] = HUNG_UP_STATUS


class Suspended(Terminated):
    """Ctrl-Z (SIGTSTP) while a run moves an arm: it ends as after Ctrl-C, exit status 148.

    A suspended recorder would leave the arm unwatched, its limits unchecked, until resumed:
    while the arm moves, Ctrl-Z stops it first, saves what arrived and ends the run (run it
    again to resume). Elsewhere Ctrl-Z suspends as usual.
    """

    signal_name: ClassVar[str] = "SIGTSTP"
    status: ClassVar[int] = SUSPENDED_STATUS


class Quit(Terminated):
    r"""Ctrl-\ (SIGQUIT) while a run moves an arm: it ends as after Ctrl-C, exit status 131.

    By default SIGQUIT ends a process at once (with a core dump): the arm would run its last
    program unwatched and the action's samples would be lost. While the arm moves it stops
    the arm first and saves what arrived; elsewhere it quits as usual.
    """

    signal_name: ClassVar[str] = "SIGQUIT"
    status: ClassVar[int] = QUIT_STATUS


#: The signals that end a run cleanly: Ctrl-C, a plain ``kill`` (SIGTERM) and a closed
#: terminal (SIGHUP, where the platform has it).
ENDING_SIGNALS: tuple[int, ...] = (
    signal.SIGINT,
    signal.SIGTERM,
    *((signal.SIGHUP,) if hasattr(signal, "SIGHUP") else ()),
)


def signal_name(signum: int) -> str:
    """Return a signal's name (``SIGINT``, ``SIGTERM``, ``SIGHUP``, ...)."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def ending(signum: int) -> KeyboardInterrupt:
    """Return the exception that ends a run for an ending signal (Ctrl-C: KeyboardInterrupt)."""
    if signum == signal.SIGTERM:
        return Terminated()
    if signum == getattr(signal, "SIGHUP", None):
        return HungUp()
    if signum == getattr(signal, "SIGTSTP", None):
        return Suspended()
    if signum == getattr(signal, "SIGQUIT", None):
        return Quit()
    return KeyboardInterrupt()


def handled_signals() -> list[int]:
    """Return the ending signals to handle now: SIGHUP not when it is ignored.

    ``nohup`` starts a command with SIGHUP ignored so that it outlives its terminal; it keeps
    running. SIGINT and SIGTERM are always handled (a shell starts background jobs with SIGINT
    ignored, and they must still stop on ``kill -INT``).
    """
    hangup = getattr(signal, "SIGHUP", None)
    return [
        number
        for number in ENDING_SIGNALS
        if number != hangup or signal.getsignal(number) is not signal.SIG_IGN
    ]


class CliError(Exception):
    """A command-line value or an output path is refused; the message names it and the fix."""


@dataclass(frozen=True, slots=True)
class Argument:
    """One ``add_argument`` call: flags and keyword options."""

    flags: tuple[str, ...]
    options: dict[str, Any]


def arg(*flags: str, **options: Any) -> Argument:  # noqa: ANN401 (argparse's own options)
    """Declare an argument of a subcommand, as for ``ArgumentParser.add_argument``."""
    return Argument(flags, options)


@dataclass(frozen=True, slots=True)
class Command:
    """A registered subcommand."""

    name: str
    help: str
    arguments: tuple[Argument, ...]
    run: Callable[[argparse.Namespace], int]


@dataclass(slots=True)
class Registry:
    """The subcommands of one program, in registration order."""

    commands: dict[str, Command] = field(default_factory=dict)

    def command(
        self, name: str, help_text: str, *arguments: Argument
    ) -> Callable[[Callable[[argparse.Namespace], int]], Callable[[argparse.Namespace], int]]:
        """Register the decorated function as subcommand ``name``; it returns the exit status."""

        def register(
            run: Callable[[argparse.Namespace], int],
        ) -> Callable[[argparse.Namespace], int]:
            self.commands[name] = Command(name, help_text, arguments, run)
            return run

        return register


#: Console width when the output is not a terminal: wide enough for any table, uncut.
FILE_WIDTH = 10_000


def output_console(*, stderr: bool = False) -> rich.console.Console:
    """Return a console for tables: the terminal's width, or unlimited when not a terminal.

    rich fits tables to the console, 80 columns when the output is a file or a pipe, and cuts
    cells with an ellipsis; a table written to a file is read whole, so it keeps every column
    at its full width there. Used by ``atikt-replay`` and ``atikt-record`` alike.
    """
    console = rich.console.Console(stderr=stderr)
    if console.is_terminal:
        return console
    return rich.console.Console(stderr=stderr, width=FILE_WIDTH)


def one_line(text: str) -> str:
    """Return ``text`` on one line (an error message printed by a command line)."""
    return " ".join(text.split())


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr (exit status 2)."""

    def error(self, message: str) -> NoReturn:
        """Print ``prog: error: message`` and where help is, then exit with status 2."""
        self.exit(USAGE_STATUS, f"{self.prog}: error: {one_line(message)}; see {self.prog} -h\n")


class _HelpFormatter(argparse.HelpFormatter):
    """Adds ``(default: X)`` to every option's help that has a default and does not say it."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        shown = action.default not in (None, False, argparse.SUPPRESS)
        if shown and "default" not in text and (action.option_strings or action.nargs == "?"):
            return f"{text} (default: %(default)s)"
        return text


def build_parser(
    prog: str, description: str, registry: Registry, version: str
) -> argparse.ArgumentParser:
    """Return the parser of ``prog`` with every subcommand of ``registry``."""
    parser = _Parser(prog=prog, description=description, formatter_class=_HelpFormatter)
    parser.add_argument("--version", action="version", version=f"{prog} {version}")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for entry in registry.commands.values():
        sub = subparsers.add_parser(
            entry.name, help=entry.help, description=entry.help, formatter_class=_HelpFormatter
        )
        for argument in entry.arguments:
            sub.add_argument(*argument.flags, **argument.options)
        sub.set_defaults(run=entry.run)
    return parser


#: A write failed for want of space (stdout redirected to a full disk, or a file's write).
_DISK_FULL = frozenset(
    number for number in (errno.ENOSPC, getattr(errno, "EDQUOT", None)) if number is not None
)


def _drop_stdout() -> None:
    """Point standard output at the null device: its buffer is dropped, not flushed at exit.

    Otherwise the interpreter's last flush fails again and prints "Exception ignored".
    """
    with contextlib.suppress(OSError, ValueError, AttributeError):
        null = os.open(os.devnull, os.O_WRONLY)
        os.dup2(null, sys.stdout.fileno())
        os.close(null)


def _too_long(err: OSError) -> str:
    """Return the one-line message for a path longer than the system allows."""
    name = str(err.filename or "")
    shown = name if len(name) <= 80 else f"{name[:40]}...{name[-30:]}"  # noqa: PLR2004
    return (
        f"the path {shown} ({len(name)} characters) is longer than the system allows "
        f"(a name at most {_NAME_MAX}, a path at most {_PATH_MAX} bytes); give a shorter path"
    )


def _limit(name: str, default: int) -> int:
    """Return a ``pathconf`` limit of the root file system, else ``default``."""
    try:
        return os.pathconf("/", name)
    except (AttributeError, OSError, ValueError):  # Windows has no pathconf
        return default


#: The longest file name and path the system accepts (Linux: 255 and 4096 bytes).
_NAME_MAX, _PATH_MAX = _limit("PC_NAME_MAX", 255), _limit("PC_PATH_MAX", 4096)


def run(
    parser: argparse.ArgumentParser,
    argv: Sequence[str] | None,
    errors: tuple[type[Exception], ...],
    interrupted: str = "interrupted; nothing unfinished was published, run it again to resume",
    recording: Collection[str] = (),
) -> int:
    """Parse ``argv`` and run the chosen subcommand; return its exit status.

    Errors of the project (``errors`` and :class:`CliError`) and a path longer than the
    system allows are printed as one line on stderr with status 1, usage errors with status 2,
    Ctrl-C as ``interrupted`` with status 130; any other exception is a bug and keeps its
    traceback. A closed standard output (``| head`` left) ends a command with status 1,
    quietly as other tools do, except the ``recording`` commands: a session whose ``| tee``
    died must not look finished, so they say so on stderr, with how to resume.
    """
    try:
        args = parser.parse_args(argv)
    except SystemExit as done:  # a usage error (one line printed), --help or --version
        return done.code if isinstance(done.code, int) else USAGE_STATUS * (done.code is not None)
    caught: tuple[type[Exception], ...] = (*errors, CliError)
    try:
        with _quiet_interrupts(), _broken_pipes_raise():
            status: int = args.run(args)
    except caught as err:
        print(f"{parser.prog}: error: {one_line(str(err))}", file=sys.stderr)  # noqa: T201
        return ERROR_STATUS
    except OSError as err:
        if err.errno == errno.ENAMETOOLONG:
            line = _too_long(err)
        elif err.errno in _DISK_FULL:
            _drop_stdout()  # what is still buffered cannot be written either
            where = f"{err.filename}: " if err.filename else ""
            line = f"{where}cannot write ({err.strerror}); free disk space or write elsewhere"
        elif err.errno == errno.EPIPE:  # the reader left (``| head``)
            _drop_stdout()
            if args.command not in recording or getattr(args, "dry_run", False):
                return ERROR_STATUS
            line = f"standard output was closed by its reader (broken pipe); {_after(interrupted)}"
        else:
            raise
        with contextlib.suppress(OSError):
            print(f"{parser.prog}: error: {line}", file=sys.stderr)  # noqa: T201
        return ERROR_STATUS
    except KeyboardInterrupt as err:  # Terminated too (SIGTERM, SIGHUP)
        said = str(err.args[0]) if err.args else ""
        line = f"{said}; {_after(interrupted)}" if said else interrupted
        if isinstance(err, Terminated) and not said:
            line = f"terminated ({err.signal_name}); {_after(interrupted)}"
        with contextlib.suppress(OSError):  # after SIGHUP the terminal may be gone
            print(f"{parser.prog}: {one_line(line)}", file=sys.stderr)  # noqa: T201
        return err.status if isinstance(err, Terminated) else INTERRUPTED_STATUS
    return status


@contextlib.contextmanager
def _broken_pipes_raise() -> Iterator[None]:
    """Let a broken pipe met by a rich console reach :func:`run` as the ``BrokenPipeError``.

    rich's own handling (``Console.on_broken_pipe``, meant to be replaced) exits the process
    with status 1 at once, which would pass over a recording command's line.
    """

    def reraise(_console: rich.console.Console) -> None:
        raise  # noqa: PLE0704 (called by rich inside its 'except BrokenPipeError')

    kept = rich.console.Console.on_broken_pipe
    rich.console.Console.on_broken_pipe = reraise  # type: ignore[method-assign,assignment]
    try:
        yield
    finally:
        rich.console.Console.on_broken_pipe = kept  # type: ignore[method-assign]


def _after(interrupted: str) -> str:
    """Return what an interruption message says after its first word (``interrupted; ...``)."""
    return interrupted.partition("; ")[2] or interrupted


#: The warning filter handed to the process pool's resource tracker (see
#: :func:`workers_ignore_interrupts`): its messages start with ``resource_tracker:``.
_QUIET_TRACKER = "ignore:resource_tracker:UserWarning"


@contextlib.contextmanager
def workers_ignore_interrupts() -> Iterator[None]:
    """Start worker processes inside the block with Ctrl-C ignored in them.

    Ctrl-C in a terminal interrupts every process of the foreground group: each worker would
    print its own traceback (or a fatal error while it starts). A signal ignored at ``exec``
    stays ignored, and Python then installs no KeyboardInterrupt handler, so workers spawned
    in this block leave Ctrl-C to the parent, which stops them. Keep the block short: Ctrl-C
    is ignored in this process too while it runs (the spawn itself takes milliseconds).

    The process pool's resource tracker (joblib's loky), started here too, takes this
    interpreter's warning options: it is told not to warn of the semaphores an interrupted run
    leaves it to unlink (it unlinks them; a run interrupted while its pool starts would add
    two warnings after the interruption's one line).
    """
    if _QUIET_TRACKER not in sys.warnoptions:
        sys.warnoptions.append(_QUIET_TRACKER)
    try:
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    except ValueError:  # not the main thread: signals are not ours to handle
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


#: Seconds between two plain progress lines when the output is not a terminal (a log, a pipe,
#: CI): often enough to show the run is alive, rare enough to keep a log readable.
PROGRESS_INTERVAL_S = 5.0


class PlainProgress(Progress):
    """A rich ``Progress`` for output that is not a terminal: a plain line every few seconds.

    rich draws nothing when the console is not a terminal; a long phase then prints nothing
    for minutes. This keeps rich's task bookkeeping and prints, every
    :data:`PROGRESS_INTERVAL_S` (and once at the end of a phase that printed),
    :func:`progress_line` for every task (from a thread, so also while a
    task makes no progress).
    """

    def __init__(self, console: Console, interval_s: float | None = None) -> None:
        """Keep the console; nothing is drawn (``disable``), lines are printed instead."""
        super().__init__(console=console, disable=True)
        self._interval_s = PROGRESS_INTERVAL_S if interval_s is None else interval_s
        self._done = threading.Event()
        self._thread: threading.Thread | None = None
        self._printed = False

    def start(self) -> None:
        """Start printing lines."""
        super().start()
        self._done.clear()
        self._thread = threading.Thread(target=self._report, name="atikt-progress", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        """Stop printing lines."""
        self._done.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        super().stop()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_val: BaseException | None,
        exc_tb: TracebackType | None,
    ) -> None:
        """Stop; print the last state if lines were printed and no error ends the block.

        A phase shorter than the interval prints nothing (a command's output stays its own);
        after an error, its one line is the last.
        """
        self.stop()
        if exc_type is None and self._printed:
            self.print_lines()

    def _report(self) -> None:
        while not self._done.wait(self._interval_s):
            self._printed = True
            self.print_lines()

    def print_lines(self) -> None:
        """Print one :func:`progress_line` per task."""
        for task in self.tasks:
            self.console.print(progress_line(task), highlight=False, soft_wrap=True)


#: Seconds of recent progress the time-left estimate follows.
RECENT_S = 30.0


def progress_line(task: Task) -> str:
    """Return a task's progress as one line for a log.

    ``study transfer: 12/100 tasks, ~40 s left (9 s)``: done of total, the remaining time and
    the time elapsed. The remaining time follows the rate of the last 30 s (the start of
    worker processes does not weigh on it, results arriving together count at their share of
    the window), else the mean time per unit so far. Without a total yet: the count alone;
    nothing done yet: no estimate.
    """
    unit = f" {task.fields['unit']}" if task.fields.get("unit") else ""
    elapsed = task.elapsed or 0.0
    if task.total is None:
        return f"{task.description}: {task.completed:g}{unit} ({elapsed:.0f} s)"
    done = f"{task.description}: {task.completed:g}/{task.total:g}{unit}"
    if task.completed >= task.total:
        return f"{done}, done ({elapsed:.0f} s)"
    if task.completed <= 0:
        return f"{done} ({elapsed:.0f} s)"
    left = elapsed / task.completed * (task.total - task.completed)
    # rich's own estimate divides by the span of its samples: results that arrive together
    # (two workers, or a pool returning finished tasks in order) read as a burst rate ("~1 s
    # left" with half the work to do); here the advances of the last 30 s are divided by the
    # whole 30 s (or the time so far), so a burst counts at its share of the window
    window = min(RECENT_S, elapsed)
    now = task.get_time()
    samples = task._progress  # noqa: SLF001 - rich's last 30 s of advances, no public view
    advanced = sum(sample.completed for sample in samples if sample.timestamp >= now - window)
    if window > 0 and advanced > 0:
        left = (task.total - task.completed) / (advanced / window)
    return f"{done}, ~{left:.0f} s left ({elapsed:.0f} s)"


def progress(console: Console, *columns: str | ProgressColumn) -> Progress:
    """Return a progress display: rich's bar on a terminal, else a :class:`PlainProgress`."""
    if console.is_terminal:
        return Progress(*columns, console=console, transient=False)
    return PlainProgress(console)


def _interrupt(signum: int, frame: object) -> None:
    """Raise KeyboardInterrupt (SIGTERM, SIGHUP: Terminated) once; ignore further ones."""
    del frame
    for number in ENDING_SIGNALS:
        signal.signal(number, signal.SIG_IGN)
    raise ending(signum)


def after_deferred_interrupt(handler: _Handler) -> _Handler:
    """Return the handler to put back after a block that deferred an ending signal.

    The command's own handler (:func:`_interrupt`) raises on the first signal and ignores
    the rest; a block that took the first one itself (an action at the robot: the stop first,
    then what arrived is saved) leaves the rest ignored, as that handler would have, so a
    second Ctrl-C cannot replace the line that names the stop and the file.
    """
    return signal.SIG_IGN if handler is _interrupt else handler


@contextlib.contextmanager
def _quiet_interrupts() -> Iterator[None]:
    """Run the block; after the first Ctrl-C, ignore further ones until the block is left.

    A second Ctrl-C while workers shut down and temporary files are removed would print a
    traceback from inside the clean-up and leave the files; the first one already stops.
    """
    try:
        previous = {number: signal.signal(number, _interrupt) for number in handled_signals()}
    except ValueError:  # not the main thread: signals are not ours to handle
        yield
        return
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


def workers(text: str) -> int:
    """Parse a ``--workers`` value: an integer of at least 1 (argparse ``type``).

    Raises:
        argparse.ArgumentTypeError: Not an integer, or below 1.
    """
    try:
        value = int(text)
    except ValueError:
        msg = f"{text!r} is not a whole number; give 1 or more worker processes"
        raise argparse.ArgumentTypeError(msg) from None
    if value < 1:
        msg = f"{value}: give 1 or more worker processes (default: all cores)"
        raise argparse.ArgumentTypeError(msg)
    return value


#: Largest seed of a run: numpy's legacy generators take 32-bit seeds.
MAX_RUN_SEED = 2**32 - 1


def seed(text: str) -> int:
    """Parse a ``--seed`` value: a whole number in 0..2**32-1 (argparse ``type``).

    Raises:
        argparse.ArgumentTypeError: Not a whole number, or out of range.
    """
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value <= MAX_RUN_SEED:
        msg = f"{text}: give a whole number in 0..{MAX_RUN_SEED}"
        raise argparse.ArgumentTypeError(msg)
    return value


def _whole(text: str, low: int, high: int, what: str) -> int:
    """Return a whole number in ``low..high``; refuse anything else naming ``what``."""
    try:
        value = int(text)
    except ValueError:
        value = low - 1
    if not low <= value <= high:
        msg = f"{text}: give {what} {low}..{high}"
        raise argparse.ArgumentTypeError(msg)
    return value


def rig_seed(text: str) -> int:
    """Parse a recorder's ``--seed``: a whole number a recording's metadata holds (0..2**63-1).

    Raises:
        argparse.ArgumentTypeError: Not a whole number, or out of range (a larger seed was
            written into recordings that ``check`` then refused).
    """
    return _whole(text, 0, MAX_SEED, "a whole number in")


def trials(text: str) -> int:
    """Parse a number of trials (``--test-trials``): 1..999999, as trials are numbered.

    Raises:
        argparse.ArgumentTypeError: Not a whole number, or out of range.
    """
    return _whole(text, 1, MAX_TRIAL, "a number of trials")


def trial(text: str) -> int:
    """Parse a ``--trial``: a trial number a recording holds (1..999999).

    Raises:
        argparse.ArgumentTypeError: Not a whole number, or out of range.
    """
    return _whole(text, 1, MAX_TRIAL, "a trial number")


#: The host a server the project starts binds unless told otherwise.
LOOPBACK = "127.0.0.1"


#: The largest TCP/UDP port.
MAX_PORT = 65_535


def host_port(text: str) -> tuple[str, int] | None:
    """Return ``(host, port)`` of ``HOST:PORT`` or ``PORT`` (host: loopback); None: no port.

    The port is a whole number in 0..65535 (0: any free port); the caller says what to give.
    """
    host, _, port = text.rpartition(":")
    number = int(port) if port.isascii() and port.isdigit() else -1
    if not 0 <= number <= MAX_PORT:
        return None
    return host or LOOPBACK, number


def port(text: str) -> int:
    """Return a port option's value: a whole number in 0..65535 (0: any free port).

    Raises:
        argparse.ArgumentTypeError: Not a whole number, or out of range.
    """
    address = host_port(text)
    if address is None or ":" in text:
        msg = f"{text}: give a port from 0 (any free port) to {MAX_PORT}"
        raise argparse.ArgumentTypeError(msg)
    return address[1]


#: The largest DDS domain id (the RTPS port mapping leaves room for 0..232).
MAX_DOMAIN_ID = 232


def domain_id(text: str) -> int:
    """Return a ``--domain-id`` option's value: a whole number in 0..232.

    Raises:
        argparse.ArgumentTypeError: Not a whole number, or out of range.
    """
    number = int(text) if text.isascii() and text.isdigit() else -1
    if not 0 <= number <= MAX_DOMAIN_ID:
        msg = f"{text}: give a DDS domain id 0..{MAX_DOMAIN_ID} (ROS_DOMAIN_ID)"
        raise argparse.ArgumentTypeError(msg)
    return number


def seconds(text: str) -> float:
    """Return a duration option's value: a positive finite number of seconds.

    Raises:
        argparse.ArgumentTypeError: Not a number, not finite (nan would never end), or <= 0.
    """
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0 < value < math.inf:
        msg = f"{text}: give a positive number of seconds"
        raise argparse.ArgumentTypeError(msg)
    return value


def worker_count(value: int | None) -> int:
    """Return the worker count: the option's value, else every core."""
    return value if value is not None else os.cpu_count() or 1


def _is_taken(path: Path) -> bool:
    """Return True if ``path`` exists and is not an empty directory."""
    return path.exists() and not (path.is_dir() and not any(path.iterdir()))


def numbered_directory(base: Path) -> Path:
    """Return ``base`` if it is free, else the first free ``base-2``, ``base-3``, ..."""
    candidate, number = base, 1
    while _is_taken(candidate):
        number += 1
        candidate = base.with_name(f"{base.name}-{number}")
    return candidate


#: Names of recorded data (recordings, their unfinished parts, ROS 1 and ROS 2 bags): never
#: replaced by an output, ``--force`` or not.
RECORDED_SUFFIXES = (".mcap", ".mcap.part", ".bag", ".db3")
#: What the outputs ``--force`` replaces are made of (tables, figures, reports, settings, a
#: saved view); a directory holding anything else is not one of them.
OUTPUT_SUFFIXES = (".parquet", ".png", ".svg", ".pdf", ".json", ".md", ".csv", ".txt", ".rrd")
#: Files a file manager leaves in any directory it showed.
_FILE_MANAGERS = frozenset({".DS_Store", "Thumbs.db", "desktop.ini"})


def _irreplaceable(path: Path) -> tuple[Path, bool] | None:
    """Return a file at or below ``path`` that no output replaces, and whether it is recorded.

    A file named as the output (``--save``) is irreplaceable when it is recorded data; below
    a directory, also any file an output of this program does not have (``--out ~`` given by
    mistake). The walk stops at the first one; a directory it cannot list counts as holding
    one (what it holds is unknown, so it is not replaced).
    """
    if not path.is_dir():
        return (path, True) if path.name.endswith(RECORDED_SUFFIXES) else None

    def unreadable(err: OSError) -> None:
        raise err

    try:
        for directory, _, names in os.walk(path, onerror=unreadable):
            for name in names:
                if name.endswith(RECORDED_SUFFIXES):
                    return Path(directory) / name, True
                if not name.endswith(OUTPUT_SUFFIXES) and name not in _FILE_MANAGERS:
                    return Path(directory) / name, False
    except OSError as err:
        return Path(err.filename or path), False
    return None


def refuse_existing(path: Path, *, force: bool, option: str = "--out") -> None:
    """Refuse an existing output unless ``force``.

    Raises:
        CliError: ``path`` exists (a non-empty directory or a file) and ``force`` is False.
    """
    if not force and _is_taken(path):
        msg = (
            f"{option} {path}: exists, and outputs are never overwritten; give another "
            f"{option}, or add --force to replace it"
        )
        raise CliError(msg)


def refuse_irreplaceable(path: Path, option: str = "--out") -> None:
    """Refuse an output ``--force`` must not replace: recorded data, or not an output at all.

    ``--force`` replaces a previous output (a run's, a study's, a saved view); a directory or
    file that holds recordings or bags (a dataset given as ``--out`` by mistake) is never
    replaced: nothing recorded is deleted by the program; nor is a directory holding files no
    output of this program has (a home directory, a project). Commands call it after
    :func:`refuse_overlap` (whose line names the input), and :func:`publish_directory` and
    :func:`publish_file` call it again before they replace anything.

    Raises:
        CliError: ``path`` is or holds recorded data, or files no output has.
    """
    if not _is_taken(path) or (found := _irreplaceable(path)) is None:
        return
    file, recorded = found
    if recorded:
        held = "is recorded data" if file == path else f"holds recorded data ({file})"
        msg = (
            f"{option} {path}: {held}; --force replaces a previous output, never recordings "
            f"or bags: give another {option}"
        )
    else:
        msg = (
            f"{option} {path}: holds files no output of this program has ({file}); --force "
            f"replaces a previous output only: give another {option}"
        )
    raise CliError(msg)


def _within(inner: Path, outer: Path) -> bool:
    """Return True if resolved ``inner`` is ``outer`` or lies below it."""
    return inner == outer or outer in inner.parents


def refuse_overlap(
    out: Path, inputs: Iterable[tuple[str, Path | None]], *, option: str = "--out"
) -> None:
    """Refuse an output that equals, contains or lies inside one of the command's inputs.

    Called by every command that writes (``--out``, ``--save``) before anything is written,
    with or without ``--force``: replacing an output must never delete or replace an input
    (a dataset, a recording being viewed, a catalog, a topic map, a session). Paths are
    compared resolved, so a link to an input is the input.

    Args:
        out: The output path (file or directory; it need not exist).
        inputs: ``(what, path)`` pairs naming each input for the message; None is skipped.
        option: The option that named ``out``.

    Raises:
        CliError: ``out`` equals, contains or lies inside an input.
    """
    target = out.resolve()
    for what, given in inputs:
        if given is None:
            continue
        source = given.resolve()
        how = (
            "is"
            if target == source
            else "contains"
            if _within(source, target)
            else "lies inside"
            if _within(target, source)
            else None
        )
        if how is not None:
            msg = (
                f"{option} {out}: {how} the {what} {given}, an input of this command; "
                f"inputs are never replaced or written into: give an {option} outside it"
            )
            raise CliError(msg)


def check_new_file(path: Path, *, force: bool, option: str = "--out") -> None:
    """Refuse an existing file (or a directory) at ``path`` unless ``force`` (and a file).

    Raises:
        CliError: The file exists and ``force`` is False, or ``path`` is a directory.
    """
    if path.is_dir():
        msg = f"{option} {path}: is a directory; give a file name"
        raise CliError(msg)
    refuse_existing(path, force=force, option=option)


def _temporary_sibling(target: Path, what: str) -> Path:
    """Return an unpredictable hidden name beside ``target`` (created exclusively by callers)."""
    return temporary_name(target, what)


def _swap_in(temporary: Path, target: Path) -> None:
    """Move ``temporary`` to ``target``, replacing what was there (moved aside, then removed)."""
    old = _temporary_sibling(target, "old") if target.exists() else None
    if old is not None:
        target.rename(old)
    try:
        temporary.rename(target)
    except OSError:
        if old is not None:
            old.rename(target)
        raise
    if old is not None and old.is_dir():
        shutil.rmtree(old, ignore_errors=True)
    elif old is not None:
        old.unlink()


@contextlib.contextmanager
def publish_directory(target: Path, *, force: bool, option: str = "--out") -> Iterator[Path]:
    """Yield a temporary directory beside ``target``; on success it becomes ``target``.

    Nothing is written at ``target`` until the block finished: a failed or interrupted run
    leaves the previous output as it was and removes its temporary directory.

    Args:
        target: The output directory.
        force: Replace an existing output (else it is refused).
        option: The option that named ``target``, for messages.

    Raises:
        CliError: ``target`` exists and ``force`` is False, or it cannot be written.
    """
    refuse_existing(target, force=force, option=option)
    refuse_irreplaceable(target, option)
    temporary = _temporary_sibling(target, "tmp")
    try:
        temporary.mkdir(parents=True)
    except OSError as err:
        msg = f"{option} {target}: cannot create it ({err.strerror}); check the directory"
        raise CliError(msg) from err
    try:
        yield temporary
        _swap_in(temporary, target)
    except BrokenPipeError:  # the reader of standard output went away: not the output's fault
        raise
    except OSError as err:
        msg = f"{option} {target}: cannot write it ({err.strerror}); check free space"
        raise CliError(msg) from err
    finally:
        shutil.rmtree(temporary, ignore_errors=True)


@contextlib.contextmanager
def publish_file(target: Path, *, force: bool, option: str = "--out") -> Iterator[Path]:
    """Yield a temporary file name beside ``target``; on success it is renamed to ``target``.

    Raises:
        CliError: ``target`` exists and ``force`` is False, or it cannot be written.
    """
    check_new_file(target, force=force, option=option)
    refuse_irreplaceable(target, option)
    temporary = temporary_name(target, f"tmp{target.suffix}")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        create_exclusive(temporary).close()  # never a link planted at the name
        yield temporary
        temporary.replace(target)
    except OSError as err:
        msg = f"{option} {target}: cannot write it ({err.strerror}); check the directory"
        raise CliError(msg) from err
    finally:
        temporary.unlink(missing_ok=True)


__all__ = [
    "ENDING_SIGNALS",
    "FILE_WIDTH",
    "HUNG_UP_STATUS",
    "INTERRUPTED_STATUS",
    "PROGRESS_INTERVAL_S",
    "QUIT_STATUS",
    "SUSPENDED_STATUS",
    "TERMINATED_STATUS",
    "Argument",
    "CliError",
    "Command",
    "HungUp",
    "PlainProgress",
    "Quit",
    "Registry",
    "Suspended",
    "Terminated",
    "arg",
    "build_parser",
    "check_new_file",
    "ending",
    "handled_signals",
    "numbered_directory",
    "one_line",
    "output_console",
    "progress",
    "progress_line",
    "publish_directory",
    "publish_file",
    "refuse_existing",
    "refuse_irreplaceable",
    "refuse_overlap",
    "rig_seed",
    "run",
    "seconds",
    "seed",
    "signal_name",
    "trial",
    "trials",
    "worker_count",
    "workers",
    "workers_ignore_interrupts",
]
