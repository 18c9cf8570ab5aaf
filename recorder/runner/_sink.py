"""The writer's own thread: the runner hands items over and never waits for the disk.

urcl reads RTDE in a background thread into a bounded queue and says when it overflows; here
the other way round: the safety loop produces, the writer consumes from a bounded queue in its
own thread. A slow disk shows as a queue that fills (the runner then ends the action, the stop
first); a failed write (a full disk) is kept and reported to the runner, which also stops.
A plain ``queue.Queue`` and a thread do this; no library adds anything for one consumer.
"""

from __future__ import annotations

import queue
import threading
from typing import TYPE_CHECKING, Self

if TYPE_CHECKING:
    from types import TracebackType

    from recorder.writing._stream import StreamItem
    from recorder.writing._writer import RecordingWriter

#: Batches the writer may fall behind by: about a minute of a 500 Hz arm and a 1 kHz skin.
CAPACITY = 4_096
#: Items handed over together (a queue operation per item would cost the simulator 10 %).
BATCH = 16
_END = object()


class WriterThread:
    """Writes items to a :class:`RecordingWriter` from a bounded queue, in its own thread."""

    def __init__(self, writer: RecordingWriter, capacity: int = CAPACITY) -> None:
        """Prepare the thread (started by ``__enter__``)."""
        self.writer = writer
        self._queue: queue.Queue[object] = queue.Queue(maxsize=capacity)
        self._thread = threading.Thread(target=self._run, name="atikt-writer", daemon=True)
        self.failure: BaseException | None = None
        self.behind = False
        self._pending: list[StreamItem] = []

    def __enter__(self) -> Self:
        """Start writing."""
        self._thread.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Write what is queued, then end the thread."""
        self.close()

    def put(self, item: StreamItem) -> None:
        """Queue one item; never blocks (a full queue sets :attr:`behind`)."""
        self._pending.append(item)
        if len(self._pending) >= BATCH:
            self._hand_over()

    def _hand_over(self) -> None:
        batch, self._pending = self._pending, []
        if self.failure is not None or self.behind or not batch:
            return
        try:
            self._queue.put_nowait(batch)
        except queue.Full:
            self.behind = True

    @property
    def problem(self) -> str:
        """Return why the writer cannot keep the action going (empty: it can)."""
        if self.failure is not None:
            return f"writing failed: {self.failure}"
        if self.behind:
            items = self._queue.maxsize * BATCH
            return f"the disk fell {items} items behind the arm and the skin"
        return ""

    def close(self) -> None:
        """Write what is queued and end the thread (idempotent)."""
        if self._thread.is_alive():
            self._hand_over()
            self._queue.put(_END)
            self._thread.join()

    def _run(self) -> None:
        while (batch := self._queue.get()) is not _END:
            if self.failure is not None:
                continue  # drain: the runner stops and saves what the file holds
            try:
                for item in batch:  # type: ignore[attr-defined]
                    self.writer.write(item)
            except BaseException as err:  # noqa: BLE001 (kept and reported to the runner)
                self.failure = err


class InlineSink:
    """Writes each item at once, in the caller's thread (rigs that compute, not hardware).

    The simulator plans a whole execution and streams it as fast as it can be written: a
    thread between them would only add its hand-overs. Same interface as :class:`WriterThread`.
    """

    def __init__(self, writer: RecordingWriter) -> None:
        """Write to ``writer``."""
        self.writer = writer
        self.failure: BaseException | None = None

    def __enter__(self) -> Self:
        """Nothing to start."""
        return self

    def __exit__(self, *_: object) -> None:
        """Nothing to stop."""

    def put(self, item: StreamItem) -> None:
        """Write one item; a failure is kept (the caller ends the action)."""
        if self.failure is not None:
            return
        try:
            self.writer.write(item)
        except BaseException as err:  # noqa: BLE001 (kept and reported like the thread's)
            self.failure = err

    @property
    def problem(self) -> str:
        """Return why the action cannot go on (empty: it can)."""
        return "" if self.failure is None else f"writing failed: {self.failure}"
