"""Live signals streamed to rerun while the rig records (``learn --rig ... --view``).

A :class:`StreamingRig` wraps a live rig: every item its ``perform`` yields goes on to the
recorder unchanged and is also logged to rerun as it arrives, under ``live/<object>/<action>/
<trial>``: skin blocks as they come (a block is 0.1 s), joint states in batches of about
0.1 s, phase events at once. The same recording is logged again from its file once it is
written (:class:`replay.live.LiveView`), so the viewer holds both the live stream and the
file as the reader sees it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Self

import numpy as np
import rerun as rr

from recorder import JointSample, PhaseEvent, SkinBlock
from replay.outputs._view import TIMELINE, log_joints, log_skin
from replay.recording._reader import JointStates, SkinSeries

if TYPE_CHECKING:
    from collections.abc import Iterator
    from types import TracebackType

    from recorder import ActionSpec, ObjectSpec, Rig, StreamItem

#: Joint samples logged together (0.1 s at RTDE's 500 Hz).
JOINT_BATCH = 50


def _series(block: SkinBlock) -> SkinSeries:
    """Return a skin block as the reader's series type (for the view's logging code)."""
    data = np.asarray(block.data, dtype=np.float32)
    stamps = block.stamp_ns + block.period_ns * np.arange(data.shape[0], dtype=np.int64)
    cells = np.arange(data.shape[1], dtype=np.uint16)
    return SkinSeries(block.modality, stamps, data, cells, block.period_ns)


class StreamingRig:
    """A rig whose items are also logged to a rerun stream as they arrive."""

    def __init__(self, rig: Rig, stream: rr.RecordingStream) -> None:
        """Wrap ``rig``; log to ``stream``."""
        self._rig = rig
        self._stream = stream
        self._joints: list[JointSample] = []
        self._prefix = "live"

    def __getattr__(self, name: str) -> Any:  # noqa: ANN401 (the wrapped rig's own attributes)
        """Forward everything else (joint_names, describe, present, source_stats...)."""
        return getattr(self._rig, name)

    def __enter__(self) -> Self:
        """Connect the wrapped rig."""
        self._rig.__enter__()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Disconnect the wrapped rig."""
        self._rig.__exit__(exc_type, exc, tb)

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        """Perform with the wrapped rig; log every item before handing it on."""
        self._prefix = f"live/{obj.id}/{action.id}/{trial:03d}"
        try:
            for item in self._rig.perform(obj, action, trial):
                self._log(item)
                yield item
        finally:
            self._flush_joints()

    def _log(self, item: StreamItem) -> None:
        """Log one item (joint states are batched)."""
        if isinstance(item, SkinBlock):
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
        names = tuple(getattr(self._rig, "joint_names", ())) or tuple(
            f"joint_{i}" for i in range(len(samples[0].position))
        )
        joints = JointStates(
            names,
            np.array([s.stamp_ns for s in samples], dtype=np.int64),
            np.array([s.position for s in samples]),
            np.array([s.velocity for s in samples]),
            np.array([s.effort for s in samples]),
        )
        log_joints(self._stream, joints, self._prefix)
