"""Foxglove, live: what is being recorded, served over the Foxglove WebSocket protocol.

:class:`FoxgloveView` is a live viewer (``recorder.runner.Viewer``) behind ``--foxglove``: a
Foxglove WebSocket server (the ``foxglove-sdk`` package) on 127.0.0.1 by default, with one
channel per topic carrying the recordings' own ROS 2 schemas (``ros2msg``) and CDR messages,
encoded by the writer's own encoder: what Foxglove shows live is what the file holds, byte for
byte. Items reach it through a bounded queue and a thread of its own: a slow or absent client
never delays the robot; what the queue could not take is counted as dropped.

:class:`TopicView` serves a lab's ROS 2 topics as ``listen`` receives them (``listen
--foxglove``): the lab's own types and CDR bytes, before any conversion. Both share one
server-and-queue base.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
from typing import TYPE_CHECKING, Any, Self, cast

from recorder.errors import RecorderError
from recorder.writing._writer import TYPE_OF_TOPIC, _Encoder
from schemas import cli

if TYPE_CHECKING:
    from pathlib import Path
    from types import TracebackType

    from recorder.writing._stream import StreamItem
    from recorder.writing._writer import RecordingInfo

#: Where the server listens unless told otherwise (loopback only).
DEFAULT_ADDRESS = f"{cli.LOOPBACK}:8765"
#: Items the view may fall behind by before it drops.
CAPACITY = 20_000
#: Longest wait for the thread when the run ends, s.
CLOSE_S = 2.0
_END = object()


#: The subprotocol foxglove-sdk's server speaks (it refuses a client that offers only the
#: older name of the same protocol, ``foxglove.websocket.v1``).
SUBPROTOCOL = "foxglove.sdk.v1"
#: The logger of foxglove-sdk's WebSocket server (it says each refused handshake there).
_SERVER_LOGGER = "foxglove.websocket.server"
#: The logger where foxglove-sdk says that a client's outbox was full (at INFO, once a client).
_LOSSY_LOGGER = "foxglove.websocket.connected_client.send_lossy"


class _Outboxes(logging.Filter):
    """Note the clients whose outbox foxglove-sdk found full (it dropped messages for them).

    The SDK drops the oldest messages of a client that falls behind, silently but for one log
    line per client, and counts nothing. Written here because the SDK exposes neither a count
    nor a callback: the line is all there is to say that a client missed messages.
    """

    def __init__(self) -> None:
        super().__init__()
        self.clients: set[str] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        text = record.getMessage()
        if text.startswith("outbox for client ") and text.endswith(" full"):
            self.clients.add(text.removeprefix("outbox for client ").removesuffix(" full"))
            return False  # said at the end of the run, with what it means
        return True


class _Handshakes(logging.Filter):
    """Turn the SDK's line per refused handshake into one line that says why, said once.

    A client that offers only ``foxglove.websocket.v1`` (Foxglove Studio before 2025, Lichtblick
    before 2025-12) retries every second; the SDK logs ``Dropping client ...: handshake
    failed`` each time, with no reason. Written here because the SDK offers no way to accept
    that subprotocol name (it is the same protocol) or to say why it refused.
    """

    def __init__(self, url: str) -> None:
        super().__init__()
        self.url = url
        self.refused = 0

    def filter(self, record: logging.LogRecord) -> bool:
        if "handshake failed" not in record.getMessage():
            return True
        self.refused += 1
        if self.refused == 1:
            record.msg = (
                f"--foxglove {self.url}: a client was refused at the handshake (said once): "
                f"this server speaks the subprotocol {SUBPROTOCOL}; a client that offers only "
                "foxglove.websocket.v1 (Foxglove Studio before 2025, Lichtblick before 2025-12) "
                "cannot connect: update it"
            )
            record.args = ()
            return True
        return False


def parse_address(text: str) -> tuple[str, int]:
    """Return ``(host, port)`` of ``HOST:PORT`` (or ``PORT``; host 127.0.0.1).

    Raises:
        RecorderError: Not a port in 0..65535.
    """
    address = cli.host_port(text)
    if address is None:
        msg = f"--foxglove {text!r}: give HOST:PORT, e.g. {DEFAULT_ADDRESS} (0: any free port)"
        raise RecorderError(msg)
    return address


class _Served:
    """A Foxglove WebSocket server fed from a bounded queue by a thread of its own.

    Subclasses say what an item is (:meth:`_serve`); offering never blocks: a full queue
    counts the item as dropped.
    """

    def __init__(self, address: str = DEFAULT_ADDRESS, capacity: int = CAPACITY) -> None:
        """Prepare the server (it listens from ``__enter__``)."""
        self.host, self.port = parse_address(address)
        self._queue: queue.Queue[object] = queue.Queue(maxsize=capacity)
        self._thread = threading.Thread(target=self._run, name="atikt-foxglove", daemon=True)
        self._server: Any = None
        #: The server's own channels: a context of its own, so that a process serving twice
        #: (or a test after another) never advertises another server's channels.
        self._context: Any = None
        self._channels: dict[str, Any] = {}
        self.dropped = 0
        self._outboxes = _Outboxes()
        self.failure = ""
        #: Topics a client has subscribed to (the server's listener adds them).
        self.subscribed: set[str] = set()

    def __enter__(self) -> Self:
        """Start the WebSocket server and the thread.

        Raises:
            RecorderError: ``foxglove-sdk`` is missing or the address cannot be bound.
        """
        try:
            import foxglove  # noqa: PLC0415 (optional: only with --foxglove)
        except ImportError as err:
            msg = f"--foxglove needs the foxglove-sdk package ({err}): pip install foxglove-sdk"
            raise RecorderError(msg) from err
        view = self

        class _Listener(foxglove.websocket.ServerListener):
            def on_subscribe(self, client: Any, channel: Any) -> None:  # noqa: ANN401, ARG002
                view.subscribed.add(str(channel.topic))

        self._context = foxglove.Context()
        lossy = logging.getLogger(_LOSSY_LOGGER)
        if not lossy.isEnabledFor(logging.INFO):  # its one line a client, noted (not printed)
            lossy.setLevel(logging.INFO)
        lossy.addFilter(self._outboxes)
        try:
            self._server = foxglove.start_server(
                name="atikt",
                host=self.host,
                port=self.port,
                server_listener=_Listener(),
                context=self._context,
            )
        except Exception as err:  # the SDK's own error types
            lossy.removeFilter(self._outboxes)
            msg = f"--foxglove {self.host}:{self.port}: cannot listen ({err}); choose another port"
            raise RecorderError(msg) from err
        self.port = int(self._server.port)
        self._handshakes = _Handshakes(self.url)
        logging.getLogger(_SERVER_LOGGER).addFilter(self._handshakes)
        self._advertise()
        self._thread.start()
        return self

    def _advertise(self) -> None:
        """Make the channels known before their first message (none by default)."""

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Serve what is queued (waiting :data:`CLOSE_S` at most), then stop the server."""
        self._offer(_END)
        self._thread.join(CLOSE_S)
        if self._server is not None:
            with contextlib.suppress(Exception):
                self._server.stop()
            logging.getLogger(_SERVER_LOGGER).removeFilter(self._handshakes)
        logging.getLogger(_LOSSY_LOGGER).removeFilter(self._outboxes)
        for channel in self._channels.values():
            with contextlib.suppress(Exception):
                channel.close()

    @property
    def behind(self) -> tuple[str, ...]:
        """Return the clients foxglove-sdk dropped messages for (their outbox was full)."""
        return tuple(sorted(self._outboxes.clients))

    def behind_line(self) -> str:
        """Return the line that says which clients missed messages ('': none did)."""
        if not self.behind:
            return ""
        return (
            f"--foxglove: {', '.join(self.behind)} fell behind; the server dropped messages "
            "for it (foxglove-sdk does not count them; the recordings hold everything)"
        )

    @property
    def url(self) -> str:
        """Return the address Foxglove connects to."""
        return f"ws://{self.host}:{self.port}"

    def _offer(self, item: object) -> None:
        try:
            self._queue.put_nowait(item)
        except queue.Full:
            self.dropped += 1

    def _run(self) -> None:
        while (item := self._queue.get()) is not _END:
            try:
                self._serve(item)
            except Exception as err:  # noqa: BLE001 (a client's trouble never reaches the robot)
                self.failure = self.failure or str(err)

    def _serve(self, item: object) -> None:
        raise NotImplementedError

    def _channel(self, topic: str, msgtype: str, msgdef: str) -> Any:  # noqa: ANN401 (the SDK's)
        """Return the topic's channel (made on first use: ROS 2 schema, CDR messages)."""
        channel = self._channels.get(topic)
        if channel is None:
            import foxglove  # noqa: PLC0415 (imported in __enter__)

            schema = foxglove.Schema(name=msgtype, encoding="ros2msg", data=msgdef.encode())
            channel = foxglove.Channel(
                topic, schema=schema, message_encoding="cdr", context=self._context
            )
            self._channels[topic] = channel
        return channel


