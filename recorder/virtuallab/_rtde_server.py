"""The virtual lab's RTDE server: the world's arm served as a UR controller serves it.

It speaks RTDE protocol version 2 on a TCP port: protocol version, controller version
(3.15 for a 125 Hz CB3, 5.11 for a 500 Hz e-Series), output setup (any subset of the
variables below; ``NOT_FOUND`` for others, as a controller answers), start and pause, text
messages. After start it sends one data package per control cycle, stamped on the controller
clock's exact grid, with the arm's state at that instant.

For tests it injects faults into the stream and reports exactly what it injected: packages
dropped, duplicated or swapped with their successor (each at its own package, ``after``
packages into the stream and 4 apart), a stall (nothing sent for ``stall_s``, then the backlog)
and a disconnect ``disconnect_after_s`` after the start. With ``at_action_s`` >= 0 the faults
are placed relative to the first announced action instead: packages are counted (for
``after``) and the disconnect timed from ``at_action_s`` seconds after that action began, so
they hit a recording and not the connection's warm-up. Each fault injected is an event of the
world's log (``source`` rtde; serve-sim prints one line each).
"""

from __future__ import annotations

import contextlib
import select
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from recorder.ur._rtde import (
    DATA_PACKAGE,
    GET_URCONTROL_VERSION,
    HEADER,
    PAUSE,
    REQUEST_PROTOCOL_VERSION,
    SETUP_INPUTS,
    SETUP_OUTPUTS,
    START,
    TEXT_MESSAGE,
    Recipe,
    pack_package,
    pack_text,
    unpack_text,
)
from recorder.virtuallab._runner import RUNTIME_PLAYING
from recorder.virtuallab._tcp import TcpServer

if TYPE_CHECKING:
    import socket
    from collections.abc import Callable

    from recorder.virtuallab._controller import VirtualController
    from recorder.virtuallab._world import RobotState

#: RTDE ``joint_mode`` of a joint that runs (JOINT_RUNNING_MODE).
JOINT_RUNNING = 253
#: RTDE ``safety_status_bits`` per safety status: normal (bit 0); protective stop (bit 2)
#: and robot emergency stop (bit 6), each with "stopped due to safety" (bit 10).
SAFETY_STATUS_BITS = {1: 1 << 0, 3: 1 << 2 | 1 << 10, 7: 1 << 6 | 1 << 10}
#: RTDE robot mode of an arm that runs (7): powered, brakes released.
_RUNNING = 7

