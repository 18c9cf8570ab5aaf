"""Live signals streamed to rerun while the rig records (``learn --rig ... --view``).

A :class:`ViewSink` takes every item the recorder hands it without ever waiting: items go into
a bounded queue (what does not fit is counted as dropped, never waited for) and a thread of its
own logs them to rerun under ``live/<object>/<action>/<trial>``: skin blocks as they come (a
block is 0.1 s), joint states in batches of about 0.1 s, phase events at once. A viewer that
is slow, blocked or gone therefore never delays the robot's loop. Each finished recording is
then logged again from its file, in the same thread, with the rerun view's code.
"""

from __future__ import annotations

import contextlib
import queue
import threading
from typing import TYPE_CHECKING, Self

import numpy as np
import rerun as rr

from recorder import JointSample, PhaseEvent, SkinBlock
from replay.outputs._view import TIMELINE, log_joints, log_skin
from replay.recording._reader import JointStates, SkinSeries

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path
    from types import TracebackType

    from recorder import RecordingInfo, StreamItem

#: Joint samples logged together (0.1 s at RTDE's 500 Hz).
JOINT_BATCH = 50
#: Items the view may fall behind by before it drops (about 20 s of a 500 Hz arm and a skin).
CAPACITY = 20_000
#: Longest wait for the viewer's thread when the run ends, s (a blocked viewer is left).
CLOSE_S = 2.0


def _series(block: SkinBlock) -> SkinSeries:
    """Return a skin block as the reader's series type (for the view's logging code)."""
    data = np.asarray(block.data, dtype=np.float32)
    stamps = block.stamp_ns + block.period_ns * np.arange(data.shape[0], dtype=np.int64)
    cells = np.arange(data.shape[1], dtype=np.uint16)
    return SkinSeries(block.modality, stamps, data, cells, block.period_ns)


class _File:
    """A finished recording to log from its file."""

    def __init__(self, path: Path) -> None:
        self.path = path


_END = object()


class ViewSink:
    """A bounded, non-blocking path from the recorder to a rerun stream (its own thread)."""

    def __init__(
        self,
        stream: rr.RecordingStream,
        log_file: Callable[[Path], None],
        capacity: int = CAPACITY,
        *,
        close_s: float | None = CLOSE_S,
    ) -> None:
        """Log items to ``stream``; finished files with ``log_file`` (both in the thread).

        ``close_s``: longest wait for the thread at the end (None: until it is done, for a
        file, which never blocks).
        """
        self._stream = stream
        self._log_file = log_file
        self._queue: queue.Queue[object] = queue.Queue(maxsize=capacity)
        self._thread = threading.Thread(target=self._run, name="atikt-view", daemon=True)
        self._joints: list[JointSample] = []
        self._prefix = "live"
        self._names: tuple[str, ...] = ()
        self.dropped = 0
        self.failure = ""
        self._close_s = close_s

    def __enter__(self) -> Self:
        """Start the thread."""
        self._thread.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Let the thread log what is queued (a viewer: waiting :data:`CLOSE_S` at most)."""
        if self._close_s is None:
            self._queue.put(_END)
        else:
            self._offer(_END)
        self._thread.join(self._close_s)

    def begin(self, info: RecordingInfo) -> None:
        """Log the next items under ``live/<object>/<action>/<trial>``."""
        meta = info.metadata
        prefix = f"{meta.object_id}/{meta.action_id}/{meta.trial:03d}"
        self._offer(("begin", prefix, info.joint_names))

    def offer(self, item: StreamItem) -> None:
        """Queue one item; never blocks (a full queue counts it as dropped)."""
        self._offer(item)

    def recorded(self, path: Path) -> None:
        """Queue a finished recording, to be logged from its file."""
        self._offer(_File(path))

    def _offer(self, item: object) -> None:
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    def _run(self) -> None:
        while (item := self._queue.get()) is not _END:
            try:
                self._log(item)
            except Exception as err:  # noqa: BLE001 (a viewer's trouble never reaches the robot)
                self.failure = self.failure or str(err)

    def _log(self, item: object) -> None:
        """Log one item (joint states are batched)."""
        if isinstance(item, tuple):
            self._flush_joints()
            _, prefix, names = item
            self._prefix, self._names = f"live/{prefix}", names
        elif isinstance(item, _File):
            self._flush_joints()
            self._log_file(item.path)
        elif isinstance(item, SkinBlock):
            log_skin(self._stream, _series(item), self._prefix)
        elif isinstance(item, JointSample):
            self._joints.append(item)
            if len(self._joints) >= JOINT_BATCH:
                self._flush_joints()
        elif isinstance(item, PhaseEvent):
            self._stream.set_time(TIMELINE, timestamp=np.datetime64(item.stamp_ns, "ns"))
            self._stream.log(f"{self._prefix}/phase", rr.TextLog(item.phase))

    def _flush_joints(self) -> None:
        """Log the joint samples held so far."""
        if not self._joints:
            return
        samples, self._joints = self._joints, []
        names = self._names or tuple(f"joint_{i}" for i in range(len(samples[0].position)))
        joints = JointStates(
            names,
            np.array([s.stamp_ns for s in samples], dtype=np.int64),
            np.array([s.position for s in samples]),
            np.array([s.velocity for s in samples]),
            np.array([s.effort for s in samples]),
        )
        with contextlib.suppress(ValueError):  # a rig whose joint count changed: not shown
            log_joints(self._stream, joints, self._prefix)
