"""``atikt-replay view --foxglove``: a Foxglove protocol client subscribes and receives every
message of the recordings, byte for byte and in order, with the files' own schemas; the server
binds 127.0.0.1 unless told otherwise and stops on Ctrl-C."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from replay.cli._main import main as replay

pytest.importorskip("websockets.sync.client")
pytest.importorskip("foxglove")

from foxglove_client import FoxgloveClient

ROOT = Path(__file__).resolve().parents[2]
RECORDINGS = [
    ROOT / "recordings" / "data" / "soft_sponge" / "P1" / "001.mcap",
    ROOT / "recordings" / "data" / "soft_sponge" / "S2" / "001.mcap",
]


def _in_files(paths: list[Path]) -> dict[str, list[bytes]]:
    found: dict[str, list[bytes]] = {}
    for path in paths:
        with path.open("rb") as stream:
            for _, channel, message in make_reader(stream).iter_messages(log_time_order=True):
                found.setdefault(channel.topic, []).append(bytes(message.data))
    return found


def test_view_plays_the_files_own_messages_to_foxglove() -> None:
    command = [sys.executable, "-m", "replay", "view", "--foxglove", "127.0.0.1:0"]
    command += ["--speed", "0", *map(str, RECORDINGS)]
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    served = subprocess.Popen(  # noqa: S603 (this project's command)
        command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert served.stdout is not None
        line = served.stdout.readline()
        assert line.startswith("foxglove on ws://127.0.0.1:"), line
        url = line.split()[2].rstrip(":")
        client = FoxgloveClient(url)
        played = served.stdout.readline()
        assert played.startswith("played "), played
        for _ in range(1500):  # the last frames on their way: a hang guard (30 s of 20 ms)
            if sum(map(len, client.received.values())) >= int(played.split()[1]):
                break
            time.sleep(0.02)
        client.close()
    finally:
        served.send_signal(signal.SIGINT)
        out, err = served.communicate(timeout=30)
    assert served.returncode == 0, err
    assert "stopped serving" in out
    in_files = _in_files(RECORDINGS)
    assert int(played.split()[1]) == sum(len(v) for v in in_files.values())
    assert set(client.received) == set(in_files)
    for topic, payloads in in_files.items():
        assert client.schemas[topic] == ("cdr", "ros2msg")
        assert client.received[topic] == payloads, topic


def test_serving_in_process_plays_every_message_then_waits_for_the_stop() -> None:
    import threading  # noqa: PLC0415

    from replay.outputs._foxglove import serve_recordings  # noqa: PLC0415

    said: list[str] = []
    stop = threading.Event()
    result: dict[str, int] = {}

    def serve() -> None:
        result["sent"] = serve_recordings(
            RECORDINGS, "127.0.0.1:0", speed=50.0, say=said.append, stop=stop
        )

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    for _ in range(1500):  # a hang guard (30 s of 20 ms waits), not a time check
        if said:
            break
        time.sleep(0.02)
    else:
        pytest.fail("the server said nothing")
    client = FoxgloveClient(said[0].split()[2].rstrip(":"))
    for _ in range(1500):  # a hang guard (30 s of 20 ms waits), not a time check
        if len(said) >= 2:
            break
        time.sleep(0.02)
    else:
        pytest.fail(f"the server said one line only: {said}")
    time.sleep(0.3)
    client.close()
    stop.set()
    thread.join(10)
    in_files = _in_files(RECORDINGS)
    assert result["sent"] == sum(len(v) for v in in_files.values())
    assert client.received == in_files


@pytest.mark.slow(6)
def test_a_client_held_up_still_gets_every_message() -> None:
    # a client that stops reading for a while (a busy laptop, a layout loading) while the
    # server plays at once: the SDK's queue of 1024 messages per client dropped the rest
    # silently (6,079 of 30,549 arrived), though the server said all were played
    import threading  # noqa: PLC0415

    from replay.outputs._foxglove import serve_recordings  # noqa: PLC0415

    many = sorted((ROOT / "recordings" / "data").glob("*/*/*.mcap"))[:16]
    said: list[str] = []
    stop = threading.Event()
    result: dict[str, int] = {}

    def serve() -> None:
        result["sent"] = serve_recordings(many, "127.0.0.1:0", speed=0, say=said.append, stop=stop)

    class HeldUp(FoxgloveClient):
        def _take(self, frame: object) -> None:
            super()._take(frame)
            if isinstance(frame, bytes) and not self.__dict__.get("held"):
                self.__dict__["held"] = True
                time.sleep(3.0)  # held up after its first message, the server playing on

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    for _ in range(1500):  # a hang guard (30 s of 20 ms waits), not a time check
        if said:
            break
        time.sleep(0.02)
    client = HeldUp(said[0].split()[2].rstrip(":"))
    for _ in range(3000):  # a hang guard (60 s of 20 ms waits), not a time check
        played = int(said[1].split()[1]) if len(said) >= 2 else None  # "played N messages ..."
        if played is not None and sum(map(len, client.received.values())) >= played:
            break
        time.sleep(0.02)
    client.close()
    stop.set()
    thread.join(10)
    in_files = _in_files(many)
    assert result["sent"] == sum(len(v) for v in in_files.values()) > 25_000
    assert client.received == in_files


def test_a_damaged_file_is_one_line_before_anything_is_served(tmp_path: Path) -> None:
    from replay.errors import ReplayError  # noqa: PLC0415
    from replay.outputs._foxglove import serve_recordings  # noqa: PLC0415

    damaged = tmp_path / "001.mcap"
    damaged.write_bytes(RECORDINGS[0].read_bytes()[:5000])
    with pytest.raises(ReplayError, match="check"):
        serve_recordings([damaged], "127.0.0.1:0", say=lambda _: None)


def test_view_refuses_two_outputs_and_an_offline_run_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = ["view", "--foxglove", "--serve", str(RECORDINGS[0])]
    assert replay(argv) == 1
    assert "--serve and --foxglove: choose one" in capsys.readouterr().err
    assert replay(["view", "--foxglove", "127.0.0.1:x", str(RECORDINGS[0])]) == 1
    assert "give HOST:PORT" in capsys.readouterr().err
    run = tmp_path / "run"
    run.mkdir()
    (run / "history.parquet").write_bytes(b"")
    assert replay(["view", "--foxglove", str(run)]) == 1
    assert "an offline learn run holds no recordings to play" in capsys.readouterr().err