#: Variables served, with their RTDE type and how to read them from the arm's state.
VARIABLES: dict[str, tuple[str, Callable[[RobotState, float], Any]]] = {
    "timestamp": ("DOUBLE", lambda _s, t: t),
    "actual_q": ("VECTOR6D", lambda s, _t: s.q),
    "target_q": ("VECTOR6D", lambda s, _t: s.q),
    "actual_qd": ("VECTOR6D", lambda s, _t: s.qd),
    "target_qd": ("VECTOR6D", lambda s, _t: s.qd),
    "target_moment": ("VECTOR6D", lambda s, _t: s.effort),
    "actual_TCP_pose": ("VECTOR6D", lambda s, _t: s.tcp_pose),
    "target_TCP_pose": ("VECTOR6D", lambda s, _t: _target(s)),
    "actual_TCP_speed": ("VECTOR6D", lambda s, _t: s.tcp_speed),
    "target_TCP_speed": ("VECTOR6D", lambda s, _t: s.target_tcp_speed),
    "actual_TCP_force": ("VECTOR6D", lambda s, _t: s.tcp_force),
    "robot_mode": ("INT32", lambda s, _t: s.robot_mode),
    "safety_status": ("INT32", lambda s, _t: s.safety_status),
    "safety_mode": ("INT32", lambda s, _t: s.safety_status),
    "runtime_state": ("UINT32", lambda s, _t: s.runtime_state),
    "speed_scaling": ("DOUBLE", lambda _s, _t: 1.0),
    "target_speed_fraction": ("DOUBLE", lambda s, _t: s.speed_fraction),
    "robot_status_bits": ("UINT32", lambda s, _t: _robot_status_bits(s)),
    "safety_status_bits": ("UINT32", lambda s, _t: SAFETY_STATUS_BITS.get(s.safety_status, 0)),
    "joint_mode": ("VECTOR6INT32", lambda _s, _t: np.full(6, JOINT_RUNNING, dtype=np.int64)),
    "actual_tool_accelerometer": ("VECTOR3D", lambda s, _t: _tool_gravity(s)),
    # an e-Series' raw force/torque sensor: the lab has none of its own, the TCP's is served
    "ft_raw_wrench": ("VECTOR6D", lambda s, _t: s.tcp_force),
}
#: What the lab does not model, served as the constants of an idle, unloaded arm, so that
#: clients asking for every variable (``ur_rtde``'s receive interface by default) connect:
#: joint accelerations, currents and control outputs 0, 30 degC joints, 48 V supplies, I/O
#: and registers 0, no payload.
UNMODELLED: dict[str, tuple[str, Any]] = {
    "target_qdd": ("VECTOR6D", np.zeros(6)),
    "target_current": ("VECTOR6D", np.zeros(6)),
    "actual_current": ("VECTOR6D", np.zeros(6)),
    "joint_control_output": ("VECTOR6D", np.zeros(6)),
    "joint_temperatures": ("VECTOR6D", np.full(6, 30.0)),
    "actual_joint_voltage": ("VECTOR6D", np.full(6, 48.0)),
    "actual_execution_time": ("DOUBLE", 0.5),
    "actual_momentum": ("DOUBLE", 0.0),
    "actual_main_voltage": ("DOUBLE", 48.0),
    "actual_robot_voltage": ("DOUBLE", 48.0),
    "actual_robot_current": ("DOUBLE", 0.0),
    "actual_digital_input_bits": ("UINT64", 0),
    "actual_digital_output_bits": ("UINT64", 0),
    "standard_analog_input0": ("DOUBLE", 0.0),
    "standard_analog_input1": ("DOUBLE", 0.0),
    "standard_analog_output0": ("DOUBLE", 0.0),
    "standard_analog_output1": ("DOUBLE", 0.0),
    "payload": ("DOUBLE", 0.0),
    "payload_cog": ("VECTOR3D", np.zeros(3)),
    "payload_inertia": ("VECTOR6D", np.zeros(6)),
    **{f"output_int_register_{i}": ("INT32", 0) for i in range(48)},
    **{f"output_double_register_{i}": ("DOUBLE", 0.0) for i in range(48)},
}


def _constant(value: Any) -> Callable[[RobotState, float], Any]:  # noqa: ANN401 (RTDE's)
    """Return a reader of ``value`` whatever the state."""
    return lambda _s, _t: value


VARIABLES.update({name: (kind, _constant(value)) for name, (kind, value) in UNMODELLED.items()})


def _target(state: RobotState) -> Any:  # noqa: ANN401 (a pose)
    return state.tcp_pose if state.target_pose is None else state.target_pose


def _robot_status_bits(state: RobotState) -> int:
    """Return RTDE ``robot_status_bits``: power on (bit 0), program running (bit 1)."""
    powered = state.robot_mode >= _RUNNING - 2  # idle (5) and beyond: powered
    return int(powered) | int(state.runtime_state == RUNTIME_PLAYING) << 1


def _tool_gravity(state: RobotState) -> Any:  # noqa: ANN401 (a vector)
    """Return what the tool's accelerometer reads of gravity at rest, tool frame, m/s^2."""
    from scipy.spatial.transform import Rotation  # noqa: PLC0415 (only when asked for)

    up = np.array([0.0, 0.0, 9.81])  # the specific force at rest: up, base frame
    return Rotation.from_rotvec(state.tcp_pose[3:6]).inv().apply(up)


#: Controller version reported for each highest frequency.
VERSIONS = {125: (3, 15, 7, 0), 500: (5, 11, 0, 0)}
#: Packages between two injected faults.
FAULT_SPACING = 4


@dataclass(frozen=True, slots=True)
class RtdeFaults:
    """Faults to inject into each connection's stream.

    Attributes:
        drop: Packages never sent.
        duplicate: Packages sent twice.
        reorder: Packages sent after their successor.
        after: Packages sent normally before the first fault (and before a stall).
        stall_s: Nothing sent for this long, then the backlog (0: no stall).
        disconnect_after_s: Close the connection this long after the start (0: never).
        at_action_s: Count from this long after the first announced action began instead of
            from the stream's start (negative: from the start).
    """

    drop: int = 0
    duplicate: int = 0
    reorder: int = 0
    after: int = 50
    stall_s: float = 0.0
    disconnect_after_s: float = 0.0
    at_action_s: float = -1.0

    def plan(self) -> dict[int, str]:
        """Return package index -> fault, each fault at its own package."""
        kinds = ["drop"] * self.drop + ["duplicate"] * self.duplicate + ["reorder"] * self.reorder
        return {self.after + FAULT_SPACING * i: kind for i, kind in enumerate(kinds)}


