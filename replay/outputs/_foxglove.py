"""Recordings played to Foxglove over its WebSocket protocol (``view --foxglove``).

A Foxglove WebSocket server (the ``foxglove-sdk`` package) on 127.0.0.1 by default advertises
one channel per topic of the recordings, with the files' own schemas (``ros2msg``) and message
encodings; once a client subscribes, every message is sent as its file holds it, byte for byte,
at the recorded pace (``speed`` times faster; 0: at once), file after file. What Foxglove shows
is the files, not a conversion of them. The server keeps serving until Ctrl-C (or SIGTERM).
"""

from __future__ import annotations

import signal
import threading
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from mcap.reader import make_reader

from replay.errors import ReplayError
from schemas import cli

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

#: Where the server listens unless told otherwise (loopback only).
DEFAULT_ADDRESS = f"{cli.LOOPBACK}:8765"
#: A client's queue of messages not yet sent, at least and at most (the SDK's default is the
#: least; the most bounds the memory of a client that never reads: a few hundred MB).
MIN_BACKLOG, MAX_BACKLOG = 1024, 2_000_000
#: How long after the first subscription the other channels may still be subscribed, s.
SUBSCRIBE_SETTLE_S = 0.5
_NS = 1_000_000_000


@dataclass(frozen=True, slots=True)
class _Topic:
    """A channel as the files declare it."""

    topic: str
    schema_name: str
    schema_encoding: str
    schema: bytes
    message_encoding: str


def parse_address(text: str) -> tuple[str, int]:
    """Return ``(host, port)`` of ``HOST:PORT`` (or ``PORT``; host 127.0.0.1).

    Raises:
        ReplayError: Not a port in 0..65535.
    """
    address = cli.host_port(text)
    if address is None:
        msg = f"--foxglove {text!r}: give HOST:PORT, e.g. {DEFAULT_ADDRESS} (0: any free port)"
        raise ReplayError(msg)
    return address


def _topics(paths: Sequence[Path]) -> tuple[dict[str, _Topic], int]:
    """Return every topic of the files with its schema, and how many messages they hold.

    A topic has the same schema in every file.

    Raises:
        ReplayError: A file cannot be read, or two files give one topic two schemas.
    """
    topics: dict[str, _Topic] = {}
    messages = 0
    for path in paths:
        try:
            with path.open("rb") as stream:
                summary = make_reader(stream).get_summary()
        except Exception as err:  # mcap's own errors: a damaged or foreign file
            msg = f"{path}: not a readable MCAP file ({err}); check it with atikt-replay check"
            raise ReplayError(msg) from err
        if summary is None:
            msg = f"{path}: the MCAP file has no summary; salvage it with check --recover"
            raise ReplayError(msg)
        messages += summary.statistics.message_count if summary.statistics else 0
        for channel in summary.channels.values():
            schema = summary.schemas.get(channel.schema_id)
            found = _Topic(
                channel.topic,
                schema.name if schema else "",
                schema.encoding if schema else "",
                bytes(schema.data) if schema else b"",
                channel.message_encoding,
            )
            known = topics.setdefault(channel.topic, found)
            if known != found:
                msg = (
                    f"{path}: topic {channel.topic} has another schema than in the files "
                    "before it; serve files of one contract version together"
                )
                raise ReplayError(msg)
    return topics, messages


def serve_recordings(
    paths: Sequence[Path],
    address: str = DEFAULT_ADDRESS,
    *,
    speed: float = 1.0,
    say: Callable[[str], Any] = print,
    stop: threading.Event | None = None,
) -> int:
    """Serve ``paths`` to Foxglove clients: play them once a client subscribed, then wait.

    Args:
        paths: Recordings, played in this order.
        address: ``HOST:PORT`` to listen on (port 0: any free port).
        speed: Times faster than recorded (0: as fast as the server takes them).
        say: Where the lines for the user go (the address, then what was played).
        stop: Set it to stop (another thread); else Ctrl-C or SIGTERM stops.

    Returns:
        The number of messages sent.

    Raises:
        ReplayError: ``foxglove-sdk`` is missing, the address cannot be bound, or a file
            cannot be read.
    """
    try:
        import foxglove  # noqa: PLC0415 (optional: only with --foxglove)
    except ImportError as err:
        msg = f"--foxglove needs the foxglove-sdk package ({err}): pip install foxglove-sdk"
        raise ReplayError(msg) from err
    host, port = parse_address(address)
    topics, messages = _topics(paths)
    subscribed = threading.Event()

    class _Subscribed(foxglove.websocket.ServerListener):
        """Notes the first subscription (playing starts then)."""

        def on_subscribe(self, client: Any, channel: Any) -> None:  # noqa: ANN401, ARG002
            subscribed.set()

    context = foxglove.Context()  # this server's channels only, however many ran before
    try:
        server = foxglove.start_server(
            name="atikt",
            host=host,
            port=port,
            server_listener=_Subscribed(),
            context=context,
            # a client that falls behind gets every message later, never fewer: the files'
            # messages fit in its queue (the SDK drops the oldest beyond 1024 by default)
            message_backlog_size=min(max(messages, MIN_BACKLOG), MAX_BACKLOG),
        )
    except Exception as err:  # the SDK's own error types
        msg = f"--foxglove {host}:{port}: cannot listen ({err}); choose another port"
        raise ReplayError(msg) from err
    stop = stop or threading.Event()
    handled = (signal.SIGINT, signal.SIGTERM)
    on_main = threading.current_thread() is threading.main_thread()
    previous = {n: signal.signal(n, lambda *_: stop.set()) for n in handled} if on_main else {}
    channels: dict[str, Any] = {}
    try:
        channels = {
            t.topic: foxglove.Channel(
                t.topic,
                schema=foxglove.Schema(
                    name=t.schema_name, encoding=t.schema_encoding, data=t.schema
                ),
                message_encoding=t.message_encoding,
                context=context,
            )
            for t in topics.values()
        }
        say(
            f"foxglove on ws://{host}:{server.port}: {len(paths)} recordings, {len(channels)} "
            "topics; open Foxglove, Open connection, Foxglove WebSocket; playing once a client "
            "subscribes (Ctrl-C stops)"
        )
        while not subscribed.wait(0.1):
            if stop.is_set():
                return 0
        stop.wait(SUBSCRIBE_SETTLE_S)  # the client subscribes to every channel at once
        sent = _play(paths, channels, speed, stop)
        say(f"played {sent} messages of {len(paths)} recordings; Ctrl-C stops serving")
        stop.wait()
        return sent
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        server.stop()
        for channel in channels.values():
            channel.close()


def _play(
    paths: Sequence[Path], channels: dict[str, Any], speed: float, stop: threading.Event
) -> int:
    """Send every message of the files in log-time order, paced; return how many."""
    sent = 0
    for path in paths:
        with path.open("rb") as stream:
            begun, first = time.monotonic_ns(), None
            for _, channel, message in make_reader(stream).iter_messages(log_time_order=True):
                if stop.is_set():
                    return sent
                first = message.log_time if first is None else first
                if speed > 0:
                    due = begun + (message.log_time - first) / speed
                    wait = (due - time.monotonic_ns()) / _NS
                    if wait > 0 and stop.wait(wait):
                        return sent
                channels[channel.topic].log(bytes(message.data), log_time=message.log_time)
                sent += 1
    return sent
