"""Foxglove, live: a protocol client subscribes to the WebSocket server while an action is
recorded and receives the file's own messages, byte for byte (the Foxglove WebSocket
protocol, subprotocol foxglove.sdk.v1), and the shipped layout names the contract's topics."""

from __future__ import annotations

import json
import logging
import time
from typing import TYPE_CHECKING

import pytest
from mcap.reader import make_reader

from recorder import SimulatedRig, load_actions, load_objects, record_action
from recorder.errors import RecorderError
from recorder.writing._foxglove import FoxgloveView, parse_address
from schemas import CHANNELS

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

pytest.importorskip("websockets.sync.client")
pytest.importorskip("foxglove")

from foxglove_client import FoxgloveClient as _Client


def _file_messages(path: Path) -> dict[str, list[bytes]]:
    with path.open("rb") as stream:
        in_file: dict[str, list[bytes]] = {}
        for _, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            in_file.setdefault(channel.topic, []).append(bytes(message.data))
    return in_file


def _until(done: Callable[[], bool], timeout_s: float = 20.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not done() and time.monotonic() < deadline:
        time.sleep(0.02)


def test_foxglove_clients_get_the_files_own_messages_live(tmp_path: Path) -> None:
    obj, action = load_objects()["wood"], load_actions()["S2"]
    with FoxgloveView("127.0.0.1:0") as view, SimulatedRig(3) as rig:
        assert view.url.startswith("ws://127.0.0.1:")
        client = _Client(view.url)
        # every channel of the contract is advertised when the server starts: a client that
        # subscribed before the action sees all of it
        topics = {channel.topic for channel in CHANNELS}
        _until(lambda: view.subscribed >= topics)
        assert view.subscribed >= topics
        written = record_action(rig, obj, action, 1, tmp_path / "001.mcap", seed=3, viewers=[view])
        in_file = _file_messages(written.path)
        _until(
            lambda: (
                {t: len(p) for t, p in client.received.items()}
                == {t: len(p) for t, p in in_file.items()}
            )
        )
        client.close()
    assert view.dropped == 0
    assert view.failure == ""
    assert set(client.received) == set(in_file)
    for topic, payloads in client.received.items():
        assert client.schemas[topic] == ("cdr", "ros2msg")
        assert payloads == in_file[topic], topic


def test_foxglove_binds_loopback_unless_told_and_refuses_a_bad_address() -> None:
    assert parse_address("8765") == ("127.0.0.1", 8765)
    assert parse_address("0.0.0.0:9000") == ("0.0.0.0", 9000)  # noqa: S104 (asked for)
    with pytest.raises(RecorderError, match="give HOST:PORT"):
        parse_address("here:port")


def test_the_shipped_layout_names_only_the_contracts_topics() -> None:
    import re  # noqa: PLC0415
    from pathlib import Path  # noqa: PLC0415

    import recorder  # noqa: PLC0415
    from schemas import CHANNELS  # noqa: PLC0415

    layout = Path(recorder.__file__).parent / "data" / "foxglove_layout.json"
    text = layout.read_text("utf-8")
    config = json.loads(text)
    assert set(config["configById"]) == set(
        re.findall(r'"([A-Za-z0-9]+![a-z]+)"', json.dumps(config["layout"]))
    )
    topics = set(re.findall(r'"(/[a-z_]+/[a-z_]+)', text))
    assert topics
    assert topics <= {channel.topic for channel in CHANNELS}


def test_a_server_advertises_its_own_channels_only() -> None:
    # a process that served before (a test before another, a second view) never shows a
    # client the channels of an earlier server: each server has a context of its own
    from recorder.writing._foxglove import TopicView  # noqa: PLC0415

    text = "std_msgs/Header header\nfloat32 data\n"
    with TopicView("127.0.0.1:0") as first:
        first.declare("/earlier", "lab_msgs/msg/Scalar", text)
        time.sleep(0.2)
    with TopicView("127.0.0.1:0") as second:
        second.declare("/now", "lab_msgs/msg/Scalar", text)
        client = _Client(second.url)
        for _ in range(200):  # a hang guard (10 s of 50 ms waits), not a time check
            if "/now" in second.subscribed:
                break
            time.sleep(0.05)
        else:
            pytest.fail("the client subscribed to nothing")
        client.close()
    assert set(client.schemas) == {"/now"}
    assert first.subscribed == set()


def test_a_client_of_the_older_subprotocol_name_is_told_why_once(
    caplog: pytest.LogCaptureFixture,
) -> None:
    # foxglove-sdk refuses foxglove.websocket.v1 with "handshake failed", once per retry
    from websockets.sync.client import connect  # noqa: PLC0415
    from websockets.typing import Subprotocol  # noqa: PLC0415

    with caplog.at_level(logging.INFO), FoxgloveView("127.0.0.1:0") as view:
        for _ in range(3):
            with pytest.raises(Exception, match="HTTP 400"):
                connect(view.url, subprotocols=[Subprotocol("foxglove.websocket.v1")]).close()
        with connect(view.url, subprotocols=[Subprotocol("foxglove.sdk.v1")]):
            pass
        time.sleep(0.2)  # the server's log lines come from its own thread
    said = [r.getMessage() for r in caplog.records if "handshake" in r.getMessage()]
    assert len(said) == 1, said
    assert said[0].startswith(f"--foxglove {view.url}: a client was refused at the handshake")
    assert "speaks the subprotocol foxglove.sdk.v1" in said[0]


def test_a_client_that_stops_reading_is_said_to_have_missed_messages() -> None:
    # foxglove-sdk drops the oldest messages of a client whose outbox is full and counts
    # nothing: the view notes which clients that happened to and says so at the end
    from recorder.writing._foxglove import TopicView  # noqa: PLC0415

    with TopicView("127.0.0.1:0") as view:
        view.declare("/skin/raw", "std_msgs/msg/String", "string data")
        client = _Client(view.url)
        _until(lambda: view.subscribed >= {"/skin/raw"})
        assert view.behind_line() == ""  # none yet
        client._stop.set()  # stops reading, its connection left open
        client.thread.join(2)
        payload = bytes(4096)
        for chunk in range(30):  # the socket's buffers fill first, then the client's outbox
            for number in range(1000):
                view.offer_raw("/skin/raw", chunk * 1000 + number, payload)
            _until(view._queue.empty, 5.0)  # served before more are offered
            if view.behind:
                break
        _until(lambda: bool(view.behind), 5.0)
        line = view.behind_line()
        client.socket.close_timeout = 0.1  # its closing frame waits behind the full outbox
        client.socket.close()
    assert len(view.behind) == 1, view.behind
    assert view.behind[0].startswith("127.0.0.1:")
    assert line.startswith(f"--foxglove: {view.behind[0]} fell behind; the server dropped")
