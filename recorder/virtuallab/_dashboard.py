"""The virtual lab's dashboard server (port 29999): the subset a lab's own scripts use.

A UR controller's dashboard server takes one command per line and answers one line. The
virtual lab answers ``robotmode``, ``safetymode`` (and ``safetystatus``), ``programState``,
``stop`` (the running program ends; the arm brakes), ``pause`` (the program waits; the arm
brakes), ``play`` (a paused program goes on; with none paused it fails: the lab runs the
programs sent to its URScript port as they arrive), ``unlock protective stop`` (releases a
protective stop), ``power off``, ``power on`` and ``brake release`` (the robot mode: an arm
that is not running takes no program and does not move) and ``close safety popup``; what a lab's
scripts ask before they start (``ur_rtde``'s ``DashboardClient``): ``PolyscopeVersion`` (the
version the RTDE port reports), ``running``, ``get robot model``, ``get serial number``,
``get loaded program`` and, on an e-Series (500 Hz), ``is in remote control`` (always true:
the lab runs what it is sent). Anything else is answered as a controller answers an unknown
command. On connecting, a client gets the controller's greeting.
"""

from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING

from recorder.virtuallab._rtde_server import VERSIONS
from recorder.virtuallab._runner import RUNTIME_PLAYING
from recorder.virtuallab._tcp import TcpServer
from recorder.virtuallab._world import (
    ROBOT_MODE_IDLE,
    ROBOT_MODE_POWER_OFF,
    ROBOT_MODE_RUNNING,
    SAFETY_EMERGENCY_STOP,
    SAFETY_PROTECTIVE_STOP,
)

if TYPE_CHECKING:
    import socket

    from recorder.virtuallab._controller import VirtualController

GREETING = "Connected: Universal Robots Dashboard Server\n"
_SAFETY = {
    1: "NORMAL",
    SAFETY_PROTECTIVE_STOP: "PROTECTIVE_STOP",
    SAFETY_EMERGENCY_STOP: "ROBOT_EMERGENCY_STOP",
}
_MODES = {ROBOT_MODE_POWER_OFF: "POWER_OFF", ROBOT_MODE_IDLE: "IDLE", ROBOT_MODE_RUNNING: "RUNNING"}
#: ``programState`` answers by RTDE ``runtime_state`` (a controller adds the program's name).
_PROGRAM_STATES = {0: "STOPPED", 1: "STOPPED", 2: "PLAYING", 4: "PAUSED"}
#: Dashboard commands that change the robot mode: the mode they lead to, their answer.
_POWER = {
    "power off": (ROBOT_MODE_POWER_OFF, "Powering off"),
    "power on": (ROBOT_MODE_IDLE, "Powering on"),
    "brake release": (ROBOT_MODE_RUNNING, "Brake releasing"),
}
#: The first PolyScope major version of the e-Series (its dashboard knows remote control).
E_SERIES = 5
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
            mode = world.robot_mode
            return f"Robotmode: {_MODES.get(mode, str(mode))}"
        if text in _POWER:
            mode, said = _POWER[text]
            if text != "brake release" or world.robot_mode != ROBOT_MODE_POWER_OFF:
                world.power(mode)  # a controller releases no brakes of an arm powered off
            return said
        if text in {"safetymode", "safetystatus"}:
            name = _SAFETY.get(safety, str(safety))
            return f"{'Safetymode' if text == 'safetymode' else 'Safetystatus'}: {name}"
        programs = {
            "stop": (world.halt_program, "Stopped"),
            "pause": (world.pause, "Pausing program"),
            # with nothing paused, as a controller answers when there is nothing to play
            "play": (world.play, "Starting program"),
        }
        if text in programs:
            do, said = programs[text]
            return said if do() is not False else "Failed to execute: play"
        if text == "programstate":
            state = world.robot_at(world.controller_ns()).runtime_state
            return _PROGRAM_STATES.get(state, "STOPPED")
        if text == "unlock protective stop":
            if safety == SAFETY_PROTECTIVE_STOP:
                world.unlock()
            return "Protective stop releasing"
        if text == "close safety popup":
            return "closing safety popup"
        return self._about(text) or f"could not understand: '{command.strip()}'"

    def _about(self, text: str) -> str:
        """Answer the questions about the controller ('' for another command)."""
        world = self.controller.world
        major, minor, bugfix, build = VERSIONS[world.frequency]
        playing = world.robot_at(world.controller_ns()).runtime_state == RUNTIME_PLAYING
        answers = {
            "polyscopeversion": f"URSoftware {major}.{minor}.{bugfix}.{build} (virtual lab)",
            "running": f"Program running: {'true' if playing else 'false'}",
            "get robot model": "UR10",
            "get serial number": "virtual lab",
            "get loaded program": "No program loaded",
        }
        if major >= E_SERIES:  # a CB3's dashboard does not know the command
            answers["is in remote control"] = "true"
        return answers.get(text, "")
