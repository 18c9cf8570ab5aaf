"""The virtual lab for the UR tests: world, RTDE and script servers on free loopback ports.

The skin is a small test LiveSkin that samples the world's skin on the recorder's clock (the
skin transports are tested on their own).
"""

from __future__ import annotations

import contextlib
import re
import threading
import time
from dataclasses import dataclass
from types import SimpleNamespace, TracebackType
from typing import TYPE_CHECKING, Any, Self

import numpy as np

from recorder import SimulatedRig, load_actions, load_objects
from recorder.live import BlockPacker, RecorderClock, SourceCounter, SourceStats
from recorder.ur import Limits, UROptions, URRig
from recorder.virtuallab import VirtualWorld
from recorder.virtuallab._controller import VirtualController
from recorder.virtuallab._dashboard import DashboardServer
from recorder.virtuallab._rtde_server import RtdeFaults, RtdeServer
from recorder.virtuallab._script_server import ScriptFaults, ScriptServer
from schemas import VOCABULARY

if TYPE_CHECKING:
    from collections.abc import Iterator, Mapping

    from recorder.writing._stream import SkinBlock

TIME_SCALE = 0.2
#: Where the tests present objects: above the simulator's workspace, tool pointing down.
POSE = [-0.7, -0.2, 0.15, 0.0, 3.14159, 0.0]
SHAPES = {"force": 3, "temperature": 1, "acceleration": 3, "proximity": 1}


class WorldSkin:
    """A LiveSkin sampling ``world.skin_at`` at each modality's rate (a test stand-in)."""

    def __init__(self, world: VirtualWorld, clock: RecorderClock) -> None:
        self._world = world
        self._clock = clock
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._blocks: list[SkinBlock] = []
        self._packers: dict[str, BlockPacker] = {}
        self._counters: dict[str, SourceCounter] = {}
        self._next: dict[str, int] = {}
        self._latest: dict[str, np.ndarray] = {}
        self._last_receive: int | None = None
        self.begin()

    def __enter__(self) -> Self:
        self._thread.start()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._stop.set()
        self._thread.join(2.0)

    @property
    def cells(self) -> int:
        return 7

    def begin(self) -> None:
        with self._lock:
            now = self._clock.now_ns()
            self._blocks = []
            self._packers, self._counters, self._next = {}, {}, {}
            for name, spec in VOCABULARY.modalities.items():
                period = round(1e9 / spec.rate_hz)
                self._packers[name] = BlockPacker(name, period, block=spec.block_samples)
                self._counters[name] = SourceCounter(f"skin_{name}", period_ns=period)
                self._next[name] = -(-now // period) * period

    def _run(self) -> None:
        while not self._stop.is_set():
            time.sleep(0.005)
            now = self._clock.now_ns()
            offset = now - self._world.controller_ns()
            with self._lock:
                for name, packer in self._packers.items():
                    while self._next[name] <= now:
                        stamp = self._next[name]
                        self._sample(name, packer, stamp, stamp - offset, now)
                        self._next[name] = stamp + packer.period_ns
                self._last_receive = now

    def _sample(self, name: str, packer: BlockPacker, stamp: int, at: int, now: int) -> None:
        value = self._world.skin_at(name, at)
        if value is None:
            value = np.zeros((7, SHAPES[name]))
        row = np.asarray(value, dtype=np.float32).reshape(7, -1)
        self._latest[name] = row
        self._counters[name].observe(None, stamp, now)
        self._blocks.extend(packer.push(stamp, now, row))

    def poll(self) -> list[SkinBlock]:
        with self._lock:
            blocks, self._blocks = self._blocks, []
        return blocks

    def finish(self) -> list[SkinBlock]:
        with self._lock:
            blocks, self._blocks = self._blocks, []
            for packer in self._packers.values():
                blocks.extend(packer.flush())
        return blocks

    def total_force(self) -> float | None:
        with self._lock:
            force = self._latest.get("force")
        return None if force is None else float(force.sum())

    def nearest(self) -> float | None:
        with self._lock:
            proximity = self._latest.get("proximity")
        return None if proximity is None else float(proximity.min())

    def last_receive_ns(self) -> int | None:
        with self._lock:
            return self._last_receive

    def stats(self) -> list[SourceStats]:
        with self._lock:
            return [counter.stats() for counter in self._counters.values()]


@dataclass
class Lab:
    """A running virtual lab."""

    world: VirtualWorld
    controller: VirtualController
    rtde: RtdeServer
    script: ScriptServer
    dashboard: DashboardServer

    def rig(
        self, poses: Mapping[str, Any] | None = None, limits: Limits | None = None, **options: Any
    ) -> URRig:
        """Return a UR rig for this lab (options over the test defaults; limits: the defaults)."""
        merged: dict[str, Any] = {
            "rtde_port": self.rtde.address[1],
            "script_port": self.script.address[1],
            "dashboard_port": self.dashboard.address[1],
            "time_scale": TIME_SCALE,
            "silence_s": 0.5,
        } | options
        return URRig(
            UROptions.from_options(merged, "lab.toml"),
            limits or Limits(),
            {"transport": "test"},
            dict(poses or {}),
            where="lab.toml",
            skin_factory=lambda _section, clock, _where: WorldSkin(self.world, clock),
        )


@contextlib.contextmanager
def virtual_lab(
    *,
    frequency: int = 125,
    rtde_faults: RtdeFaults | None = None,
    script_faults: ScriptFaults | None = None,
    seed: int = 0,
    time_scale: float = TIME_SCALE,
    poses: Mapping[str, Any] | None = None,
) -> Iterator[Lab]:
    """Run a virtual lab on free loopback ports (its objects' faces below ``poses``)."""
    with SimulatedRig(seed) as sim:
        world = VirtualWorld(
            sim,
            load_objects(),
            load_actions(),
            time_scale=time_scale,
            frequency=frequency,
            poses=dict(poses or {}),
        )
        controller = VirtualController(world)
        rtde = RtdeServer(controller, "127.0.0.1", 0, frequency=frequency, faults=rtde_faults)
        script = ScriptServer(controller, "127.0.0.1", 0, faults=script_faults)
        dashboard = DashboardServer(controller, "127.0.0.1", 0)
        with world, rtde, script, dashboard:
            yield Lab(world, controller, rtde, script, dashboard)


def config(options: Mapping[str, Any], sections: Mapping[str, Any]) -> SimpleNamespace:
    """Return a stand-in rig configuration (name, options, sections, source)."""
    return SimpleNamespace(
        name="ur", options=dict(options), sections=dict(sections), source="lab.toml"
    )


def program_kind(name: str) -> str:
    """Return a program's name without the driver's tag (``atikt_move_1a2b3c``: ``atikt_move``)."""
    return re.sub(r"_[0-9a-f]{6}$", "", name) if name.startswith("atikt_") else name
