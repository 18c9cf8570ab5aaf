"""An RTDE client that receives every data package (Universal Robots Real-Time Data Exchange).

Written by hand, because no maintained package on PyPI receives every package: ``ur-rtde``'s
``RTDEReceiveInterface`` keeps only the latest value of each variable (a recorder cannot count
what it never saw), and Universal Robots' own Python client is not published on PyPI (only as
source on GitHub) and its ``receive()`` discards all but the newest package. The protocol is
small (the RTDE guide's packet formats, version 2): every package is ``uint16 size, uint8
command, payload``, big-endian; the client asks for protocol version 2, reads the controller
version, sets up an output recipe (frequency and variable names; the controller answers with
a recipe id and the variables' types, ``NOT_FOUND`` for unknown names) and starts the stream.
After that the controller sends one data package per control cycle (125 Hz on CB3, 500 Hz on
e-Series) and text messages; :meth:`RtdeClient.receive` returns each data package as it
arrives, for a :class:`recorder.live.SourceReader` thread.
"""

from __future__ import annotations

import contextlib
import math
import socket
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Self

import numpy as np

from recorder.errors import RigError
from recorder.live import Received

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from types import TracebackType

#: The RTDE port of a UR controller.
RTDE_PORT = 30004
#: Protocol version this client speaks.
PROTOCOL_VERSION = 2

# Package types (the RTDE guide's command bytes).
REQUEST_PROTOCOL_VERSION = ord("V")
GET_URCONTROL_VERSION = ord("v")
TEXT_MESSAGE = ord("M")
DATA_PACKAGE = ord("U")
SETUP_OUTPUTS = ord("O")
SETUP_INPUTS = ord("I")
START = ord("S")
PAUSE = ord("P")

HEADER = struct.Struct(">HB")
#: Wire formats of the RTDE types: struct format of one value, and how many values.
TYPES: dict[str, tuple[str, int]] = {
    "BOOL": ("?", 1),
    "UINT8": ("B", 1),
    "UINT32": ("I", 1),
    "UINT64": ("Q", 1),
    "INT32": ("i", 1),
    "DOUBLE": ("d", 1),
    "VECTOR3D": ("d", 3),
    "VECTOR6D": ("d", 6),
    "VECTOR6INT32": ("i", 6),
    "VECTOR6UINT32": ("I", 6),
}
#: Text message levels (RTDE protocol version 2).
MESSAGE_LEVELS = ("exception", "error", "warning", "info")
#: Highest RTDE frequency of each controller generation (major version 3: CB3, 5: e-Series).
MAX_FREQUENCY = {3: 125.0, 5: 500.0}


class RtdeError(RigError):
    """The RTDE connection failed or the controller refused a request."""


def pack_package(command: int, payload: bytes = b"") -> bytes:
    """Return one RTDE package: size, command and payload."""
    return HEADER.pack(HEADER.size + len(payload), command) + payload


def pack_text(message: str, source: str, level: int) -> bytes:
    """Return the payload of a text message (version 2: message, source, level)."""
    text, origin = message.encode()[:255], source.encode()[:255]
    return bytes([len(text)]) + text + bytes([len(origin)]) + origin + bytes([level])


def unpack_text(payload: bytes) -> tuple[str, str, int]:
    """Return (message, source, level) of a version-2 text message payload."""
    size = payload[0]
    message = payload[1 : 1 + size].decode(errors="replace")
    rest = payload[1 + size :]
    source = rest[1 : 1 + rest[0]].decode(errors="replace") if rest else ""
    level = rest[1 + rest[0]] if len(rest) > 1 + (rest[0] if rest else 0) else 3
    return message, source, level


@dataclass(frozen=True, slots=True)
class Recipe:
    """An output recipe: the variables of every data package and how to parse them.

    Attributes:
        recipe_id: The controller's id of the recipe (first byte of each data package).
        names: Variable names, in package order.
        types: Their RTDE types.
        frequency: Packages per second.
    """

    recipe_id: int
    names: tuple[str, ...]
    types: tuple[str, ...]
    frequency: float

    @property
    def layout(self) -> struct.Struct:
        """Return the struct of a data package's payload (recipe id, then the values)."""
        return struct.Struct(">B" + "".join(f"{TYPES[t][1]}{TYPES[t][0]}" for t in self.types))

    def fault(self, payload: bytes) -> str | None:
        """Return why a data package cannot be taken (None: it is well formed and finite).

        A package of another recipe, of the wrong size, or holding a NaN or infinite value
        is malformed: counted at the source and never written.
        """
        layout = self.layout
        if len(payload) != layout.size:
            return f"{len(payload)} bytes, expected {layout.size}"
        if payload[0] != self.recipe_id:
            return f"recipe {payload[0]}, expected {self.recipe_id}"
        values = layout.unpack(payload)
        if not all(math.isfinite(v) for v in values if isinstance(v, float)):
            return "a NaN or infinite value"
        return None

    def parse(self, payload: bytes) -> dict[str, Any]:
        """Return a data package's values by name (vectors as float64/int arrays).

        Raises:
            RtdeError: The package is not of this recipe or has the wrong size.
        """
        layout = self.layout
        if len(payload) != layout.size or payload[0] != self.recipe_id:
            msg = (
                f"RTDE data package of {len(payload)} bytes for recipe {payload[:1].hex()}: "
                f"expected {layout.size} bytes of recipe {self.recipe_id}"
            )
            raise RtdeError(msg)
        flat = layout.unpack(payload)
        values: dict[str, Any] = {}
        index = 1
        for name, kind in zip(self.names, self.types, strict=True):
            count = TYPES[kind][1]
            chunk = flat[index : index + count]
            values[name] = chunk[0] if count == 1 else np.asarray(chunk)
            index += count
        return values


