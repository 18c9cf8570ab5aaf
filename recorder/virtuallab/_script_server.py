"""The virtual lab's URScript port: programs are parsed, checked and run on the virtual arm.

A UR controller's primary interface (port 30001) takes a program as text; a new program
replaces the running one. This server cuts the stream into programs (``def name(): ... end``
or one line; a program above ``MAX_PROGRAM_BYTES``, or a definition unterminated past it, is
refused with one log line and dropped), checks each as the controller's compiler would (an
unknown function or an argument that is not a literal: one error line, the program does not
run) and hands it to the world, which runs it cycle by cycle (``_runner``).

Like a controller's primary interface, it streams the arm's state to every client at 10 Hz:
a primary-protocol robot state message (type 16) holding the robot mode data sub-package
(type 0, the CB3 layout: timestamp, the power, stop and program flags, robot and control
mode, speed fractions). When a program starts, every client gets the controller's key message
``PROGRAM_XXX_STARTED`` with the program's name (a robot message, type 20, of key type 7), as
a controller sends it on its primary interface (its secondary, 30002, sends no messages); a
program the lab cannot run gets a runtime exception message (type 10) with the error. A
client that does not read only misses messages (a full buffer drops them); a client must not
stall the programs it sends.

Faults: a protective stop ``protective_stop_s`` (real seconds) after each announced action
begins; the URScript connections closed ``drop_s`` after each announced action begins (a
switch or cable glitch, a controller dropping a client); the port gone ``gone_s`` after an
action begins (connections closed, new ones refused: only the dashboard server can stop the
arm then); the connections deaf ``deaf_s`` after an action begins (open, their programs
received and never run, nothing said: a half-dead link that forwards nothing, whose stop only
the dashboard server delivers).
"""

from __future__ import annotations

import contextlib
import select
import socket
import struct
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from recorder.virtuallab._runner import RUNTIME_PAUSED, RUNTIME_PLAYING
from recorder.virtuallab._tcp import TcpServer
from recorder.virtuallab._urscript import (
    MAX_PROGRAM_BYTES,
    ProgramSplitter,
    check_program,
    parse_program,
    split_programs,
)
from recorder.virtuallab._world import (
    ROBOT_MODE_IDLE,
    SAFETY_EMERGENCY_STOP,
    SAFETY_NORMAL,
)

if TYPE_CHECKING:
    from collections.abc import Iterator

    from recorder.virtuallab._controller import VirtualController

__all__ = ["ScriptFaults", "ScriptServer", "check_program", "split_programs"]
#: Programs' texts kept for tests (the newest).
KEPT_PROGRAMS = 100
#: The state stream's period on the URScript port, s (a primary interface's 10 Hz).
STATE_PERIOD_S = 0.1
#: Primary protocol: message type robot state, sub-package type robot mode data.
ROBOT_STATE, ROBOT_MODE_DATA = 16, 0
#: Robot mode data, CB3 layout: timestamp (us), 7 flags (real robot connected, enabled, power
#: on, emergency stopped, protective stopped, program running, program paused), robot mode,
#: control mode, target speed fraction, speed scaling, target speed fraction limit.
_MODE_DATA = struct.Struct(">iBQ???????BBddd")
_MESSAGE = struct.Struct(">iB")
#: Primary protocol: message type robot message, its key message type.
ROBOT_MESSAGE, KEY_MESSAGE, RUNTIME_EXCEPTION = 20, 7, 10
#: A robot message's head (timestamp in us, source, type) and a key message's (code,
#: argument, title length).
_ROBOT_MESSAGE = struct.Struct(">QbB")
_KEY = struct.Struct(">iiB")
#: A runtime exception message's head (line, column).
_EXCEPTION = struct.Struct(">ii")
#: How often a client's loop looks whether the server stops, s.
STOP_POLL_S = 0.1
#: How long the rest of a message begun may take to send, s.
SEND_TIMEOUT_S = 0.1


@dataclass(slots=True)
class _Outbox:
    """Messages waiting for one client, and the socket that wakes its thread."""

    waker: socket.socket
    messages: list[bytes] = field(default_factory=list)

    def put(self, message: bytes) -> None:
        """Add a message and wake the client's thread (a full wake buffer: it is awake)."""
        self.messages.append(message)
        with contextlib.suppress(OSError):
            self.waker.send(b"\0")

    def take(self) -> list[bytes]:
        """Return the waiting messages, leaving none."""
        taken, self.messages = self.messages, []
        return taken


@dataclass(frozen=True, slots=True)
class ScriptFaults:
    """Faults of the URScript side.

    Attributes:
        protective_stop_s: A protective stop this long (real seconds) after an action
            starts (0: never).
        drop_s: Close every URScript connection this long (real seconds) after an action
            starts (0: never); the port takes new connections.
        gone_s: Close the port this long (real seconds) after an action starts (0: never):
            its connections are closed and new ones refused.
        deaf_s: This long (real seconds) after an action starts (0: never), the connections
            open then take programs and never run them, and say nothing (a half-dead link);
            new connections work.
    """

    protective_stop_s: float = 0.0
    drop_s: float = 0.0
    gone_s: float = 0.0
    deaf_s: float = 0.0