@dataclass(slots=True)
class Injected:
    """What the server injected (over all connections).

    Attributes:
        sent: Data packages sent (copies included).
        dropped: Packages dropped.
        duplicated: Packages sent twice.
        reordered: Packages sent after their successor.
        stalls: Stalls.
        disconnects: Connections closed on purpose.
    """

    sent: int = 0
    dropped: int = 0
    duplicated: int = 0
    reordered: int = 0
    stalls: int = 0
    disconnects: int = 0


@dataclass(slots=True)
class _Session:
    """One client's state."""

    sock: socket.socket
    recipe: Recipe | None = None
    started: bool = False
    buffer: bytearray = field(default_factory=bytearray)


class RtdeServer(TcpServer):
    """Serve the arm over RTDE on ``host:port`` (a context manager; port 0: any free port)."""

    thread_name = "atikt-rtde-server"
    no_delay = True

    def __init__(
        self,
        controller: VirtualController,
        host: str = "127.0.0.1",
        port: int = 30004,
        *,
        frequency: int = 125,
        faults: RtdeFaults | None = None,
    ) -> None:
        """Prepare the server (it listens from ``__enter__``).

        Args:
            controller: The virtual controller whose arm is served.
            host: Address to bind (loopback unless told otherwise).
            port: Port to bind (0: a free one; read :attr:`address`).
            frequency: Highest frequency (125: a CB3, 500: an e-Series).
            faults: Faults to inject into every stream.
        """
        self.controller = controller
        super().__init__(host, port)
        self.max_frequency = frequency
        self.faults = faults or RtdeFaults()
        self._lock = threading.Lock()
        self._injected = Injected()

    @property
    def injected(self) -> Injected:
        """Return a copy of what was injected so far."""
        with self._lock:
            return Injected(**{k: getattr(self._injected, k) for k in Injected.__slots__})

    def _count(self, **counts: int) -> None:
        with self._lock:
            for key, value in counts.items():
                setattr(self._injected, key, getattr(self._injected, key) + value)

    def serve(self, sock: socket.socket) -> None:
        """Answer one client until it leaves, the server stops or a disconnect is injected."""
        session = _Session(sock)
        with contextlib.closing(sock), contextlib.suppress(OSError):
            while not self.stopping.is_set():
                if session.started:
                    if not self._stream(session):
                        return
                elif not self._handle_ready(session, 0.1):
                    return

    def _handle_ready(self, session: _Session, timeout_s: float) -> bool:
        """Read and answer requests for at most ``timeout_s``; False: the client left."""
        readable, _, _ = select.select([session.sock], [], [], max(timeout_s, 0.0))
        if not readable:
            return True
        chunk = session.sock.recv(65536)
        if not chunk:
            return False
        session.buffer += chunk
        while len(session.buffer) >= HEADER.size:
            size, kind = HEADER.unpack_from(session.buffer)
            if len(session.buffer) < size:
                break
            payload = bytes(session.buffer[HEADER.size : size])
            del session.buffer[:size]
            self._answer(session, kind, payload)
        return True

    def _answer(self, session: _Session, kind: int, payload: bytes) -> None:
        """Answer one request."""
        sock = session.sock
        if kind == REQUEST_PROTOCOL_VERSION:
            version = struct.unpack(">H", payload[:2])[0] if len(payload) >= 2 else 0  # noqa: PLR2004
            sock.sendall(pack_package(kind, bytes([version in {1, 2}])))
        elif kind == GET_URCONTROL_VERSION:
            sock.sendall(pack_package(kind, struct.pack(">IIII", *VERSIONS[self.max_frequency])))
        elif kind == SETUP_OUTPUTS:
            sock.sendall(pack_package(kind, self._setup(session, payload)))
        elif kind == SETUP_INPUTS:
            names = payload.decode(errors="replace").split(",")
            sock.sendall(
                pack_package(kind, b"\x00" + ",".join(["NOT_FOUND"] * len(names)).encode())
            )
        elif kind == START:
            session.started = session.recipe is not None
            sock.sendall(pack_package(kind, bytes([session.started])))
        elif kind == PAUSE:
            session.started = False
            sock.sendall(pack_package(kind, b"\x01"))
        elif kind == TEXT_MESSAGE:
            message, source, _ = unpack_text(payload)
            self.controller.note(f"RTDE text message from {source or 'a client'}: {message}")
        else:
            text = pack_text(f"unknown RTDE package type {kind}", "RTDE", 1)
            sock.sendall(pack_package(TEXT_MESSAGE, text))

    def _setup(self, session: _Session, payload: bytes) -> bytes:
        """Set up an output recipe; return the answer (recipe id and types)."""
        frequency = struct.unpack(">d", payload[:8])[0] if len(payload) >= 8 else 0.0  # noqa: PLR2004
        # ur_rtde ends the list with a comma; a controller ignores the empty name.
        names = payload[8:].decode(errors="replace").removesuffix(",").split(",")
        types = [VARIABLES[n][0] if n in VARIABLES else "NOT_FOUND" for n in names]
        ok = "NOT_FOUND" not in types and 0 < frequency <= self.max_frequency
        session.recipe = Recipe(1, tuple(names), tuple(types), frequency) if ok else None
        return bytes([1 if ok else 0]) + ",".join(types).encode()

    def _package(self, recipe: Recipe, controller_ns: int) -> bytes:
        """Return the data package of the arm's state at a controller time."""
        state = self.controller.state_at(controller_ns)
        values: list[Any] = [recipe.recipe_id]
        for name in recipe.names:
            value = VARIABLES[name][1](state, controller_ns / 1e9)
            if isinstance(value, np.ndarray):
                values.extend(value.tolist())  # floats, or ints of an integer vector
            else:
                values.append(value)
        return pack_package(DATA_PACKAGE, recipe.layout.pack(*values))

    def _stream(self, session: _Session) -> bool:
        """Send one package per cycle (with the faults); False: the connection ends."""
        recipe = session.recipe
        assert recipe is not None  # noqa: S101 (start refuses without a recipe)
        period = round(1e9 / recipe.frequency)
        clock = self.controller.controller_ns
        tick = -(-clock() // period)
        plan, faults = self.faults.plan(), self.faults
        started_ns, index, held = None, 0, None
        while session.started and not self.stopping.is_set():
            due = tick * period
            wait = (due - clock()) / 1e9
            # requests are answered even when the stream runs behind its clock (wait <= 0)
            if not self._handle_ready(session, wait):
                return False
            if not session.started or clock() < due:
                continue
            started_ns = self._armed(started_ns, due)
            armed = started_ns is not None
            late = armed and due - (started_ns or 0) >= faults.disconnect_after_s * 1e9
            if faults.disconnect_after_s and late:
                self._count(disconnects=1)
                self._event(due, "disconnect")
                return False
            if armed and faults.stall_s and index == faults.after:
                self._count(stalls=1)
                self._event(due, "stall", seconds=faults.stall_s)
                time.sleep(faults.stall_s)
            package = self._package(recipe, due)
            fault = plan.get(index) if armed else None
            if fault is not None:
                self._event(due, fault, package=index)
            held = self._send(session.sock, package, fault, held)
            index += 1 if armed else 0
            tick += 1
        return True

    def _armed(self, started_ns: int | None, due: int) -> int | None:
        """Return when the faults' counting began (None: not yet)."""
        if started_ns is not None:
            return started_ns
        if self.faults.at_action_s < 0:
            return due
        first = self.controller.world.first_action_ns
        if first is None or due < first + self.faults.at_action_s * 1e9:
            return None
        return due

    def _event(self, controller_ns: int, fault: str, **details: Any) -> None:  # noqa: ANN401
        self.controller.world.events_log.add(
            "fault", controller_ns, source="rtde", fault=fault, **details
        )

    def _send(
        self, sock: socket.socket, package: bytes, fault: str | None, held: bytes | None
    ) -> bytes | None:
        """Send a package as the fault says; return a package held back for reordering."""
        if fault == "drop":
            self._count(dropped=1)
            return held
        if fault == "reorder":
            self._count(reordered=1)
            return package
        sock.sendall(package)
        self._count(sent=1)
        if fault == "duplicate":
            sock.sendall(package)
            self._count(sent=1, duplicated=1)
        if held is not None:
            sock.sendall(held)
            self._count(sent=1)
        return None
