"""The virtual lab's dashboard server (port 29999): the subset a lab's own scripts use.

A UR controller's dashboard server takes one command per line and answers one line. The
virtual lab answers ``robotmode``, ``safetymode`` (and ``safetystatus``), ``stop`` (the
running program ends; the arm brakes), ``play`` (nothing to resume: the lab runs the programs
sent to its URScript port as they arrive), ``unlock protective stop`` (releases a protective
stop) and ``close safety popup``; anything else is answered as a controller answers an
unknown command. On connecting, a client gets the controller's greeting.
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING

from recorder.virtuallab._tcp import TcpServer
from recorder.virtuallab._world import SAFETY_EMERGENCY_STOP, SAFETY_PROTECTIVE_STOP

if TYPE_CHECKING:
    import socket

    from recorder.virtuallab._controller import VirtualController

GREETING = "Connected: Universal Robots Dashboard Server\n"
_SAFETY = {
    1: "NORMAL",
    SAFETY_PROTECTIVE_STOP: "PROTECTIVE_STOP",
    SAFETY_EMERGENCY_STOP: "ROBOT_EMERGENCY_STOP",
}
#: Longest command line read, bytes (a longer one is dropped).
MAX_LINE = 1024


class DashboardServer(TcpServer):
    """Answer dashboard commands on ``host:port`` (a context manager; port 0: a free one)."""

    thread_name = "atikt-dashboard"

    def __init__(
        self, controller: VirtualController, host: str = "127.0.0.1", port: int = 29999
    ) -> None:
        """Prepare the server (it listens from ``__enter__``)."""
        self.controller = controller
        super().__init__(host, port)

    def serve(self, sock: socket.socket) -> None:
        """Answer one client's commands until it leaves."""
        sock.settimeout(0.1)
        buffer = b""
        with contextlib.closing(sock), contextlib.suppress(OSError):
            sock.sendall(GREETING.encode())
            while not self.stopping.is_set():
                try:
                    chunk = sock.recv(4096)
                except TimeoutError:
                    continue
                if not chunk:
                    return
                buffer += chunk
                while b"\n" in buffer:
                    line, buffer = buffer.split(b"\n", 1)
                    sock.sendall((self.answer(line.decode(errors="replace")) + "\n").encode())
                buffer = buffer[-MAX_LINE:]

    def answer(self, command: str) -> str:  # noqa: PLR0911 (one answer per command)
        """Return the answer to one command (and do what it says)."""
        world = self.controller.world
        text = command.strip().lower()
        safety = world.safety
        if text == "robotmode":
            return "Robotmode: RUNNING"
        if text in {"safetymode", "safetystatus"}:
            name = _SAFETY.get(safety, str(safety))
            return f"{'Safetymode' if text == 'safetymode' else 'Safetystatus'}: {name}"
        if text == "stop":
            world.halt_program()
            return "Stopped"
        if text == "play":
            return "Starting program"
        if text == "unlock protective stop":
            if safety == SAFETY_PROTECTIVE_STOP:
                world.unlock()
            return "Protective stop releasing"
        if text == "close safety popup":
            return "closing safety popup"
        return f"could not understand: '{command.strip()}'"
