"""Rigs for tests of dataset workers, importable by worker processes (no pytest needed)."""

from __future__ import annotations

import errno
import os
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import mcap.writer
from conftest import FakeRig

if TYPE_CHECKING:
    from collections.abc import Iterator

    from recorder import ActionSpec, StreamItem
    from recorder._catalog import ObjectSpec


def _full(*_args: object, **_kwargs: object) -> None:
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


class FullDiskOnTrialOne(FakeRig):
    """Trial 1 meets a full disk at once; the other trials stream slowly (still writing)."""

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        original: Any = mcap.writer.Writer.flush
        if trial == 1:
            mcap.writer.Writer.flush = _full  # type: ignore[method-assign]
        try:
            for item in super().perform(obj, action, trial):
                if trial != 1:
                    time.sleep(0.002)
                yield item
        finally:
            mcap.writer.Writer.flush = original  # type: ignore[method-assign]


class SleepingRig(FakeRig):
    """Writes its process id into ``$ATIKT_TEST_PIDS`` and then streams nothing for minutes."""

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        pids = Path(os.environ["ATIKT_TEST_PIDS"])
        (pids / str(os.getpid())).write_text("", "utf-8")
        time.sleep(600)
        yield from super().perform(obj, action, trial)