class ScriptServer(TcpServer):
    """Accept URScript programs on ``host:port`` (a context manager; port 0: a free one)."""

    thread_name = "atikt-script"
    #: A message leaves when it happens: with Nagle's algorithm a key message (a program
    #: started) waited for the acknowledgement of the state message before it, ~25 ms on
    #: loopback, and a driver saw another client's program 12 cycles late at 500 Hz.
    no_delay = True

    def __init__(
        self,
        controller: VirtualController,
        host: str = "127.0.0.1",
        port: int = 30001,
        *,
        faults: ScriptFaults | None = None,
        limit: int = MAX_PROGRAM_BYTES,
    ) -> None:
        """Prepare the server (it listens from ``__enter__``)."""
        self.controller = controller
        super().__init__(host, port)
        self.faults = faults or ScriptFaults()
        self.limit = limit
        self._lock = threading.Lock()
        self._programs: list[str] = []
        self.stops_injected = 0
        self.drops_injected = 0
        self._clients: set[socket.socket] = set()
        #: Connections gone deaf (``deaf_s``): their programs are received and never run.
        self._deaf: set[socket.socket] = set()
        self.deafened = 0
        #: Messages waiting for each client (sent by the client's own thread, whole).
        self._outbox: dict[socket.socket, _Outbox] = {}
        controller.world.on_program(self._started)
        if self.faults.protective_stop_s > 0:
            controller.world.on_action(self._arm_stop)
        if self.faults.drop_s > 0:
            controller.world.on_action(self._arm_drop)
        if self.faults.gone_s > 0:
            controller.world.on_action(self._arm_gone)
        if self.faults.deaf_s > 0:
            controller.world.on_action(self._arm_deaf)

    @property
    def programs(self) -> list[str]:
        """Return the newest programs received (at most ``KEPT_PROGRAMS``)."""
        with self._lock:
            return list(self._programs)

    def serve(self, sock: socket.socket) -> None:
        """Read programs from one client until it leaves; send it the state and messages.

        A message (a program started) wakes the client's thread at once, as a controller
        sends it when it happens, not at the next state message.
        """
        splitter = ProgramSplitter(self.limit)
        sock.settimeout(SEND_TIMEOUT_S)  # a message begun is finished within this
        wake, waker = socket.socketpair()
        waker.settimeout(0.0)  # a wake never blocks the world
        with self._lock:
            self._clients.add(sock)
            self._outbox[sock] = _Outbox(waker)
        next_state = time.monotonic()
        with (
            contextlib.closing(sock),
            contextlib.closing(wake),
            contextlib.closing(waker),
            contextlib.suppress(OSError),
            self._client(sock),
        ):
            while not self.stopping.is_set():
                wait = min(max(next_state - time.monotonic(), 0.0), STOP_POLL_S)
                ready, _, _ = select.select([sock, wake], [], [], wait)
                if wake in ready:
                    wake.recv(4096)
                with self._lock:
                    waiting = self._outbox[sock].take()
                if time.monotonic() >= next_state:
                    next_state += STATE_PERIOD_S
                    waiting.append(self.state_message())
                for message in waiting:
                    _send_whole(sock, message)
                if sock not in ready:
                    continue
                chunk = sock.recv(65536)
                if not chunk:
                    return
                received = time.monotonic_ns()
                programs, refusals = splitter.feed(chunk.decode(errors="replace"))
                for refusal in refusals:
                    self._refuse(refusal)
                with self._lock:
                    deaf = sock in self._deaf
                for program in programs if not deaf else ():
                    self.run(program, received)

    def state_message(self) -> bytes:
        """Return the arm's state now as a primary-protocol robot state message."""
        world = self.controller.world
        now = world.controller_ns()
        state = world.robot_at(now)
        safety, runtime = state.safety_status, state.runtime_state
        flags = (
            False,  # real robot connected: a virtual lab
            False,  # real robot enabled
            state.robot_mode >= ROBOT_MODE_IDLE,  # power on
            safety == SAFETY_EMERGENCY_STOP,
            safety not in {SAFETY_NORMAL, SAFETY_EMERGENCY_STOP},  # protective stopped
            runtime == RUNTIME_PLAYING,
            runtime == RUNTIME_PAUSED,
        )
        data = _MODE_DATA.pack(
            _MODE_DATA.size,
            ROBOT_MODE_DATA,
            now // 1000,
            *flags,
            state.robot_mode,
            0,  # control mode: position
            state.speed_fraction,
            state.speed_fraction,
            1.0,
        )
        return _MESSAGE.pack(_MESSAGE.size + len(data), ROBOT_STATE) + data

    def _started(self, name: str) -> None:
        """Tell every client that program ``name`` started (a key message)."""
        world = self.controller.world
        self._tell(key_message("PROGRAM_XXX_STARTED", name, world.controller_ns() // 1000))

    def _tell(self, message: bytes) -> None:
        """Send ``message`` to every client (each client's thread sends it, whole)."""
        with self._lock:
            for outbox in self._outbox.values():
                outbox.put(message)

    @contextlib.contextmanager
    def _client(self, sock: socket.socket) -> Iterator[None]:
        try:
            yield
        finally:
            with self._lock:
                self._clients.discard(sock)
                self._deaf.discard(sock)
                self._outbox.pop(sock, None)

    def run(self, text: str, received_ns: int | None = None) -> None:
        """Check a program and run it (it replaces the running one)."""
        with self._lock:
            self._programs = [*self._programs[-(KEPT_PROGRAMS - 1) :], text]
        program = parse_program(text, received_ns or time.monotonic_ns())
        if program.errors:
            for error in program.errors:
                self._refuse(f"URScript error, program not run: {error}")
            world = self.controller.world
            self._tell(runtime_exception("; ".join(program.errors), world.controller_ns() // 1000))
            return
        self.controller.execute(program)

    def _refuse(self, line: str) -> None:
        world = self.controller.world
        world.events_log.add("program_refused", world.controller_ns(), reason=line)
        self.controller.note(line)

    def _arm_stop(self, _action: tuple[str, str, int]) -> None:
        """Schedule the injected protective stop after an action began."""
        timer = threading.Timer(self.faults.protective_stop_s, self._protective_stop)
        timer.daemon = True
        timer.start()

    def _arm_drop(self, _action: tuple[str, str, int]) -> None:
        """Schedule the injected drop of the connections after an action began."""
        timer = threading.Timer(self.faults.drop_s, self.drop_clients)
        timer.daemon = True
        timer.start()

    def _arm_gone(self, _action: tuple[str, str, int]) -> None:
        """Schedule the injected loss of the port after an action began."""
        timer = threading.Timer(self.faults.gone_s, self.close_port)
        timer.daemon = True
        timer.start()

    def _arm_deaf(self, _action: tuple[str, str, int]) -> None:
        """Schedule the connections' going deaf after an action began."""
        timer = threading.Timer(self.faults.deaf_s, self.deafen_clients)
        timer.daemon = True
        timer.start()

    def deafen_clients(self) -> None:
        """Ignore every program of the connections open now (injected fault)."""
        with self._lock:
            fresh = self._clients - self._deaf
            self._deaf |= fresh
            self.deafened += len(fresh)
        if not fresh:
            return
        world = self.controller.world
        world.events_log.add("fault", world.controller_ns(), source="script", fault="deaf")
        self.controller.note(
            f"URScript connections deaf ({len(fresh)}: their programs are no longer run; "
            "injected fault)"
        )

    def close_port(self) -> None:
        """Refuse new connections from now on and close every client's (injected fault)."""
        self.stop_listening()
        self.drop_clients("gone")

    def drop_clients(self, fault: str = "drop") -> None:
        """Close every client's connection (the port takes new ones unless it is gone)."""
        with self._lock:
            clients = list(self._clients)
            self.drops_injected += 1
        for sock in clients:
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RDWR)
        world = self.controller.world
        world.events_log.add("fault", world.controller_ns(), source="script", fault=fault)
        said = "dropped" if fault == "drop" else "dropped, the port closed"
        self.controller.note(f"URScript connections {said} ({len(clients)}; injected fault)")

    def _protective_stop(self) -> None:
        with self._lock:
            self.stops_injected += 1
        world = self.controller.world
        world.stop("protective")
        world.events_log.add(
            "fault", world.controller_ns(), source="script", fault="protective_stop"
        )
        self.controller.note("protective stop (injected fault)")


def key_message(title: str, text: str, timestamp_us: int) -> bytes:
    """Return a primary-protocol key message (a controller's ``PROGRAM_XXX_STARTED``...)."""
    head = _ROBOT_MESSAGE.pack(timestamp_us, -2, KEY_MESSAGE)  # source -2: the controller
    title_bytes = title.encode()
    body = head + _KEY.pack(0, 0, len(title_bytes)) + title_bytes + text.encode()
    return _MESSAGE.pack(_MESSAGE.size + len(body), ROBOT_MESSAGE) + body


def runtime_exception(text: str, timestamp_us: int) -> bytes:
    """Return a primary-protocol runtime exception message (a program the controller stopped)."""
    head = _ROBOT_MESSAGE.pack(timestamp_us, -2, RUNTIME_EXCEPTION)
    body = head + _EXCEPTION.pack(0, 0) + text.encode()
    return _MESSAGE.pack(_MESSAGE.size + len(body), ROBOT_MESSAGE) + body


def _send_whole(sock: socket.socket, message: bytes) -> None:
    """Send a message whole, or nothing of it when the client's buffer is full.

    A message begun is finished (blocking up to the socket's timeout), so the stream stays
    framed; a client that does not read at all misses messages.
    """
    try:
        sent = sock.send(message, socket.MSG_DONTWAIT)
    except BlockingIOError:
        return
    if sent < len(message):
        sock.sendall(message[sent:])
