"""One reader thread per live source, into a bounded queue that counts what it drops.

Universal Robots' C++ client library reads RTDE in a background thread into a bounded
pipeline and warns when it overflows; this is the same shape for every live source. The thread
only receives and stamps: ``receive()`` blocks for at most its own timeout and returns one
:class:`Received` (or None when nothing came). Parsing, counting and writing happen in the
consumer. The thread never blocks on a full queue (a slow consumer must not stall the socket):
it drops the sample and counts it; given a ``place`` (what a sample's own time is, read cheaply,
e.g. a ROS 2 message's header stamp from its first 12 bytes), it also keeps each dropped
sample's receive time and that for the consumer (:meth:`SourceReader.dropped`), so that the
loss is counted where the sample belonged. A reader created under ``readers_at(priority)``
(a rig with ``rt_priority``) runs under ``SCHED_FIFO`` (``recorder.live._realtime``).
"""

from __future__ import annotations

import queue
import threading
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Self

from recorder.errors import RigError
from recorder.live._realtime import NORMAL, reader_priority, real_time

if TYPE_CHECKING:
    from collections.abc import Callable

#: Default queue capacity: 10 s of a 1 kHz source, far more than a consumer falls behind.
DEFAULT_CAPACITY = 10_000
#: Dropped samples whose place a reader keeps until the consumer takes them (beyond: the
#: oldest are only counted; a consumer that takes them every step never gets near).
DROPS_KEPT = 10_000
#: A sample dropped: (its receive time ns, its own time as ``place`` read it, or None).
Drop = tuple[int, int | None]


class SourceLostError(RigError):
    """A live source's connection was lost or it went silent."""


@dataclass(frozen=True, slots=True)
class Received:
    """One sample (or frame) as it arrived.

    Attributes:
        receive_ns: Receive time on the recorder's clock, ns.
        payload: What the source delivered (bytes, a decoded message...).
    """

    receive_ns: int
    payload: Any


class SourceReader:
    """Run ``receive`` in a thread and queue what it returns (a context manager).

    ``receive()`` returns a :class:`Received`, or None after its own timeout; an exception
    ends the thread and is raised again (as :class:`SourceLostError`) by :meth:`drain`.
    """

    def __init__(
        self,
        name: str,
        receive: Callable[[], Received | None],
        *,
        capacity: int = DEFAULT_CAPACITY,
        place: Callable[[Received], int | None] | None = None,
    ) -> None:
        """Prepare the reader; the thread starts with :meth:`start` or ``__enter__``.

        Args:
            name: The source, for messages.
            receive: Blocks until a sample arrives or its timeout passes.
            capacity: Queue capacity in samples.
            place: Reads a sample's own time (None: it cannot); given, every sample the full
                queue drops is kept with it for :meth:`dropped`. It runs in the reader thread
                on the drop path only: it must be cheap and never raise.
        """
        self.name = name
        self._receive = receive
        self._queue: queue.Queue[Received] = queue.Queue(maxsize=capacity)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"atikt-{name}", daemon=True)
        self._error: BaseException | None = None
        self._lock = threading.Lock()
        self._overflowed = 0
        self._place = place
        self._dropped: deque[Drop] = deque(maxlen=DROPS_KEPT)
        self._received = 0
        self._last_receive_ns: int | None = None
        self._priority = reader_priority()
        #: The thread's scheduling once it runs: ``"SCHED_FIFO 50"`` or ``"normal"``.
        self.scheduling = NORMAL

    def __enter__(self) -> Self:
        """Start the thread."""
        self.start()
        return self

    def __exit__(self, *_: object) -> None:
        """Stop the thread."""
        self.stop()

    def start(self) -> None:
        """Start reading."""
        self._thread.start()

    def stop(self, timeout_s: float = 2.0) -> None:
        """Ask the thread to end and wait for it (``receive`` returns within its timeout)."""
        self._stop.set()
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout_s)

    def _run(self) -> None:
        """Receive until stopped or until ``receive`` fails."""
        try:
            with real_time(self._priority) as self.scheduling:
                while not self._stop.is_set():
                    item = self._receive()
                    if item is not None:
                        self.deliver(item)
        except BaseException as err:  # noqa: BLE001 (handed to the consumer, never lost)
            self._error = err

    def deliver(self, item: Received) -> None:
        """Queue one received sample (counted; a full queue drops it, counted as overflow).

        The reader thread calls it for what ``receive`` returns; a source stepped in the
        consumer's own thread (the in-process virtual lab) calls it directly.
        """
        with self._lock:
            self._received += 1
            self._last_receive_ns = item.receive_ns
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            at = None if self._place is None else self._place(item)
            with self._lock:
                self._overflowed += 1
                if self._place is not None:
                    self._dropped.append((item.receive_ns, at))

    @property
    def overflowed(self) -> int:
        """Samples dropped because the queue was full, since the start."""
        with self._lock:
            return self._overflowed

    def dropped(self) -> tuple[int, list[Drop]]:
        """Return the overflow count since the start, and take the drops kept since the last call.

        Each drop is ``(receive ns, its own time as place read it, or None)``; they are taken
        together with the count, so every drop taken is in the count (with ``place`` and a
        consumer that calls this often, every drop counted is taken once).
        """
        with self._lock:
            taken = list(self._dropped)
            self._dropped.clear()
            return self._overflowed, taken

    @property
    def received(self) -> int:
        """Samples received since the start (queued or dropped)."""
        with self._lock:
            return self._received

    @property
    def last_receive_ns(self) -> int | None:
        """Receive time of the latest sample (None: nothing yet)."""
        with self._lock:
            return self._last_receive_ns

    @property
    def alive(self) -> bool:
        """Whether the thread is still reading."""
        return self._thread.is_alive()

    def check(self) -> None:
        """Raise the reason the thread ended, if it ended on an error.

        Raises:
            SourceLostError: ``receive`` failed (connection lost, socket closed...).
        """
        if self._error is not None:
            msg = f"source {self.name}: connection lost ({self._error})"
            raise SourceLostError(msg) from self._error

    def get(self, timeout_s: float) -> Received | None:
        """Return the next queued sample, waiting at most ``timeout_s`` (None: none came)."""
        try:
            return self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return None

    def drain(self, limit: int = DEFAULT_CAPACITY) -> list[Received]:
        """Return what is queued now (at most ``limit``), without waiting.

        Raises:
            SourceLostError: The queue is empty and the thread ended on an error.
        """
        items: list[Received] = []
        while len(items) < limit:
            try:
                items.append(self._queue.get_nowait())
            except queue.Empty:
                break
        if not items:
            self.check()
        return items
