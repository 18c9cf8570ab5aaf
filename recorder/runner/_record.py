"""Recording one action: the runner's loop here, the writer in its own thread, nothing lost.

:func:`record_action` is the one way an action is recorded, for every rig: the simulator
(whose physics plans the whole execution), a lab's plug-in rig, and an arm under the runner
(:class:`recorder.runner.ArmRig`). The items go to the writer through a bounded queue; a
signal, a writer that failed or fell behind, or a stop of the rig ends the action (an arm gets
its stop first) and what arrived is kept as ``<trial>.incomplete.mcap``.
"""

from __future__ import annotations

import contextlib
import shutil
from collections.abc import Generator
from typing import TYPE_CHECKING

from recorder._rig import Moving, source_stats
from recorder.errors import ActionStoppedError, RecorderError
from recorder.runner._interrupts import InterruptFlag, deferred_interrupts, raise_interrupt
from recorder.runner._runner import ArmRig, Stop
from recorder.runner._sink import InlineSink, WriterThread
from recorder.writing._writer import RecordingInfo, RecordingWriter

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder._rig import Rig
    from recorder.runner._viewer import Viewer
    from recorder.writing._stream import StreamItem
    from recorder.writing._writer import WrittenRecording


#: Free space an action at the robot asks for before it begins, bytes.
MIN_FREE_BYTES = 64_000_000


class _Watch:
    """What ends an action besides the rig: a deferred signal, a writer in trouble."""

    def __init__(self, flag: InterruptFlag, sink: WriterThread | InlineSink) -> None:
        self.flag, self.sink = flag, sink

    def problem(self) -> str:
        if self.flag.signum is not None:
            return self.flag.reason
        if self.flag.continued:
            return self.flag.stopped_meanwhile
        return self.sink.problem


def record_action(
    rig: Rig,
    obj: ObjectSpec,
    action: ActionSpec,
    trial: int,
    path: Path,
    *,
    seed: int,
    viewers: Sequence[Viewer] = (),
    durable: bool = True,
) -> WrittenRecording:
    """Perform ``action`` on ``obj`` with a connected ``rig`` and record it to ``path``.

    Args:
        rig: A rig inside its ``with`` block.
        obj: The object to explore.
        action: The exploratory action.
        trial: Trial number of this (object, action).
        path: Final path of the recording; it must not exist.
        seed: Seed the rig was created with (for the metadata record).
        viewers: Live views: each gets every item as it arrives and the file once written;
            none may block (``recorder.runner.Viewer``).
        durable: Sync the file to the disk before it counts as written (see
            ``RecordingWriter``; False only for a dataset that can be recorded again).

    Returns:
        What was written.

    Raises:
        OutputExistsError: ``path`` exists.
        ActionStoppedError: A stop ended the action early; what arrived is kept in the
            incomplete file the error names (``<trial>.incomplete.mcap``).
        KeyboardInterrupt: Ctrl-C (``schemas.cli.Terminated``: SIGTERM) during the action,
            after the arm's stop and after what arrived was kept (the message names the file).
        RecorderError: The rig or the file failed; what arrived is kept (incomplete). Or, at
            the robot, too little free disk for the action (nothing was sent, no file made).
        RigError: The arm could not start the action (nothing was sent, no file made).
    """
    moving = isinstance(rig, Moving)
    if isinstance(rig, Moving):  # an arm that could not start the action: no file for it
        check_room(path.parent)
        rig.check_ready()
    info = RecordingInfo.create(obj, action, trial, rig, seed)
    for viewer in viewers:
        viewer.begin(info)
    with deferred_interrupts(arm=moving) as flag:
        written, stop = _write(rig, obj, action, trial, path, info, viewers, flag, durable=durable)
    if written is None:  # pragma: no cover (the 'with' block always sets it)
        msg = f"{path}: the recording was not finished"
        raise RecorderError(msg)
    for viewer in viewers:
        viewer.recorded(written.path)
    _raise_deferred(flag, written.path, stop)
    if stop is not None:
        raise ActionStoppedError(_said(stop), stop.at_ns, written.path)
    return written


def _write(  # noqa: PLR0917 (record_action's own arguments, passed on)
    rig: Rig,
    obj: ObjectSpec,
    action: ActionSpec,
    trial: int,
    path: Path,
    info: RecordingInfo,
    viewers: Sequence[Viewer],
    flag: InterruptFlag,
    *,
    durable: bool,
) -> tuple[WrittenRecording | None, Stop | None]:
    """Run the action into its file; return what was written and the stop that ended it."""
    writer = RecordingWriter(path, info, durable=durable)
    stop: Stop | None = None
    failure: RecorderError | None = None
    try:
        with writer:
            # an arm's loop must never wait for the disk: its writer has a thread of its own
            sink = WriterThread(writer) if isinstance(rig, Moving) else InlineSink(writer)
            with sink:
                put = _fan_out(sink.put, [viewer.offer for viewer in viewers])
                try:
                    stop = _run(rig, obj, action, trial, put=put, watch=_Watch(flag, sink))
                except KeyboardInterrupt as err:  # a signal while a driver call held the loop
                    if flag.held:  # the file says why it is incomplete: the signal, the arm
                        err.args = (f"{flag.reason}: {flag.held}",)
                    raise
            if sink.failure is not None:
                failure = _failed(path, sink.failure)
                raise failure from sink.failure
            if stop is not None:
                writer.mark_incomplete(_said(stop), stop.at_ns)
            if stats := source_stats(rig):
                writer.add_sources(stats)
    except RecorderError as err:
        if err is not failure:
            raise
        raise _writing_stopped(err, stop, writer.kept) from err.__cause__
    except KeyboardInterrupt as err:
        if flag.held:
            err.args = (f"{err}; what arrived is kept in {writer.kept}",)
        raise
    return writer.result, stop