@dataclass(frozen=True, slots=True)
class TextMessage:
    """A text message from the controller.

    Attributes:
        receive_ns: Receive time on the recorder's clock, ns.
        message: The text.
        source: Who sent it.
        level: ``exception``, ``error``, ``warning`` or ``info``.
    """

    receive_ns: int
    message: str
    source: str
    level: str


class RtdeClient:
    """One RTDE connection (a context manager): handshake, then every data package in order.

    Before :meth:`start`, requests are answered in the calling thread. After it, only
    :meth:`receive` reads the socket (one reader thread): it returns data packages, keeps text
    messages in :attr:`messages` and hands the answer of :meth:`pause` over to its caller.
    """

    def __init__(
        self,
        host: str,
        port: int = RTDE_PORT,
        *,
        timeout_s: float = 0.1,
        connect_timeout_s: float = 2.0,
        clock: Callable[[], int] = time.monotonic_ns,
    ) -> None:
        """Prepare a connection (nothing is opened before :meth:`connect`).

        Args:
            host: The controller's address.
            port: The RTDE port.
            timeout_s: Longest wait of one :meth:`receive` call.
            connect_timeout_s: Longest wait for the connection and each handshake answer.
            clock: Receive times, ns (the recorder's clock).
        """
        self.host, self.port = host, port
        self._timeout_s = timeout_s
        self._connect_timeout_s = connect_timeout_s
        self._clock = clock
        self._socket: socket.socket | None = None
        self._buffer = bytearray()
        self._started = False
        self._paused = threading.Event()
        self.recipe: Recipe | None = None
        self.messages: deque[TextMessage] = deque(maxlen=1000)
        #: Data packages left out since the connection opened (another recipe, wrong size,
        #: NaN or infinite values); the recorder adds those of an action to its accounting.
        self.malformed = 0
        #: Why the latest malformed package was left out (for the one-line report).
        self.last_fault = ""

    @property
    def where(self) -> str:
        """Return ``host:port``, for messages."""
        return f"{self.host}:{self.port}"

    def __enter__(self) -> Self:
        """Connect."""
        self.connect()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Close the connection."""
        self.close()

    def connect(self) -> None:
        """Open the connection and negotiate protocol version 2.

        Raises:
            RtdeError: Nothing listens there, or the controller refuses version 2.
        """
        try:
            sock = socket.create_connection((self.host, self.port), self._connect_timeout_s)
        except OSError as err:
            msg = (
                f"RTDE {self.where}: cannot connect ({err}); check the rig option host, that the "
                "controller is on and reachable, or start atikt-record serve-sim"
            )
            raise RtdeError(msg) from err
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._socket = sock
        answer = self._request(REQUEST_PROTOCOL_VERSION, struct.pack(">H", PROTOCOL_VERSION))
        if not answer or not answer[0]:
            msg = f"RTDE {self.where}: the controller refuses protocol version 2; update it"
            raise RtdeError(msg)

    @property
    def peer_host(self) -> str:
        """Return the address connected to (``host`` resolved: ``localhost`` is 127.0.0.1)."""
        try:
            return str(self._connected().getpeername()[0])
        except OSError:
            return self.host

    def controller_version(self) -> tuple[int, int, int, int]:
        """Return the controller's version (major, minor, bugfix, build).

        Raises:
            RtdeError: The answer is malformed or the connection failed.
        """
        answer = self._request(GET_URCONTROL_VERSION)
        if len(answer) != 16:  # noqa: PLR2004 (four uint32)
            msg = f"RTDE {self.where}: malformed controller version answer ({answer.hex()})"
            raise RtdeError(msg)
        major, minor, bugfix, build = struct.unpack(">IIII", answer)
        return major, minor, bugfix, build

    def setup_outputs(self, names: Sequence[str], frequency: float) -> Recipe:
        """Ask for ``names`` at ``frequency`` packages per second; return the recipe.

        Raises:
            RtdeError: The controller does not know a variable or answered malformed.
        """
        payload = struct.pack(">d", frequency) + ",".join(names).encode()
        answer = self._request(SETUP_OUTPUTS, payload)
        if not answer:
            msg = f"RTDE {self.where}: empty answer to the output setup"
            raise RtdeError(msg)
        types = tuple(answer[1:].decode(errors="replace").split(","))
        unknown = [n for n, t in zip(names, types, strict=False) if t not in TYPES]
        if len(types) != len(names) or unknown:
            msg = (
                f"RTDE {self.where}: the controller does not provide {', '.join(unknown)} "
                f"(answered {','.join(types)}); update the controller's software"
            )
            raise RtdeError(msg)
        self.recipe = Recipe(answer[0], tuple(names), types, frequency)
        return self.recipe

    def start(self) -> None:
        """Start the data stream.

        Raises:
            RtdeError: The controller refused (no recipe, or another client's recipe).
        """
        answer = self._request(START)
        if not answer or not answer[0]:
            msg = f"RTDE {self.where}: the controller refused to start the data stream"
            raise RtdeError(msg)
        self._started = True

    def pause(self, timeout_s: float = 1.0) -> bool:
        """Pause the stream; return whether the controller confirmed within ``timeout_s``.

        While a reader thread calls :meth:`receive`, the confirmation arrives there.
        """
        if self._socket is None:
            return False
        self._paused.clear()
        try:
            self._socket.sendall(pack_package(PAUSE))
        except OSError:
            return False
        return self._paused.wait(timeout_s)

    def close(self) -> None:
        """Close the connection (idempotent)."""
        sock, self._socket = self._socket, None
        if sock is not None:
            with contextlib.suppress(OSError):
                sock.close()

    def _request(self, command: int, payload: bytes = b"") -> bytes:
        """Send a request and return the payload of its answer (text messages are kept)."""
        sock = self._connected()
        try:
            sock.sendall(pack_package(command, payload))
        except OSError as err:
            msg = f"RTDE {self.where}: connection lost ({err})"
            raise RtdeError(msg) from err
        deadline = time.monotonic() + self._connect_timeout_s
        while time.monotonic() < deadline:
            package = self._read(min(self._timeout_s, self._connect_timeout_s))
            if package is None:
                continue
            kind, answer = package
            if kind == command:
                return answer
            self._other(kind, answer)
        seconds = self._connect_timeout_s
        msg = (
            f"RTDE {self.where}: no answer to request {chr(command)!r} within {seconds:g} s (the "
            "connection was taken, nothing came back); check that the port is the controller's "
            "RTDE port (30004), and the network between (a link that forwards one way only)"
        )
        raise RtdeError(msg)

    def _connected(self) -> socket.socket:
        if self._socket is None:
            msg = f"RTDE {self.where}: not connected; call connect() first"
            raise RtdeError(msg)
        return self._socket

    def _read(self, timeout_s: float) -> tuple[int, bytes] | None:
        """Return the next whole package, or None when none completed within ``timeout_s``.

        A package split over several reads stays in the buffer until it is complete.

        Raises:
            RtdeError: The controller closed the connection or it failed.
        """
        sock = self._connected()
        deadline = time.monotonic() + timeout_s
        while True:
            if len(self._buffer) >= HEADER.size:
                size, kind = HEADER.unpack_from(self._buffer)
                if size < HEADER.size:
                    msg = f"RTDE {self.where}: malformed package size {size}"
                    raise RtdeError(msg)
                if len(self._buffer) >= size:
                    payload = bytes(self._buffer[HEADER.size : size])
                    del self._buffer[:size]
                    return kind, payload
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            sock.settimeout(left)
            try:
                chunk = sock.recv(65536)
            except TimeoutError:
                return None
            except OSError as err:
                msg = f"RTDE {self.where}: connection lost ({err})"
                raise RtdeError(msg) from err
            if not chunk:
                msg = f"RTDE {self.where}: the controller closed the connection"
                raise RtdeError(msg)
            self._buffer += chunk

    def _other(self, kind: int, payload: bytes) -> None:
        """Handle a package that is not the awaited one: text messages, pause answers."""
        if kind == TEXT_MESSAGE:
            message, source, level = unpack_text(payload)
            name = MESSAGE_LEVELS[level] if level < len(MESSAGE_LEVELS) else str(level)
            self.messages.append(TextMessage(self._clock(), message, source, name))
        elif kind == PAUSE:
            self._started = False
            self._paused.set()

    def receive(self) -> Received | None:
        """Return the next data package (payload: its bytes), or None after the timeout.

        Call it from one reader thread after :meth:`start`; every well-formed package is
        returned, in the order it arrived. A malformed one (another recipe, the wrong size,
        a NaN or infinite value) is counted in :attr:`malformed` and skipped: one bad package
        never ends the stream.

        Raises:
            RtdeError: The connection was lost.
        """
        package = self._read(self._timeout_s)
        if package is None:
            return None
        kind, payload = package
        receive_ns = self._clock()
        if kind == DATA_PACKAGE:
            fault = None if self.recipe is None else self.recipe.fault(payload)
            if fault is None:
                return Received(receive_ns, payload)
            self.malformed += 1
            self.last_fault = fault
            return None
        self._other(kind, payload)
        return None
