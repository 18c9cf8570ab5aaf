"""Rigs for tests of dataset workers, importable by worker processes (no pytest needed)."""

from __future__ import annotations

import errno
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from conftest import FakeRig

from recorder.writing import _mcap

if TYPE_CHECKING:
    from collections.abc import Iterator

    from recorder import ActionSpec, StreamItem
    from recorder._catalog import ObjectSpec


def _full(*_args: object, **_kwargs: object) -> None:
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


_FLUSH: Any = _mcap.McapWriter.flush


class FullDiskOnTrialOne(FakeRig):
    """Trial 1 meets a full disk at once; the other trials stream slowly (still writing).

    The disk stays full in the worker of trial 1 until that worker's next action starts (the
    writer writes in its own thread, also after the rig's last item).
    """

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        full = trial == 1
        _mcap.McapWriter.flush = _full if full else _FLUSH  # type: ignore[method-assign]
        for item in super().perform(obj, action, trial):
            if not full:
                time.sleep(0.002)
            yield item


class SleepingRig(FakeRig):
    """Writes its process id into ``$ATIKT_TEST_PIDS`` and then streams nothing for minutes."""

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        pids = Path(os.environ["ATIKT_TEST_PIDS"])
        (pids / str(os.getpid())).write_text("", "utf-8")
        time.sleep(600)
        yield from super().perform(obj, action, trial)