def check_room(directory: Path) -> None:
    """Refuse an action at the robot into ``directory`` on a disk nearly full.

    An action asks for :data:`MIN_FREE_BYTES`, or twice the largest recording (complete or
    not) already in ``directory`` when that is more: the same action's earlier trials say
    best what a rig's sources write (a skin of images writes far more than a few MB). A full
    disk during the action stops the arm and keeps what was written; refusing before anything
    moves spares the robot's time and the object.

    Raises:
        RecorderError: Too little room, one line naming the directory.
    """
    where = directory
    while not where.exists() and where != where.parent:
        where = where.parent
    try:
        free = shutil.disk_usage(where).free
    except OSError:  # not ours to judge: the writer says what fails
        return
    need, why = MIN_FREE_BYTES, "an action at the robot asks for"
    with contextlib.suppress(OSError):  # a directory that cannot be listed: the minimum
        largest = max((f.stat().st_size for f in directory.glob("*.mcap")), default=0)
        if 2 * largest > need:
            need, why = 2 * largest, "this action asks for (twice its largest recording here)"
    if free < need:
        msg = (
            f"{where}: {free / 1e6:.1f} MB free on its disk, below the {need / 1e6:.0f} MB "
            f"{why}; free disk space or give another --out, then run again to resume"
        )
        raise RecorderError(msg)


def _said(stop: Stop) -> str:
    """Return why the action stopped, and what a person must know of the arm."""
    return f"{stop.reason}; {stop.arm_left}" if stop.arm_left else stop.reason


def _raise_deferred(flag: InterruptFlag, path: Path, stop: Stop | None) -> None:
    """Raise the interrupt that arrived during the action, naming the file that kept it."""
    if flag.signum is None:
        return
    stopped = "the arm was stopped"
    if stop is not None and stop.arm_left:
        stopped = stop.arm_left
    try:
        raise_interrupt(flag.signum)
    except KeyboardInterrupt as err:
        err.args = (f"{flag.reason}: {stopped}; what arrived is kept in {path}",)
        raise


def _fan_out(
    first: Callable[[StreamItem], None], others: Sequence[Callable[[StreamItem], None]]
) -> Callable[[StreamItem], None]:
    if not others:
        return first

    def put(item: StreamItem) -> None:
        first(item)
        for other in others:
            other(item)

    return put


def _run(
    rig: Rig,
    obj: ObjectSpec,
    action: ActionSpec,
    trial: int,
    *,
    put: Callable[[StreamItem], None],
    watch: _Watch,
) -> Stop | None:
    """Run the action; return the stop that ended it early (None: a normal end)."""
    if isinstance(rig, ArmRig):
        return rig.run(obj, action, trial, put, watch)
    items = rig.perform(obj, action, trial)
    try:
        for item in items:
            put(item)
            if problem := watch.problem():
                return Stop(problem, 0)
    except ActionStoppedError as stop:  # a rig that performs itself stopped (its own reason)
        return Stop(stop.reason, stop.at_ns)
    finally:
        if isinstance(items, Generator):  # its own stop (a finally, GeneratorExit) runs now
            with contextlib.suppress(Exception):
                items.close()
    return None


def _writing_stopped(err: RecorderError, stop: Stop | None, kept: Path | None) -> RecorderError:
    """Return the line of an action the file's writing ended: what of the arm, where the data is.

    A stop ended the action (the runner saw the writer fail): the arm was stopped, or what a
    person must know of it. What arrived is kept: as the incomplete recording, or as its
    ``.part`` when the disk had no room to finish it (the next session sets it aside).
    """
    said = [str(err)]
    if stop is not None:
        said.append(stop.arm_left or "the arm was stopped")
    if kept is not None and kept.name.endswith(".part"):
        said.append(
            f"what arrived is kept in {kept} (no room to finish it; "
            f"'atikt-replay check {kept} --recover' salvages it)"
        )
    elif kept is not None:
        said.append(f"what arrived is kept in {kept}")
    return RecorderError("; ".join(said))


def _failed(path: Path, failure: BaseException) -> RecorderError:
    if isinstance(failure, RecorderError):
        return failure
    return RecorderError(f"{path}: writing the recording failed ({failure})")
