"""A Foxglove WebSocket protocol client for tests (subprotocol foxglove.sdk.v1).

It subscribes to every channel the server advertises and keeps, per topic, the payload of
every message that arrives (the server's binary MessageData frames: opcode 0x01, subscription
id u32, receive time u64, payload).
"""

from __future__ import annotations

import json
import re
import struct
import threading
import time
from typing import Any

from websockets.sync.client import connect
from websockets.typing import Subprotocol

_UNKNOWN = re.compile(r"Unknown channel ID: (\d+)")
_MESSAGE_DATA = 0x01  # server -> client binary opcode: subscription id, receive time, payload


class FoxgloveClient:
    """Subscribes to every channel the server advertises; keeps what arrives per topic."""

    def __init__(self, url: str) -> None:
        # entered as a context manager (websockets 17.1 deprecates a bare connect()); close()
        # leaves it
        connection = connect(url, subprotocols=[Subprotocol("foxglove.sdk.v1")])
        self.socket = connection.__enter__()
        self.topics: dict[int, str] = {}
        self.received: dict[str, list[bytes]] = {}
        self.schemas: dict[str, tuple[str, str]] = {}
        self._next = 1
        #: Subscription id per channel id.
        self._subscription: dict[int, int] = {}
        #: Why the client stopped reading before close() (empty: it did not).
        self.error = ""
        self._stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                frame: Any = self.socket.recv(timeout=0.1)
            except TimeoutError:
                continue
            except Exception as err:  # noqa: BLE001 (the server went away: the test is over)
                if not self._stop.is_set():
                    self.error = f"recv: {err!r}"
                return
            try:
                self._take(frame)
            except Exception as err:  # noqa: BLE001 (kept for the test's message)
                self.error = f"{type(err).__name__}: {err} in {str(frame)[:200]}"
                return

    def _take(self, frame: Any) -> None:
        """Keep a message's payload; subscribe to every channel an advertisement names."""
        if isinstance(frame, bytes):
            if frame[0] == _MESSAGE_DATA:
                subscription, _ = struct.unpack_from("<IQ", frame, 1)
                topic = self.topics[subscription]
                self.received.setdefault(topic, []).append(frame[13:])
            return
        message = json.loads(frame)
        unknown = _UNKNOWN.fullmatch(str(message.get("message", "")))
        if message["op"] == "status" and unknown and int(unknown[1]) in self._subscription:
            # foxglove-sdk sends an advertisement before it records the channel as advertised to
            # this client (connected_client.rs: advertise_channels), so a subscription sent the
            # moment the advertisement arrives may be refused as unknown: ask again, as a client
            # that wants the channel would
            channel = int(unknown[1])
            time.sleep(0.01)
            subscription = {"id": self._subscription[channel], "channelId": channel}
            self.socket.send(json.dumps({"op": "subscribe", "subscriptions": [subscription]}))
            return
        if message["op"] == "advertise":
            subscriptions = []
            for channel in message["channels"]:
                self.topics[self._next] = channel["topic"]
                encoding = (channel["encoding"], channel["schemaEncoding"])
                self.schemas[channel["topic"]] = encoding
                subscriptions.append({"id": self._next, "channelId": channel["id"]})
                self._subscription[channel["id"]] = self._next
                self._next += 1
            self.socket.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    def close(self) -> None:
        self._stop.set()
        self.thread.join(2)
        self.socket.close()
