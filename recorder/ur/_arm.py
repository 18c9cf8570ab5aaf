"""The UR driver: a Universal Robots arm's state over RTDE, its motion as URScript.

The driver reads every RTDE data package in a reader thread (bounded queue, overflow counted),
counts it by the controller's ``timestamp`` and turns each new, in-order package into an
:class:`recorder.runner.ArmSample`; each command of the runner is one URScript program sent
to the primary interface, port 30001 (it replaces the running one; see ``_script``). It
decides nothing: phases, limits and the stop belong to the runner.

A package the recipe cannot parse (another recipe id, a wrong size) or with a non-finite value
is counted as malformed and skipped: it never ends the action and never reaches the file.

The script connection is read too, in a thread of its own: a controller streams its state to
every client of its primary and secondary (10 Hz) and real-time (125/500 Hz) interfaces, and a
client that never reads fills its receive buffer, on which a controller may drop it. The
state is dropped (RTDE carries it); the primary interface's key messages are read:
``PROGRAM_XXX_STARTED`` names every program that starts, and one not of this driver (a
colleague's computer, the pendant) has replaced the action's program; a runtime exception
(a program that did not compile, or one the controller stopped) ends the action with the
controller's own text. A port that names none of the driver's own programs sends no messages
(the secondary interface, 30002): that is said once, as programs of others are then not seen.
The end of that stream is the connection's loss, known before the next program would go into a
dead socket. A lost connection ends the
action at the next state sample (the arm's last program runs on, and no stop could follow it),
and so does a program found with its connection lost; the stop then goes over a new
connection (the controller takes one at any time), and between actions a lost connection is
made again. When no new connection is taken either, the stop goes to the dashboard server
(port 29999: ``stop`` ends the running program and the arm brakes), a second way in that
shares no socket with the programs; only when that fails too does the stop count as not sent.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
import secrets
import socket
import struct
import threading
import time
from typing import TYPE_CHECKING, Any, Self

import numpy as np

from recorder._sim.ur10 import JOINT_NAMES  # the UR arms' joints, in RTDE's order
from recorder.errors import RigError
from recorder.live import RecorderClock, SourceCounter, SourceLostError, SourceReader
from recorder.runner import arm_lock
from recorder.runner._arm import ArmSample
from recorder.ur._rtde import MAX_FREQUENCY, RtdeClient, RtdeError
from recorder.ur._script import (
    Announcement,
    move_program,
    program,
    slide_program,
    speed_program,
    stop_program,
)

if TYPE_CHECKING:
    from collections.abc import Mapping
    from types import TracebackType

    from numpy.typing import NDArray

    from recorder.live import Received, SourceStats
    from recorder.runner._arm import Context

_log = logging.getLogger("atikt.ur")

#: The RTDE outputs the driver asks for (``target_moment``: the joint torques it records).
RTDE_VARIABLES = (
    "timestamp",
    "actual_q",
    "actual_qd",
    "target_moment",
    "actual_TCP_pose",
    "actual_TCP_force",
    "robot_mode",
    "safety_status",
)
#: RTDE outputs read when the controller provides them: the teach pendant's speed slider and
#: the program's state.
OPTIONAL_VARIABLES = ("target_speed_fraction", "runtime_state")
#: The recipes asked for in turn, until the controller provides one: a controller (or a
#: controller emulator) without ``safety_status``, a later addition to RTDE, gives
#: ``safety_mode`` (the same values up to 9; ur_rtde reads that one), and one without the
#: slider's output is driven without it.
RECIPES = (
    (*RTDE_VARIABLES, *OPTIONAL_VARIABLES),
    RTDE_VARIABLES,
    (*RTDE_VARIABLES[:-1], "safety_mode", *OPTIONAL_VARIABLES),
    (*RTDE_VARIABLES[:-1], "safety_mode"),
)
#: ``TCP_QUICKACK`` where the platform has it (Linux), else None.
_QUICKACK: int | None = getattr(socket, "TCP_QUICKACK", None)
#: The slider's lowest reading taken as full speed (it reads 1.0 at 100 %).
FULL_SPEED = 0.999
#: RTDE ``safety_status`` values under which the arm may move (normal, reduced).
SAFE_STATUS = frozenset({1, 2})
#: Names of the other safety states, for messages.
SAFETY_NAMES = {
    3: "protective stop",
    4: "recovery",
    5: "safeguard stop",
    6: "system emergency stop",
    7: "robot emergency stop",
    8: "violation",
    9: "fault",
}
#: What a person does about each safety state before the recorder may move the arm again.
SAFETY_FIXES = {
    3: "once its cause is clear, unlock it at the teach pendant or with the dashboard's "
    "'unlock protective stop'",
    4: "move the arm back inside its safety limits in the teach pendant's recovery mode",
    5: "reset the safeguard input (a light curtain, a door) at the cell",
    6: "release the emergency stop button, then reset it at the teach pendant",
    7: "release the emergency stop button, then reset it at the teach pendant",
    8: "read the teach pendant's log, then restart the safety system as it says",
    9: "read the teach pendant's log, then restart the safety system as it says",
}
#: RTDE ``runtime_state`` values: a program paused (a stop: the action cannot go on), and a
#: program running, stopping or resuming (before an action: another's, which ours would replace).
RUNTIME_PAUSED = {3: "pausing", 4: "paused"}
RUNTIME_BUSY = {0: "stopping", 2: "playing", 5: "resuming"}
#: RTDE ``robot_mode`` of an arm that can move (ROBOT_MODE_RUNNING: powered, brakes released).
RUNNING = 7
#: Names of the other robot modes, for messages (the controller's RobotMode enumeration).
ROBOT_MODE_NAMES = {
    -1: "no controller",
    0: "disconnected",
    1: "confirm safety",
    2: "booting",
    3: "powered off",
    4: "powering on",
    5: "idle, brakes engaged",
    6: "backdrive",
    8: "updating firmware",
}
#: How long a new script connection may take when the old one was lost (s): the stop waits
#: on it.
RECONNECT_S = 1.0
#: How long the controller's stream on the script connection may be silent before it is said
#: (a controller sends its state there ten times a second), s.
SCRIPT_SILENT_S = 2.0
#: How long each step of the dashboard's stop (connect, greeting, answer) may take, s.
DASHBOARD_S = 0.5
#: The longest dashboard answer said in a message, characters.
ANSWER_SHOWN = 80


def _answered(port: int, answer: str) -> str:
    """Say what a dashboard port answered that was not what a dashboard server says.

    A dashboard server answers a line of text; bytes that are not text (control characters,
    or undecodable bytes replaced) come from another server on that port -- RTDE's or the
    primary interface's binary packages, when ``dashboard_port`` names their port -- and are
    never printed: they would fill the terminal with escapes.
    """
    if "\ufffd" in answer or not answer.replace("\t", " ").isprintable():
        return (
            f"port {port} answered with bytes that are not text: not a UR dashboard server "
            "(is dashboard_port another interface's port?)"
        )
    shown = answer if len(answer) <= ANSWER_SHOWN else f"{answer[:ANSWER_SHOWN]}..."
    return f"port {port} answered {shown!r}"


#: The dashboard server's port on every UR controller.
DASHBOARD_PORT = 29999
#: Primary protocol (the script connection's stream): a message's head (size, type), the
#: robot message type and its key message type, a robot message's head (timestamp, source,
#: type) and a key message's (code, argument, title length).
_MESSAGE_HEAD = struct.Struct(">iB")
ROBOT_MESSAGE, KEY_MESSAGE, RUNTIME_EXCEPTION = 20, 7, 10
_ROBOT_MESSAGE_HEAD = struct.Struct(">QbB")
_KEY_HEAD = struct.Struct(">iiB")
#: A runtime exception message's head (line, column); its text follows.
_EXCEPTION_HEAD = struct.Struct(">ii")
#: The largest primary-protocol message taken as framed (a controller's are a few kB).
MAX_MESSAGE = 1 << 20
#: The prefix of this driver's program names (``_script``).
OWN_PROGRAMS = "atikt_"
#: Seconds after its first program by which a controller that names programs has named one
#: (a real controller does within a few cycles; generous for a loaded virtual lab).
NAMED_WITHIN_S = 1.0
#: RTDE samples read when connecting to estimate the controller's clock offset.
OFFSET_SAMPLES = 10
_NS = 1_000_000_000


@dataclasses.dataclass(frozen=True, slots=True)
class Connection:
    """Where the controller is.

    Attributes:
        host: The controller's address.
        rtde_port: RTDE port.
        script_port: The port the programs go to (30001, the primary interface).
        frequency: RTDE packages per second: 125 (CB3) or 500 (e-Series).
        dashboard_port: The dashboard server's port, the stop's way in when no URScript
            connection takes it (0: none).
    """

    host: str
    rtde_port: int
    script_port: int
    frequency: int
    dashboard_port: int = DASHBOARD_PORT


class URArm:
    """A UR arm over RTDE and URScript (an :class:`recorder.runner.ArmDriver`)."""

    def __init__(
        self, connection: Connection, clock: RecorderClock, where: str = "<rig options>"
    ) -> None:
        """Prepare the driver (nothing is opened before ``__enter__``)."""
        self.connection, self.where = connection, where
        self._clock = clock
        self._stack: contextlib.ExitStack | None = None
        self._rtde: RtdeClient | None = None
        self._reader: SourceReader | None = None
        self._script: socket.socket | None = None
        #: Why the script connection was lost (empty: it was not), seen by its reader.
        self._script_lost = ""
        #: Bytes the controller sent on the script connection (read and dropped).
        self.script_bytes = 0
        #: Script connections made again after one was lost.
        self.reconnects = 0
        #: When the controller last sent on the script connection (monotonic ns; 0: never).
        self._heard_ns = 0
        #: Whether the silence of that stream since then was said.
        self._silence_said = False
        #: Whether :meth:`poll` reported the script connection's loss (once per loss).
        self._loss_said = False
        #: The program of another that started since :meth:`begin` (empty: none), seen by
        #: the script reader in the controller's key messages.
        self._foreign = ""
        #: The controller's last runtime exception since :meth:`begin` (empty: none): the
        #: program running was stopped, or one sent did not compile.
        self._exception = ""
        #: The size a message claimed when the script stream stopped being framed.
        self._unframed_size = 0
        #: Programs sent, and starts of the driver's own programs the controller named.
        self.programs_sent = self.own_starts = 0
        #: This driver's mark on its programs' names (``atikt_move_<tag>``): the controller
        #: names every program that starts, so another computer running this recorder against
        #: the same arm (its programs are ``atikt_*`` too) is told apart by it.
        self.tag = secrets.token_hex(3)
        #: When the first program was sent (monotonic ns, 0: none yet). A controller names a
        #: program within a few cycles; one sent just before an action begins (a move to a
        #: pose the arm is at already ends at once) may not be named yet.
        self._first_sent_ns = 0
        self._no_messages_said = False
        #: Why the last new script connection failed.
        self._unsent = ""
        self._version = ""
        #: Whether the dashboard server answered on connecting (empty: not asked).
        self._dashboard = ""
        self._offset_ns = 0
        self._newest_ns = -1
        self._counter = SourceCounter("rtde", period_ns=self.period_ns)
        self._overflow_base = 0
        self._client_malformed_base = 0
        self.malformed = 0
        self.last_error = ""
        #: The context of the last program if it was a speed (its renewals say no phase).
        self._speeding: Context | None = None

    # -- connection -----------------------------------------------------------------------

    def __enter__(self) -> Self:
        """Connect to RTDE and the script port; estimate the controller's clock offset.

        Raises:
            RigError: A connection failed or the controller cannot stream at the frequency.
        """
        with contextlib.ExitStack() as stack:
            link = self.connection
            rtde = RtdeClient(link.host, link.rtde_port, clock=self._clock.now_ns)
            rtde.connect()
            stack.callback(rtde.close)
            # one process drives an arm, whichever port its programs go to (30001, 30002 and
            # 30003 all reach the same controller): the arm is its address and RTDE port
            stack.enter_context(arm_lock(f"ur-{rtde.peer_host}-{link.rtde_port}", self.where))
            major, minor, bugfix, build = rtde.controller_version()
            self._version = f"{major}.{minor}.{bugfix}.{build}"
            if link.frequency > MAX_FREQUENCY.get(major, 500.0):
                msg = (
                    f"{self.where}: rig option frequency = {link.frequency}, but controller "
                    f"{self._version} streams RTDE at {MAX_FREQUENCY[major]:g} Hz at most; "
                    "give frequency = 125"
                )
                raise RigError(msg)
            _setup_outputs(rtde, link.frequency)
            rtde.start()
            reader = SourceReader("rtde", rtde.receive)
            reader.start()
            stack.callback(_stop_rtde, rtde, reader)
            self._rtde, self._reader = rtde, reader
            self._open_script()
            stack.callback(self._close_script)
            self._dashboard = self._probe_dashboard()
            self._offset_ns = self._estimate_offset()
            self._stack = stack.pop_all()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Disconnect, whatever happened."""
        stack, self._stack = self._stack, None
        if stack is not None:
            stack.close()
        self._rtde = self._reader = self._script = None
        self._script_lost = ""  # closed, not lost: nothing is sent again

    def _open_script(self, timeout_s: float = 2.0) -> socket.socket:
        """Connect to the script port, make it the driver's connection and start its reader.

        Raises:
            RigError: The controller did not take the connection within ``timeout_s``.
        """
        link = self.connection
        try:
            sock = socket.create_connection((link.host, link.script_port), timeout=timeout_s)
        except OSError as err:
            msg = (
                f"URScript {link.host}:{link.script_port}: cannot connect ({err}); check the "
                "rig options host and script_port, and that the controller is in remote control"
            )
            raise RigError(msg) from err
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # a stop leaves at once
        # the connection is ours before its reader starts: a loss at once is noted too
        self._script, self._script_lost, self._loss_said = sock, "", False
        reader = threading.Thread(
            target=self._read_script, args=(sock,), daemon=True, name="atikt-urscript"
        )
        reader.start()
        return sock

    def _read_script(self, sock: socket.socket) -> None:
        """Read what the controller sends on ``sock``; note programs of another, and the end."""
        buffer = bytearray()
        framed = True  # a stream that is not the primary protocol is only drained
        while True:
            try:
                chunk = sock.recv(65536)
            except TimeoutError:
                continue
            except OSError as err:
                lost = f"{err.strerror or err}"
                break
            if not chunk:
                lost = "closed by the controller"
                break
            if _QUICKACK is not None:
                # acknowledged at once (Linux): a controller that sends with Nagle's algorithm
                # otherwise holds its next message (another's program started) for our delayed
                # acknowledgement, ~25 ms (measured in the virtual lab with Nagle on)
                sock.setsockopt(socket.IPPROTO_TCP, _QUICKACK, 1)
            self.script_bytes += len(chunk)
            self._heard_ns = time.monotonic_ns()
            if framed:
                buffer += chunk
                framed = self._read_messages(buffer)
                if not framed:
                    link = self.connection
                    _log.warning(
                        "%s: the stream on port %d is not the controller's primary protocol "
                        "(a message of %d bytes): programs of other clients are no longer seen "
                        "on this connection",
                        self.where,
                        link.script_port,
                        self._unframed_size,
                    )
        if self._script is sock:  # not closed by us
            self._script_lost = lost

    def _read_messages(self, buffer: bytearray) -> bool:
        """Take the whole messages off ``buffer``; return False when it is not framed."""
        while len(buffer) >= _MESSAGE_HEAD.size:
            size, kind = _MESSAGE_HEAD.unpack_from(buffer)
            if not _MESSAGE_HEAD.size <= size <= MAX_MESSAGE:
                self._unframed_size = size
                buffer.clear()
                return False
            if len(buffer) < size:
                return True
            if kind == ROBOT_MESSAGE:
                body = bytes(buffer[_MESSAGE_HEAD.size : size])
                started = _started_program(body)
                if started is not None and _own(started, self.tag):
                    self.own_starts += 1
                elif started is not None:
                    self._foreign = started or "a program without a name"
                if (exception := _runtime_exception(body)) is not None:
                    self._exception = exception
            del buffer[:size]
        return True

    def _close_script(self) -> None:
        sock, self._script = self._script, None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)  # ends its reader's recv
            with contextlib.suppress(OSError):
                sock.close()

    def _estimate_offset(self) -> int:
        """Return recorder time minus controller time from the first packages (lowest latency)."""
        reader = self._parts()
        warmup = SourceCounter("rtde", period_ns=self.period_ns)
        deadline = self._clock.now_ns() + 2 * _NS
        while warmup.stats().received < OFFSET_SAMPLES and self._clock.now_ns() < deadline:
            item = reader.get(0.05)
            if item is None:
                reader.check()
                continue
            values = self._parse(item)
            if values is not None:
                warmup.observe(None, _stamp(values), item.receive_ns)
        if warmup.clock_offset_ns is None:
            rtde = self._rtde
            where = rtde.where if rtde is not None else self.connection.host
            msg = f"RTDE {where}: no data package within 2 s after start; check the controller"
            raise RigError(msg)
        return warmup.clock_offset_ns

    def _parts(self) -> SourceReader:
        if self._reader is None or self._rtde is None:
            msg = f"{self.where}: the UR driver is used before it connected; use `with rig:`"
            raise RigError(msg)
        return self._reader

    # -- the driver interface -------------------------------------------------------------

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Return the UR joint names."""
        return JOINT_NAMES

    @property
    def period_ns(self) -> int:
        """Return one controller cycle, ns."""
        return round(_NS / self.connection.frequency)

    def describe(self) -> Mapping[str, str]:
        """Return the connection settings (the rig's identity; the version is a fact)."""
        link = self.connection
        return {
            "host": link.host,
            "rtde_port": str(link.rtde_port),
            "script_port": str(link.script_port),
            "rtde_frequency_hz": str(link.frequency),
        }

    def facts(self) -> Mapping[str, str]:
        """Return the controller's version, and whether its dashboard answered, on connecting."""
        learned = {"controller_version": self._version} if self._version else {}
        if self._dashboard:
            learned["dashboard"] = self._dashboard
        return learned

    def _probe_dashboard(self) -> str:
        """Return whether the dashboard server (the stop's second way in) greets a client.

        Nothing is sent to it: the greeting is read, and the connection closed.
        """
        port = self.connection.dashboard_port
        if not port:
            return "none (dashboard_port = 0)"
        try:
            greeting, _ = self._dashboard_says(None)
        except OSError as err:
            return f"port {port} not reachable ({err.strerror or err})"
        if greeting.startswith("Connected"):
            return f"port {port} answers"
        return _answered(port, greeting)

    def _dashboard_says(self, command: bytes | None) -> tuple[str, str]:
        """Return the dashboard server's greeting and its answer to ``command`` (None: none).

        Each step (connect, greeting, answer) may take :data:`DASHBOARD_S`.

        Raises:
            OSError: The server could not be reached or did not answer in time.
        """
        link = self.connection
        with socket.create_connection((link.host, link.dashboard_port), DASHBOARD_S) as sock:
            sock.settimeout(DASHBOARD_S)
            with sock.makefile("rb") as answers:
                greeting = answers.readline(1024).decode(errors="replace").strip()
                if command is None:
                    return greeting, ""
                sock.sendall(command + b"\n")
                return greeting, answers.readline(1024).decode(errors="replace").strip()

    def begin(self) -> None:
        """Take what queued between actions as the arm's state; count afresh from here.

        A script connection lost since the last action is made again (nothing was moving).
        """
        reader = self._parts()
        if self._script_lost:
            with contextlib.suppress(RigError):
                self._reconnect()
        named_by_now = self._first_sent_ns and (
            time.monotonic_ns() - self._first_sent_ns > NAMED_WITHIN_S * _NS
        )
        if named_by_now and not self.own_starts and not self._no_messages_said:
            self._no_messages_said = True
            link = self.connection
            _log.warning(
                "%s: the controller named none of the %d programs sent to port %d: it sends "
                "no messages there (a secondary interface), so programs of other clients are "
                "not seen; give script_port = 30001 (the primary interface)",
                self.where,
                self.programs_sent,
                link.script_port,
            )
        with contextlib.suppress(SourceLostError):
            for item in reader.drain():
                values = self._parse(item, count=False)
                if values is not None:
                    self._newest_ns = max(self._newest_ns, _stamp(values))
        self._overflow_base = reader.overflowed
        self._counter = SourceCounter("rtde", period_ns=self.period_ns)
        self.malformed = 0
        self._foreign = self._exception = ""
        self._client_malformed_base = self._rtde.malformed if self._rtde is not None else 0

    def poll(self, wait_s: float) -> list[ArmSample]:
        """Return the new in-order state samples, waiting up to ``wait_s`` for the first.

        Raises:
            SourceLostError: The RTDE connection was lost, or the script connection (said
                once: the arm's last program runs on, and no stop could follow it).
        """
        reader = self._parts()
        if (lost := self._script_lost) and not self._loss_said:
            self._loss_said = True
            link = self.connection
            msg = f"URScript connection to {link.host}:{link.script_port} lost ({lost})"
            raise SourceLostError(msg)
        self._check_heard()
        first = reader.get(wait_s) if wait_s > 0 else None
        packages = ([first] if first is not None else []) + reader.drain()
        samples = []
        for package in packages:
            sample = self._sample(package)
            if sample is not None:
                samples.append(sample)
        return samples

    def _check_heard(self) -> None:
        """Say once when the controller's stream on the script connection falls silent.

        A controller sends its state there ten times a second; a stream that stops while the
        connection stays open (a link that forwards one way only) hides the key messages: a
        program of another client would replace ours unseen (the limits still hold: they are
        judged on RTDE).
        """
        heard = self._heard_ns
        if not heard:
            return
        silent_s = (time.monotonic_ns() - heard) / 1e9
        if silent_s <= SCRIPT_SILENT_S:
            self._silence_said = False
        elif not self._silence_said and self._script is not None and not self._script_lost:
            self._silence_said = True
            _log.warning(
                "%s: the controller's messages on port %d stopped arriving %.1f s ago (it "
                "sends its state there ten times a second): a program another client starts "
                "is not seen until they come again; check the network between (a link that "
                "forwards one way only)",
                self.where,
                self.connection.script_port,
                silent_s,
            )

    def _parse(self, package: Received, *, count: bool = True) -> dict[str, Any] | None:
        """Return a package's values; None (counted as malformed) when it cannot be used."""
        recipe = self._rtde.recipe if self._rtde is not None else None
        if recipe is None:
            return None
        try:
            values = recipe.parse(package.payload)
        except (RtdeError, ValueError) as err:
            self.malformed += count
            self.last_error = str(err)
            return None
        if not all(_finite(value) for value in values.values()):
            self.malformed += count
            self.last_error = "RTDE data package with a non-finite value"
            return None
        return values

    def _sample(self, package: Received) -> ArmSample | None:
        """Count one package; return its state if it is new and in order.

        A duplicate or a package older than the newest one is counted, not returned (the
        recording's stamps strictly increase).
        """
        values = self._parse(package)
        return None if values is None else self._state(values, package.receive_ns)

    def _state(self, values: Mapping[str, Any], receive_ns: int) -> ArmSample | None:
        """Count one package's values; return its state if it is new and in order."""
        stamp = _stamp(values)
        if not self._counter.observe(None, stamp, receive_ns) or stamp <= self._newest_ns:
            return None
        self._newest_ns = stamp
        given = "safety_status" if "safety_status" in values else "safety_mode"
        safety, mode = int(values[given]), int(values["robot_mode"])
        stopped = ""
        if safety not in SAFE_STATUS:
            name = SAFETY_NAMES.get(safety, "unsafe state")
            fix = SAFETY_FIXES.get(safety, "see the teach pendant")
            stopped = f"{name} (RTDE {given} {safety}; {fix})"
        elif mode != RUNNING:  # powered off, brakes engaged, backdrive: no program moves it
            name = ROBOT_MODE_NAMES.get(mode, "unknown mode")
            stopped = (
                f"arm not running ({name}: RTDE robot_mode {mode}; power it on and release "
                "its brakes)"
            )
        elif (slider := values.get("target_speed_fraction", 1.0)) < FULL_SPEED:
            # a slide at half its speed is another action: its recording would pass every
            # check and still be wrong
            stopped = (
                f"speed slider at {slider * 100:.0f} % (RTDE target_speed_fraction "
                f"{slider:.3f}; set it to 100 %: an action's speeds are part of its recording)"
            )
        runtime = int(values.get("runtime_state", 1))
        if not stopped and self._exception:
            stopped = f"a runtime exception ({self._exception})"
        if not stopped and runtime in RUNTIME_PAUSED:
            stopped = (
                f"program {RUNTIME_PAUSED[runtime]} (RTDE runtime_state {runtime}: the teach "
                "pendant's or the dashboard's pause; press stop there)"
            )
        busy = ""
        if runtime in RUNTIME_BUSY:
            busy = f"a program is {RUNTIME_BUSY[runtime]} (RTDE runtime_state {runtime})"
        return ArmSample(
            stamp_ns=stamp + self._offset_ns,
            receive_ns=receive_ns,
            q=np.asarray(values["actual_q"], dtype=np.float64),
            qd=np.asarray(values["actual_qd"], dtype=np.float64),
            effort=np.asarray(values["target_moment"], dtype=np.float64),
            tcp_pose=np.asarray(values["actual_TCP_pose"], dtype=np.float64),
            tcp_force=np.asarray(values["actual_TCP_force"], dtype=np.float64),
            stopped=stopped,
            busy=busy,
            replaced=(
                f"another client's program {self._foreign!r} started on the controller and "
                "replaced ours (a second computer or the teach pendant: one drives the arm)"
                if self._foreign
                else ""
            ),
        )

    def speed(
        self, velocity: NDArray[np.float64], acceleration: float, duration_s: float, at: Context
    ) -> None:
        """Send ``speedl``."""
        # a renewal of the same phase's speed (the runner's lease) says its phase only once:
        # the controller's log gets one line per phase, not four a second
        said = None if at == self._speeding else _said(at)
        self._send(speed_program(said, at.phase, velocity, acceleration, duration_s))
        self._speeding = at

    def move(
        self, pose: NDArray[np.float64], speed: float, acceleration: float, at: Context | None
    ) -> None:
        """Send ``movel``."""
        phase = "present" if at is None else at.phase
        back, lease = ((), 0.0) if at is None else (at.back, at.lease_s)
        self._send(move_program(_said(at), phase, pose, speed, acceleration, back, lease))

    def force_slide(
        self,
        force_n: float,
        velocity: NDArray[np.float64],
        duration_s: float,
        acceleration: float,
        at: Context,
    ) -> None:
        """Send ``force_mode`` with ``speedl``, then ``end_force_mode`` and ``stopl``."""
        said = Announcement(at.object_id, at.action_id, at.trial)
        program = slide_program(said, at.phase, force_n, velocity, duration_s, acceleration)
        self._send(program)

    def announce(self, at: Context) -> None:
        """Send a program that only writes the phase into the controller's log."""
        self._send(
            program(
                "atikt_mark", [Announcement(at.object_id, at.action_id, at.trial).line(at.phase)]
            )
        )

    def stop(self, acceleration: float, at: Context | None) -> str:
        """Send ``stopl``, over a new connection if the script connection was lost.

        When no new connection takes it either, the dashboard server's ``stop`` ends the
        running program (the arm brakes at the controller's own deceleration).

        Returns:
            How the arm was stopped when not by ``stopl`` (empty: by ``stopl``).

        Raises:
            SourceLostError: Neither the script connections nor the dashboard took it.
        """
        phase = "stop" if at is None else at.phase
        try:
            self._send(stop_program(_said(at), phase, acceleration), reconnect=True)
        except SourceLostError as lost:
            refused = self._dashboard_stop()
            if refused:
                msg = f"{lost}; the dashboard's stop failed ({refused})"
                raise SourceLostError(msg) from None
            # the loss is said in the stop's line: the state read next is the arm's, not it
            self._loss_said = True
            link = self.connection
            return (
                f"the arm was stopped by the dashboard server {link.host}:"
                f"{link.dashboard_port} (no new URScript connection: {self._unsent})"
            )
        return ""

    def stop_otherwise(self) -> str:
        """Stop the arm by the dashboard server: the URScript stop did not bring it to rest.

        A script connection that takes the bytes but delivers none (half dead: no error, no
        end) looks like a live one; the dashboard shares no socket with it.

        Raises:
            SourceLostError: The dashboard's stop failed (no ``dashboard_port``, refused).
        """
        link = self.connection
        if refused := self._dashboard_stop():
            msg = f"the dashboard's stop failed ({refused})"
            raise SourceLostError(msg)
        return f"the dashboard server {link.host}:{link.dashboard_port} took the stop"

    def _dashboard_stop(self) -> str:
        """Send the dashboard server ``stop``; return why it failed (empty: it stopped).

        A controller answers ``Stopped`` once the program is ended; anything else (``Failed
        to execute: stop``, in local control on an e-Series) is a stop not taken.
        """
        link = self.connection
        if not link.dashboard_port:
            return "no dashboard_port"
        try:
            _, answer = self._dashboard_says(b"stop")
        except OSError as err:
            return f"port {link.dashboard_port}: {err.strerror or err}"
        if answer.lower().startswith("stopped"):
            return ""
        return _answered(link.dashboard_port, answer)

    def stats(self) -> list[SourceStats]:
        """Return the RTDE stream's accounting since :meth:`begin`."""
        reader = self._reader
        if reader is not None:
            missed = reader.overflowed - self._overflow_base
            if missed:
                self._counter.overflow(missed)
                self._overflow_base = reader.overflowed
        stats = self._counter.stats()
        # left out by the client (another recipe, the wrong size, NaN) or by the driver
        rtde = self._rtde
        client = rtde.malformed - self._client_malformed_base if rtde is not None else 0
        if malformed := self.malformed + client:
            stats = dataclasses.replace(stats, malformed=stats.malformed + malformed)
        return [stats]

    def _named(self, text: str) -> str:
        """Return a program with this driver's :attr:`tag` in its name."""
        return _tagged(text, self.tag)

    def _send(self, text: str, *, reconnect: bool = False) -> None:
        """Send a URScript program (it replaces the running one).

        Args:
            text: The program.
            reconnect: When the connection was lost, send over a new one (the stop); else
                a lost connection raises (a program of an action that may have lost its
                predecessors).

        Raises:
            SourceLostError: The script connection is closed or lost (and, with
                ``reconnect``, a new one failed too).
        """
        self._speeding = None
        sock, lost = self._script, self._script_lost
        link = self.connection
        where = f"{link.host}:{link.script_port}"
        if sock is None and not lost:
            msg = f"URScript connection to {where} is closed"
            raise SourceLostError(msg)
        data = self._named(text).encode()
        if sock is not None and not lost:
            try:
                sock.sendall(data)
            except OSError as err:
                lost = self._script_lost = f"{err.strerror or err}"
            else:
                self.programs_sent += 1
                self._first_sent_ns = self._first_sent_ns or time.monotonic_ns()
                return
        if not reconnect:
            msg = f"URScript connection to {where} lost ({lost})"
            raise SourceLostError(msg)
        try:
            self._reconnect().sendall(data)
        except (RigError, OSError) as err:
            cause = (err.strerror or str(err)) if isinstance(err, OSError) else "cannot connect"
            self._unsent = cause
            msg = f"URScript connection to {where} lost ({lost}); a new one failed ({cause})"
            raise SourceLostError(msg) from None

    def _reconnect(self) -> socket.socket:
        """Replace a lost script connection by a new one.

        Raises:
            RigError: The controller did not take it within :data:`RECONNECT_S`.
        """
        self._close_script()
        sock = self._open_script(RECONNECT_S)
        self.reconnects += 1
        return sock


def _setup_outputs(rtde: RtdeClient, frequency: int) -> None:
    """Set up the first of :data:`RECIPES` the controller provides.

    Raises:
        RtdeError: It provides none (the error names what it lacks of :data:`RTDE_VARIABLES`).
    """
    said: RtdeError | None = None
    for names in RECIPES:
        try:
            rtde.setup_outputs(names, frequency)
        except RtdeError as err:
            said = err if said is None or names == RTDE_VARIABLES else said
        else:
            return
    assert said is not None  # noqa: S101 (RECIPES is not empty)
    raise said


def _stop_rtde(rtde: RtdeClient, reader: SourceReader) -> None:
    with contextlib.suppress(RtdeError):
        rtde.pause(timeout_s=0.2)
    reader.stop()


def _own(name: str, tag: str) -> bool:
    """Whether program ``name`` is one this driver (``tag``) sent."""
    return name.startswith(OWN_PROGRAMS) and name.endswith(f"_{tag}")


def _tagged(text: str, tag: str) -> str:
    """Return a ``def name():`` program as ``def name_<tag>():`` (see :attr:`URArm.tag`)."""
    if not text.startswith("def "):
        return text
    name, rest = text[4:].split("(", 1)
    return f"def {name}_{tag}({rest}"


def _started_program(body: bytes) -> str | None:
    """Return the program a robot message says started (None: another message)."""
    head = _ROBOT_MESSAGE_HEAD.size + _KEY_HEAD.size
    if len(body) < head or body[_ROBOT_MESSAGE_HEAD.size - 1] != KEY_MESSAGE:
        return None
    title_size = body[head - 1]
    title = body[head : head + title_size]
    if title != b"PROGRAM_XXX_STARTED":
        return None
    return body[head + title_size :].decode(errors="replace")


def _runtime_exception(body: bytes) -> str | None:
    """Return the text of a runtime exception message (None: another message)."""
    head = _ROBOT_MESSAGE_HEAD.size + _EXCEPTION_HEAD.size
    if len(body) < head or body[_ROBOT_MESSAGE_HEAD.size - 1] != RUNTIME_EXCEPTION:
        return None
    line, column = _EXCEPTION_HEAD.unpack_from(body, _ROBOT_MESSAGE_HEAD.size)
    text = body[head:].decode(errors="replace").strip() or "no text"
    return f"line {line}, column {column}: {text}" if line > 0 else text


def _said(at: Context | None) -> Announcement | None:
    return None if at is None else Announcement(at.object_id, at.action_id, at.trial)


def _stamp(values: Mapping[str, Any]) -> int:
    return round(float(values["timestamp"]) * _NS)


def _finite(value: object) -> bool:
    if isinstance(value, np.ndarray):
        return bool(np.all(np.isfinite(value)))
    return not isinstance(value, float) or math.isfinite(value)
