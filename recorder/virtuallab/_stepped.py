"""The simulated UR10 as a driver of the action runner: the virtual lab stepped in-process.

The ``sim-ur10`` rig is the virtual lab's world (a kinematic UR10 executing the URScript the
UR driver writes, over the simulator's objects, with the simulated skin) run inside the
recorder's process on a simulated clock, under the same runner (:class:`recorder.runner.ArmRig`)
and the same drivers' code as a UR at the robot:

- the arm is the UR driver (:class:`recorder.ur.URArm`) with its two wires replaced: each
  program it writes is parsed and run by the world as the virtual lab's URScript server runs
  it, and each state sample is the world's RTDE state of one controller cycle, counted and
  checked as an RTDE package is;
- the skin is the UDP skin (:class:`recorder.live.UdpSkin`) reading the frames the virtual
  lab's skin server encodes in the configuration's ``[skin]`` layout, handed over in process
  instead of through a socket.

Time is the simulated clock's: each time the runner waits for the next state sample, the clock
moves one controller cycle and the world computes it. Nothing waits on the machine's clock, so a
session runs as fast as the machine computes the world (about 7 times real time at 125 Hz on
one core) and gives the same recordings on a loaded machine as on a quiet one, for a seed.
The runner's phases, limits, silence detection and stops are the ones that drive a real arm.

The configuration is the UR rig's (``recorder/data/ur_rig.example.toml`` when none is given):
the connection options are not used; the skin must be ``udp`` or ``serial`` (a ROS 2 skin
is rehearsed with ``serve-sim --ros2``). Objects without a pose are presented at
:data:`DEFAULT_POSE`: the virtual lab puts the announced object under the skin.
"""

from __future__ import annotations

import contextlib
from collections import deque
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self

from recorder._catalog import load_actions, load_objects
from recorder._rigconfig import FrozenTable, RigConfig, RigPlugin, load_rig_config
from recorder.errors import RigError
from recorder.live import Received, RecorderClock, SourceCounter, SourceReader, UdpSkin
from recorder.live import parse_layout as parse_skin_layout
from recorder.runner import ArmRig, RunnerOptions
from recorder.ur import Connection, URArm
from recorder.ur._rig import read_ur_config
from recorder.virtuallab._skin_server import SkinFaults, SkinServer
from recorder.virtuallab._urscript import parse_program
from recorder.virtuallab._world import HOME_POSE, VirtualWorld

if TYPE_CHECKING:
    from collections.abc import Iterator, Mapping, Sequence
    from types import TracebackType

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder.live import SkinLayout
    from recorder.runner import ArmSample
    from recorder.writing._stream import StreamItem

#: The simulated clock's start: 2017-07-14 02:40:00 UTC, ns (a fixed origin: a session's
#: stamps depend on its inputs only).
START_NS = 1_500_000_000 * 1_000_000_000
#: Where an object without a pose in the configuration is presented (its face lies 20 mm
#: below): the virtual lab's home pose, 5 cm lower.
DEFAULT_POSE = (HOME_POSE[0], HOME_POSE[1], HOME_POSE[2] - 0.05, *HOME_POSE[3:])
#: The configuration used when none is given.
EXAMPLE_CONFIG = Path(__file__).resolve().parents[1] / "data" / "ur_rig.example.toml"
#: The skin transports the in-process lab can serve (framed skins).
FRAMED = frozenset({"udp", "serial"})
_NS = 1_000_000_000


class SteppedClock(RecorderClock):
    """The recorder's clock moved by the lab, one controller cycle at a time."""

    __slots__ = ("now",)
    real = False

    def __init__(self, start_ns: int = START_NS) -> None:
        """Start at ``start_ns``."""
        self._offset_ns = 0
        self.now = start_ns

    def now_ns(self) -> int:
        """Return the simulated time, ns."""
        return self.now


class _Inbox(SourceReader):
    """A source reader without a thread: the lab delivers frames as it computes them."""

    def start(self) -> None:
        """Nothing to start (no thread)."""

    def stop(self, timeout_s: float = 0.0) -> None:
        """Nothing to stop."""
        del timeout_s


class _InboxLink:
    """The skin server's link into the skin's inbox (what a socket would carry).

    Frames are held while the clock is before :attr:`hold_until_ns`, then delivered in order
    (a stalled transport, for tests).
    """

    def __init__(self, inbox: _Inbox, clock: SteppedClock) -> None:
        self._inbox, self._clock = inbox, clock
        self.hold_until_ns = 0
        self._held: deque[bytes] = deque()

    def send(self, frames: list[bytes]) -> None:
        self._held.extend(frames)
        self.release()

    def release(self) -> None:
        """Deliver the frames held, unless the link is stalled."""
        now = self._clock.now_ns()
        if now >= self.hold_until_ns:
            while self._held:
                self._inbox.deliver(Received(now, self._held.popleft()))

    def close(self) -> None:
        """Nothing to close."""