class FoxgloveView(_Served):
    """Serves every recorded item to Foxglove clients as it arrives (a context manager)."""

    def __init__(self, address: str = DEFAULT_ADDRESS, capacity: int = CAPACITY) -> None:
        """Prepare the server (it listens from ``__enter__``)."""
        super().__init__(address, capacity)
        self._encoder: _Encoder | None = None

    def _advertise(self) -> None:
        """Advertise every topic of the contract now.

        A client (a layout's panels) subscribes before the first recording, and sees each
        recording from its first message.
        """
        from schemas import build_typestore  # noqa: PLC0415

        store = build_typestore()
        for topic, msgtype in TYPE_OF_TOPIC.items():
            text, _ = store.generate_msgdef(msgtype, ros_version=2)
            self._channel(topic, msgtype, text)

    def begin(self, info: RecordingInfo) -> None:
        """Encode the next items as ``info``'s recording does."""
        self._offer(info)

    def offer(self, item: StreamItem) -> None:
        """Queue one item; never blocks (a full queue counts it as dropped)."""
        self._offer(item)

    def recorded(self, path: Path) -> None:
        """Nothing to do: the items were served as they arrived."""

    def _serve(self, item: object) -> None:
        from recorder.writing._writer import RecordingInfo  # noqa: PLC0415

        if isinstance(item, RecordingInfo):
            self._encoder = _Encoder(item)
            return
        if self._encoder is None:
            return
        topic, _stamp, payload = self._encoder.encode(item)  # type: ignore[arg-type]
        if topic not in self._channels:
            msgtype = TYPE_OF_TOPIC[topic]
            text, _ = self._encoder.store.generate_msgdef(msgtype, ros_version=2)
            self._channel(topic, msgtype, text)
        self._channels[topic].log(payload, log_time=item.receive_ns)  # type: ignore[attr-defined]


class TopicView(_Served):
    """Serves a lab's ROS 2 topics as they are received (``listen --foxglove``).

    The messages are the CDR bytes that arrived, on the lab's own topics and types: what
    Foxglove shows is what ``listen`` is recording from, before any conversion.
    """

    def declare(self, topic: str, msgtype: str, msgdef: str) -> None:
        """Announce a topic (its type and ROS 2 message definition) before its messages."""
        self._offer((topic, msgtype, msgdef))

    def offer_raw(self, topic: str, receive_ns: int, raw: bytes) -> None:
        """Queue one received message; never blocks (a full queue counts it as dropped)."""
        self._offer((topic, receive_ns, raw))

    def _serve(self, item: object) -> None:
        topic, second, third = cast("tuple[str, Any, Any]", item)
        if isinstance(second, str):
            self._channel(topic, second, third)
        elif topic in self._channels:
            self._channels[topic].log(third, log_time=second)
