"""The virtual lab's URScript port: programs are checked, announced actions are played.

A UR controller's secondary interface (port 30002) takes a program as text; a new program
replaces the running one. This server accepts the subset the UR rig sends (``def name(): ...
end`` with one function call per line, or a single line) and checks it as the controller's
compiler would: an unknown function is an error logged in one line, and the program does not
run. A valid program's ``textmsg("atikt: object=.. action=.. trial=.. phase=approach")``
starts that action in the world; a ``movel`` outside an action parks the arm at its target;
the other calls are checked, not executed (the world plays the simulator's motion).

Fault for tests: a protective stop ``protective_stop_s`` after an action starts.
"""

from __future__ import annotations

import contextlib
import re
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from recorder.errors import RigError
from recorder.ur._script import FUNCTIONS
from recorder.virtuallab._tcp import TcpServer

if TYPE_CHECKING:
    import socket

    from recorder.virtuallab._controller import VirtualController

_CALL = re.compile(r"([A-Za-z_]\w*)\s*\(")
_STATEMENT = re.compile(r"^[A-Za-z_]\w*\s*\(.*\)$")
_ANNOUNCE = re.compile(r'textmsg\("atikt:([^"]*)"\)')
_POSE = re.compile(r"movel\(\s*p\[([^\]]*)\]")


@dataclass(frozen=True, slots=True)
class ScriptFaults:
    """Faults of the URScript side.

    Attributes:
        protective_stop_s: A protective stop this long (real seconds) after an action
            starts (0: never).
    """

    protective_stop_s: float = 0.0


def split_programs(text: str) -> tuple[list[str], str]:
    """Return the complete programs in ``text`` and the incomplete rest.

    A program is ``def name(): ... end`` (``end`` alone at column 0) or one line outside a
    definition.
    """
    programs: list[str] = []
    lines = text.split("\n")
    rest = lines.pop()
    current: list[str] | None = None
    for line in lines:
        if current is None:
            if line.startswith("def "):
                current = [line]
            elif line.strip():
                programs.append(line + "\n")
        else:
            current.append(line)
            if line.rstrip() == "end":
                programs.append("\n".join(current) + "\n")
                current = None
    unfinished = "\n".join(current) + "\n" if current is not None else ""
    return programs, unfinished + rest


def check_program(program: str) -> list[str]:
    """Return the program's errors (an unknown function, a line that is not a call)."""
    errors: list[str] = []
    body = program.strip().split("\n")
    if body[0].startswith("def "):
        body = body[1:-1]
    for number, raw in enumerate(body, start=1):
        line = raw.strip()
        if not line:
            continue
        if not _STATEMENT.match(line):
            errors.append(f"line {number}: not a function call: {line!r}")
            continue
        errors.extend(
            f"line {number}: unknown function {name}()"
            for name in _CALL.findall(_strip_strings(line))
            if name not in FUNCTIONS
        )
    return errors


def _strip_strings(line: str) -> str:
    return re.sub(r'"[^"]*"', '""', line)


def announcement(program: str) -> dict[str, str] | None:
    """Return the ``key=value`` pairs of a program's ``atikt:`` text message (None: none)."""
    found = _ANNOUNCE.search(program)
    if found is None:
        return None
    pairs = (item.partition("=") for item in found.group(1).split())
    return {key: value for key, _, value in pairs}


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
    ) -> None:
        """Prepare the server (it listens from ``__enter__``)."""
        self.controller = controller
        super().__init__(host, port)
        self.faults = faults or ScriptFaults()
        self._lock = threading.Lock()
        self.programs: list[str] = []
        self.stops_injected = 0

    def serve(self, sock: socket.socket) -> None:
        """Read programs from one client until it leaves."""
        text = ""
        sock.settimeout(0.1)
        with contextlib.closing(sock), contextlib.suppress(OSError):
            while not self.stopping.is_set():
                try:
                    chunk = sock.recv(65536)
                except TimeoutError:
                    continue
                if not chunk:
                    return
                programs, text = split_programs(text + chunk.decode(errors="replace"))
                for program in programs:
                    self.run(program)

    def run(self, program: str) -> None:
        """Check a program and run what the virtual lab runs of it."""
        with self._lock:
            self.programs.append(program)
        errors = check_program(program)
        if errors:
            for error in errors:
                self.controller.note(f"URScript error, program not run: {error}")
            return
        said = announcement(program)
        if said is not None and said.get("phase", "approach") == "approach":
            self._start(said)
            return
        moved = _POSE.search(program)
        if said is None and moved is not None:
            pose = np.array([float(v) for v in moved.group(1).split(",")])
            self.controller.park(pose)

    def _start(self, said: dict[str, str]) -> None:
        """Start the announced action; schedule an injected protective stop.

        The approach is sent again whenever its speed changes (speed from proximity): an
        announcement of the action already playing is such an update, not a new action.
        """
        key = (said.get("object"), said.get("action"), said.get("trial"))
        playing = self.controller.world.playing()
        if playing is not None and key == (playing[0], playing[1], str(playing[2])):
            return
        try:
            self.controller.start_action(said["object"], said["action"], int(said["trial"]))
        except (KeyError, ValueError, RigError) as err:
            self.controller.note(f"textmsg announcement {said} not played: {err}")
            return
        delay = self.faults.protective_stop_s
        if delay > 0:
            timer = threading.Timer(delay, self._protective_stop)
            timer.daemon = True
            timer.start()

    def _protective_stop(self) -> None:
        with self._lock:
            self.stops_injected += 1
        self.controller.world.stop("protective")
        self.controller.note("protective stop (injected fault)")