class SteppedLab:
    """The virtual lab's world and skin server, stepped by the arm driver's waits."""

    def __init__(
        self,
        seed: int,
        frequency: int,
        time_scale: float,
        poses: Mapping[str, Sequence[float]],
        layout: SkinLayout,
    ) -> None:
        """Prepare (the world is built on ``__enter__``)."""
        self.seed, self.frequency, self.time_scale = seed, frequency, time_scale
        self.poses, self.layout = dict(poses), layout
        self.clock = SteppedClock()
        self.inbox = _Inbox(layout.name, lambda: None)
        self.objects: dict[str, ObjectSpec] = dict(load_objects())
        self.actions: dict[str, ActionSpec] = dict(load_actions())
        self._stack: contextlib.ExitStack | None = None
        self._world: VirtualWorld | None = None
        self._skin: SkinServer | None = None
        #: The skin's link (``hold_until_ns`` stalls it: tests).
        self.link = _InboxLink(self.inbox, self.clock)

    def __enter__(self) -> Self:
        """Build the world at rest at its home pose and start its skin's frames."""
        from recorder._sim import SimulatedRig  # noqa: PLC0415 (scipy; only when used)

        with contextlib.ExitStack() as stack:
            sim = stack.enter_context(SimulatedRig(self.seed))
            self._world = VirtualWorld(
                sim,
                self.objects,
                self.actions,
                time_scale=self.time_scale,
                clock=self.clock.now_ns,
                frequency=self.frequency,
                poses=self.poses,
                seed=self.seed,
            )
            self._skin = SkinServer(self._world, self.link, self.layout, SkinFaults())
            self._skin.start(thread=False)
            stack.callback(self._skin.stop)
            self._stack = stack.pop_all()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Drop the world."""
        stack, self._stack = self._stack, None
        if stack is not None:
            stack.close()
        self._world = self._skin = None

    @property
    def world(self) -> VirtualWorld:
        """Return the world (inside ``with``)."""
        if self._world is None:
            msg = "the in-process virtual lab is used outside its with block"
            raise RigError(msg)
        return self._world

    def know(self, obj: ObjectSpec, action: ActionSpec) -> None:
        """Let the world announce an object and an action of another catalog."""
        self.objects.setdefault(obj.id, obj)
        self.actions.setdefault(action.id, action)

    def step(self) -> int:
        """Move the clock one controller cycle; compute it and send its skin frames.

        Returns:
            The controller time of the cycle's end, ns.
        """
        world = self.world
        self.clock.now += world.period_ns
        now = world.controller_ns()
        world.advance_to(now)
        if self._skin is not None:
            self._skin.send_due(now)
            self.link.release()
        return now


class SteppedArm(URArm):
    """The UR driver on the in-process lab: programs run by the world, states of its cycles."""

    def __init__(self, lab: SteppedLab, where: str) -> None:
        """Drive ``lab``'s arm."""
        super().__init__(Connection("in-process", 0, 0, lab.frequency), lab.clock, where)
        self.lab = lab

    def __enter__(self) -> Self:
        """Nothing to connect: the lab is built by the rig; the clocks share their origin."""
        self._offset_ns = self.lab.clock.now_ns() - self.lab.world.controller_ns()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Nothing to disconnect."""

    def describe(self) -> Mapping[str, str]:
        """Return the controller's cycle rate (the in-process lab has no address)."""
        frequency = str(self.lab.frequency)
        return {"controller": "in-process virtual lab", "rtde_frequency_hz": frequency}

    def facts(self) -> Mapping[str, str]:
        """Return nothing learned (the lab is part of the recorder)."""
        return {}

    def begin(self) -> None:
        """Count afresh from here."""
        self._counter = SourceCounter("rtde", period_ns=self.period_ns)
        self.malformed = 0

    def poll(self, wait_s: float) -> list[ArmSample]:
        """Return the next cycle's state when asked to wait for it (time passes); else none."""
        if wait_s <= 0:
            return []
        now = self.lab.step()
        state = self.lab.world.robot_at(now)
        values = {
            "timestamp": now / _NS,
            "actual_q": state.q,
            "actual_qd": state.qd,
            "target_moment": state.effort,
            "actual_TCP_pose": state.tcp_pose,
            "actual_TCP_force": state.tcp_force,
            "robot_mode": state.robot_mode,
            "safety_status": state.safety_status,
            "target_speed_fraction": state.speed_fraction,
            "runtime_state": state.runtime_state,
        }
        sample = self._state(values, self.lab.clock.now_ns())
        return [] if sample is None else [sample]

    def _send(self, text: str, *, reconnect: bool = False) -> None:  # noqa: ARG002 (no wire)
        """Run a program as the lab's URScript server does (errors go to its log)."""
        self._speeding = None
        program = parse_program(self._named(text), self.lab.clock.now_ns())
        world = self.lab.world
        if program.errors:
            for error in program.errors:
                world.note(f"URScript error, program not run: {error}")
            return
        world.run(program)


