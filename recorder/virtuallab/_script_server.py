"""The virtual lab's URScript port: programs are parsed, checked and run on the virtual arm.

A UR controller's secondary interface (port 30002) takes a program as text; a new program
replaces the running one. This server cuts the stream into programs (``def name(): ... end``
or one line; a program above ``MAX_PROGRAM_BYTES``, or a definition unterminated past it, is
refused with one log line and dropped), checks each as the controller's compiler would (an
unknown function or an argument that is not a literal: one error line, the program does not
run) and hands it to the world, which runs it cycle by cycle (``_runner``).

Fault for tests: a protective stop ``protective_stop_s`` (real seconds) after each announced
action begins.
"""

from __future__ import annotations

import contextlib
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

from recorder.virtuallab._tcp import TcpServer
from recorder.virtuallab._urscript import (
    MAX_PROGRAM_BYTES,
    ProgramSplitter,
    check_program,
    parse_program,
    split_programs,
)

if TYPE_CHECKING:
    import socket

    from recorder.virtuallab._controller import VirtualController

__all__ = ["ScriptFaults", "ScriptServer", "check_program", "split_programs"]
#: Programs' texts kept for tests (the newest).
KEPT_PROGRAMS = 100


@dataclass(frozen=True, slots=True)
class ScriptFaults:
    """Faults of the URScript side.

    Attributes:
        protective_stop_s: A protective stop this long (real seconds) after an action
            starts (0: never).
    """

    protective_stop_s: float = 0.0


class ScriptServer(TcpServer):
    """Accept URScript programs on ``host:port`` (a context manager; port 0: a free one)."""

    thread_name = "atikt-script"

    def __init__(
        self,
        controller: VirtualController,
        host: str = "127.0.0.1",
        port: int = 30002,
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
        if self.faults.protective_stop_s > 0:
            controller.world.on_action(self._arm_stop)

    @property
    def programs(self) -> list[str]:
        """Return the newest programs received (at most ``KEPT_PROGRAMS``)."""
        with self._lock:
            return list(self._programs)

    def serve(self, sock: socket.socket) -> None:
        """Read programs from one client until it leaves."""
        splitter = ProgramSplitter(self.limit)
        sock.settimeout(0.1)
        with contextlib.closing(sock), contextlib.suppress(OSError):
            while not self.stopping.is_set():
                try:
                    chunk = sock.recv(65536)
                except TimeoutError:
                    continue
                if not chunk:
                    return
                received = time.monotonic_ns()
                programs, refusals = splitter.feed(chunk.decode(errors="replace"))
                for refusal in refusals:
                    self._refuse(refusal)
                for program in programs:
                    self.run(program, received)

    def run(self, text: str, received_ns: int | None = None) -> None:
        """Check a program and run it (it replaces the running one)."""
        with self._lock:
            self._programs = [*self._programs[-(KEPT_PROGRAMS - 1) :], text]
        program = parse_program(text, received_ns or time.monotonic_ns())
        if program.errors:
            for error in program.errors:
                self._refuse(f"URScript error, program not run: {error}")
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

    def _protective_stop(self) -> None:
        with self._lock:
            self.stops_injected += 1
        world = self.controller.world
        world.stop("protective")
        world.events_log.add(
            "fault", world.controller_ns(), source="script", fault="protective_stop"
        )
        self.controller.note("protective stop (injected fault)")
