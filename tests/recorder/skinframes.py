"""Helpers of the skin frame tests: the example layout, a fake world, polling until done."""

from __future__ import annotations

import time
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from collections.abc import Callable

    from numpy.typing import NDArray

    from recorder.live._frames import FrameSkin
    from recorder.writing._stream import SkinBlock

EXAMPLE = Path(__file__).parents[2] / "recorder" / "data" / "skin_udp.example.toml"
COUNTS = {"force": 3, "acceleration": 3, "temperature": 1, "proximity": 1}


#: A two-cell UDP skin of one frame type (1 kHz force; a u16 counter, a u32 stamp in us):
#: the hostile-source and sender tests' layout.
TWO_CELLS = 2
TWO_CELL_LAYOUT: dict[str, Any] = {
    "transport": "udp",
    "bind": "127.0.0.1:0",
    "cells": TWO_CELLS,
    "header": {"magic": [0xAA, 0x55]},
    "frames": {
        "fast": {
            "rate_hz": 1000,
            "sequence": {"at": 2, "type": "u16"},
            "stamp": {"at": 4, "type": "u32", "unit_ns": 1000},
            "cell_stride": 12,
            "force": {"at": 8, "type": "f32", "count": 3},
        }
    },
}


def example(**changes: Any) -> dict[str, Any]:
    """Return the example [skin] table on an ephemeral port, with top-level keys changed."""
    with EXAMPLE.open("rb") as stream:
        section: dict[str, Any] = tomllib.load(stream)["skin"]
    return {**section, "bind": "127.0.0.1:0", **changes}


def serial_example(device: str) -> dict[str, Any]:
    """Return the example [skin] table over a serial device."""
    section = example(transport="serial", device=device)
    del section["bind"]
    return section


class RampWorld:
    """A skin whose every value is a ramp of controller time (exactly representable steps)."""

    def __init__(self, cells: int = 7) -> None:
        self.cells = cells
        self.origin = time.monotonic_ns()

    def controller_ns(self) -> int:
        return time.monotonic_ns() - self.origin

    def skin_at(self, modality: str, controller_ns: int) -> NDArray[np.float64]:
        step = (controller_ns // 1_000_000) % 1000
        value = {"force": 0.001, "acceleration": 0.01, "temperature": 0.01}.get(modality, 1e-5)
        base = np.arange(self.cells * COUNTS[modality]).reshape(self.cells, -1)
        return np.asarray((base + step) * value, dtype=np.float64)


def poll_until(
    skin: FrameSkin, done: Callable[[], bool], timeout_s: float = 10.0
) -> list[SkinBlock]:
    """Poll the skin every 5 ms until ``done()`` (or the timeout); return the blocks."""
    blocks: list[SkinBlock] = []
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        blocks += skin.poll()
        time.sleep(0.005)
    return blocks


def received_past(skin: FrameSkin, source: int, sensor_ns: int) -> Callable[[], bool]:
    """Return a test: the source's latest sensor time passed ``sensor_ns``."""

    def done() -> bool:
        return skin.stats()[source].last_sensor_ns > sensor_ns

    return done