class SteppedSkin(UdpSkin):
    """The UDP skin reading the in-process lab's frames."""

    def __init__(self, lab: SteppedLab) -> None:
        """Read ``lab``'s frames in its layout."""
        super().__init__(lab.layout, lab.clock)
        self.lab = lab

    def _open(self) -> SourceReader:
        return self.lab.inbox

    def _close(self) -> None:
        """Nothing to close."""


class SimUR10Rig(ArmRig):
    """The simulated UR10 under the runner (a :class:`recorder.Rig`; exclusive)."""

    def __init__(self, lab: SteppedLab, config: Any) -> None:  # noqa: ANN401 (a URConfig)
        """Drive ``lab`` with the runner as ``config`` (a checked UR configuration) says."""
        self.lab = lab
        options = config.options
        runner = RunnerOptions(options.time_scale, options.silence_s, options.motion)
        super().__init__(
            SteppedArm(lab, config.where),
            SteppedSkin(lab),
            config.limits,
            runner,
            lab.poses,
            kind="sim-ur10",
            skin_transport=str(config.skin.get("transport", "")),
            where=config.where,
            clock=lab.clock,
        )
        self._lab_stack: contextlib.ExitStack | None = None

    def __enter__(self) -> Self:
        """Build the lab, then connect the driver and the skin to it."""
        with contextlib.ExitStack() as stack:
            stack.enter_context(self.lab)
            super().__enter__()
            stack.push(super().__exit__)
            self._lab_stack = stack.pop_all()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Disconnect, then drop the lab."""
        stack, self._lab_stack = self._lab_stack, None
        if stack is not None:
            stack.__exit__(exc_type, exc, tb)

    def describe(self) -> Mapping[str, str]:
        """Return the rig's configuration and the lab's seed (its identity in a dataset)."""
        return {**super().describe(), "seed": str(self.lab.seed)}

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        """Perform ``action`` on ``obj`` (objects and actions of any catalog)."""
        self.lab.know(obj, action)
        return super().perform(obj, action, trial)


def build_sim_ur10_rig(seed: int, config: RigConfig) -> SimUR10Rig:
    """Build the simulated UR10 rig from a UR rig configuration (the example when none).

    Args:
        seed: Seed of the simulated skin's noise and the objects' conditions.
        config: A UR rig configuration; without tables, ``recorder/data/ur_rig.example.toml``'s
            (its options first, then the given ones).

    Raises:
        RigError: The configuration is malformed, its skin is not framed (udp or serial), or a
            pose or motion setting is outside the limits.
    """
    if not config.sections and not config.source:
        example = load_rig_config(EXAMPLE_CONFIG)
        config = RigConfig(
            config.name,
            FrozenTable({**example.options, **config.options}),
            example.sections,
            str(EXAMPLE_CONFIG),
        )
    checked = read_ur_config(config, rig="sim-ur10")
    transport = checked.skin.get("transport")
    if transport not in FRAMED:
        msg = (
            f"{checked.where}: [skin] transport = {transport!r}: the sim-ur10 rig serves framed "
            "skins (udp, serial); rehearse a ROS 2 skin with atikt-record serve-sim --ros2"
        )
        raise RigError(msg)
    layout = parse_skin_layout(checked.skin, checked.where)
    poses = {object_id: list(DEFAULT_POSE) for object_id in load_objects()}
    poses.update({key: list(value) for key, value in checked.poses.items()})
    options = checked.options
    lab = SteppedLab(seed, options.frequency, options.time_scale, poses, layout)
    return SimUR10Rig(lab, checked)


#: The simulated UR10 rig as a plug-in: one lab per rig, actions one after another.
PLUGIN = RigPlugin(
    build=build_sim_ur10_rig,
    exclusive=True,
    description="the simulated UR10 under the action runner (the virtual lab, in-process)",
)
