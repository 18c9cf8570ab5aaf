"""``listen`` rehearsed against the virtual lab's ROS 2 side, and hostile DDS sources.

serve-sim publishes the world's joint states, skin cells and the annotations of the action it
plays; ``listen`` records them. Hostile cases: a message above the map's size, an action
whose 'end' is lost, a listener that joins part-way, malformed annotations, SIGTERM.
"""

from __future__ import annotations

import contextlib
import json
import re
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any, cast

import forked
import numpy as np
import pytest

pytest.importorskip("cyclonedds")

from recorder import SimulatedRig, load_actions, load_objects
from recorder.bagimport._listen import listen
from recorder.bagimport._source import ANNOTATION_TYPE, typestore
from recorder.bagimport._topicmap import load_topic_map
from recorder.live import SOURCES_RECORD, parse_source_stats
from recorder.live.dds import LOOPBACK_CONFIG, DdsDomain
from recorder.virtuallab import VirtualWorld
from recorder.virtuallab._ros2_server import serve_ros2
from recorder.virtuallab._urscript import Call, Program
from replay.cli._main import main as replay_main
from schemas import is_incomplete

if TYPE_CHECKING:
    from collections.abc import Iterator

    from recorder.bagimport._report import ImportReport

EXAMPLE = Path(__file__).parents[2] / "recorder" / "data" / "topic_map.example.toml"


def _map(root: Path, **time: str) -> Path:
    """Return the example map without a tool pose (fewer topics for the virtual lab)."""
    text = EXAMPLE.read_text(encoding="utf-8")
    head, _, rest = text.partition("\n[tool_pose]\n")
    rest = rest[rest.index("\n[skin]") :]
    text = head + rest
    text = text.replace("max_delay_s = 2.0", "max_delay_s = 0.3")
    for key, value in time.items():
        text = re.sub(rf"^{key} = .*$", f"{key} = {value}", text, count=1, flags=re.MULTILINE)
    path = root / "map.toml"
    path.write_text(text, encoding="utf-8")
    return path


_RUNNING: list[_Run] = []


@pytest.fixture(autouse=True)
def _stop_listeners() -> Iterator[None]:
    """Stop every listener a test started, also when it failed (none outlives its test)."""
    yield
    while _RUNNING:
        run = _RUNNING.pop()
        run.stop.set()
        run.thread.join(30)


class _Run:
    """``listen`` in a thread while the virtual lab plays actions."""

    def __init__(self, domain: int, root: Path, map_path: Path, view: Any = None) -> None:
        self.domain, self.root, self.map_path, self.view = domain, root, map_path, view
        self.notes: list[str] = []
        self.stop = threading.Event()
        self.result: dict[str, ImportReport] = {}
        self.error = ""
        self.thread = threading.Thread(target=self._listen, daemon=True)
        _RUNNING.append(self)

    def _listen(self) -> None:
        try:
            self._run_listen()
        except BaseException as err:  # for the test's message: the thread's own error
            self.error = f"{type(err).__name__}: {err}"
            raise

    def _run_listen(self) -> None:
        self.result["report"] = listen(
            load_topic_map(self.map_path),
            self.root / "out",
            objects=load_objects(None),
            actions=load_actions(None),
            domain_id=self.domain,
            stop=self.stop,
            discovery_s=5.0,
            on_note=self.notes.append,
            view=self.view,
        )

    def finish(self) -> ImportReport:
        self.stop.set()
        self.thread.join(30)
        return self.result["report"]


def _announce(world: VirtualWorld, action: str, trial: int, phase: str) -> None:
    """Announce a phase as the UR driver's programs do (a ``textmsg`` the lab executes)."""
    said = f"atikt: object=wood action={action} trial={trial} phase={phase}"
    world.run(Program(f'textmsg("{said}")', (Call("textmsg", (said,)),)))


def _play(world: VirtualWorld, action: str, trial: int, *, wait: Any = None) -> None:
    """Announce an action's phases in time (a thread); with ``wait``, until its end is said.

    The virtual lab executes programs: an action's phases are what its programs announce, as
    a driver announces them (approach, contact, execute for the action's duration, retract,
    end).
    """
    world.prepare("wood", action, trial)
    duration = load_actions(None)[action].duration_s
    # the execute phase held 0.3 s past the action's duration: the lab executes each
    # announcement on its next cycle, later on a loaded machine, which shortens the phase
    plan = [("approach", 0.3), ("contact", 0.1), ("execute", duration + 0.3), ("retract", 0.3)]

    def run() -> None:
        for phase, hold in [*plan, ("end", 0.0)]:
            _announce(world, action, trial, phase)
            time.sleep(hold)

    threading.Thread(target=run, daemon=True).start()
    for _ in range(1200):  # a hang guard (60 s of 50 ms waits), not a time check
        if wait is None or (wait.annotated and json.loads(wait.annotated[-1][1])["phase"] == "end"):
            break
        time.sleep(0.05)
    else:
        pytest.fail("the server announced no end")


#: The virtual lab's DDS configuration beside a ``listen`` process: serve_ros2's loopback
#: configuration, and reliable writers that end without lingering. A ``listen`` process exits
#: without deleting its participant, so the lab keeps its readers matched until their lease
#: runs out, and each of its writers, deleted as the lab ends, would linger 1 s (Cyclone's
#: default) for acknowledgements that never come: 8 s for the lab's topics, after the test.
_NO_LINGER_CONFIG = LOOPBACK_CONFIG.replace(
    "</Domain>", "<Internal><WriterLingerDuration>0s</WriterLingerDuration></Internal></Domain>"
)


def _no_linger(domain_id: int) -> object | None:
    """Return the domain configured by :data:`_NO_LINGER_CONFIG` (None: it exists already).

    The lab's participant joins it (``DdsDomain`` joins a domain of this process as it is); it
    must be kept until the lab has ended.
    """
    from cyclonedds.core import DDSException  # noqa: PLC0415 (after the importorskip)
    from cyclonedds.domain import Domain  # noqa: PLC0415

    try:
        return Domain(domain_id, _NO_LINGER_CONFIG)
    except DDSException:  # the domain exists in this process: the lab joins it as it is
        return None


@contextlib.contextmanager
def _served(
    map_path: Path, domain_id: int, rate_hz: int, *, listen_process: bool = False
) -> Iterator[tuple[VirtualWorld, Any]]:
    """Serve the virtual lab's topics (its world ticking until the block ends).

    ``listen_process``: a ``listen`` in a process of its own listens, and ends before the lab
    does; the lab's writers do not linger for it (:data:`_NO_LINGER_CONFIG`).
    """
    domain = _no_linger(domain_id) if listen_process else None
    with (
        SimulatedRig(0) as rig,
        VirtualWorld(rig, load_objects(None), load_actions(None), time_scale=1.0) as world,
        serve_ros2(world, map_path, domain_id=domain_id, rate_hz=rate_hz) as server,
    ):
        yield world, server
    del domain  # kept until the lab's participant was deleted


@pytest.mark.slow(6)
def test_listen_rehearsed_against_serve_sim(dds_domain: int, tmp_path: Path) -> None:
    map_path = _map(tmp_path)
    with _served(map_path, dds_domain, 250) as (world, server):
        run = _Run(dds_domain, tmp_path, map_path)
        run.thread.start()
        time.sleep(1.5)  # discovery
        _play(world, "S1", 1, wait=server)
        time.sleep(1.8)  # max_delay_s + the import's margin
        report = run.finish()
    phases = [json.loads(text)["phase"] for _, text in server.annotated]
    assert phases[-1] == "end"
    assert "execute" in phases
    assert len(report.written) == 1, run.notes
    path = report.written[0]
    assert replay_main(["check", str(path)]) == 0
    stats = _stats(path)
    assert all(s.lost == 0 for s in stats)


def test_a_listen_dry_run_says_what_each_topic_sends_and_writes_nothing(
    dds_domain: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from recorder._cli import main as record  # noqa: PLC0415

    map_path = _map(tmp_path)
    out = tmp_path / "listened"
    argv = ["listen", "--topic-map", str(map_path), "--out", str(out)]
    argv += ["--domain-id", str(dds_domain), "--dry-run", "--duration", "1"]
    with _served(map_path, dds_domain, 250):
        status = record(argv)
    said = capsys.readouterr()
    assert status == 0, said.err
    lines = said.out.splitlines()
    assert lines[0].startswith(f"dry run of listen: DDS domain {dds_domain}, ")
    assert lines[0].endswith("read for 1 s; nothing written")
    cells = [line for line in lines if line.startswith("  /skin/cell_")]
    assert cells, said.out
    for line in cells:  # 250 Hz for a second: fewer on a machine too loaded for the lab's rate
        received = int(re.search(r": (\d+) received", line)[1])  # type: ignore[index]
        assert 0 < received < 400, line
    assert any(line.startswith("  /annotations (std_msgs/msg/String): ") for line in lines)
    assert lines[-1].startswith("listen: ready")
    assert not out.exists()  # no journal, no recording, no directory


def _stats(path: Path) -> list[Any]:
    from mcap.reader import make_reader  # noqa: PLC0415

    with path.open("rb") as handle:
        for record in make_reader(handle).iter_metadata():
            if record.name == SOURCES_RECORD:
                return list(parse_source_stats(dict(record.metadata)))
    return []


def test_lost_end_is_kept_as_incomplete_with_a_line(dds_domain: int, tmp_path: Path) -> None:
    map_path = _map(tmp_path)
    with _served(map_path, dds_domain, 250) as (world, server):
        run = _Run(dds_domain, tmp_path, map_path)
        run.thread.start()
        time.sleep(1.5)
        _play(world, "S1", 2)
        for _ in range(500):  # a hang guard (10 s of 20 ms waits), not a time check
            if any("execute" in t for _, t in server.annotated):
                break
            time.sleep(0.02)
        else:
            pytest.fail("the server announced no execute phase")
        report = run.finish()  # stopped before the action's end
    assert report.written == []
    assert len(report.incomplete) == 1
    assert is_incomplete(report.incomplete[0])
    assert any("kept as incomplete" in line and "before its 'end'" in line for line in run.notes)


@pytest.mark.slow(6)
def test_huge_messages_and_bad_annotations_are_counted_with_a_line(
    dds_domain: int, tmp_path: Path
) -> None:
    # the joint topic's own budget (64 KiB) holds: the huge message (1.6 MB) is within the
    # map's default for every other topic ([time] max_message_kib = 4096)
    map_path = _map(tmp_path)
    text = map_path.read_text(encoding="utf-8")
    joint_topic = 'topic = "/joint_states"\n'
    assert joint_topic in text
    map_path.write_text(text.replace(joint_topic, joint_topic + "max_message_kib = 64\n", 1))
    topic_map = load_topic_map(map_path)
    assert topic_map.message_budget("/joint_states") == (64 << 10, "[joint_states]")
    assert topic_map.message_budget("/annotations") == (4096 << 10, "[time]")
    store = typestore(topic_map)
    with _served(map_path, dds_domain, 250) as (world, server):
        hostile = DdsDomain(dds_domain, store)
        annotations = hostile.writer("/annotations", ANNOTATION_TYPE)
        run = _Run(dds_domain, tmp_path, map_path)
        run.thread.start()
        time.sleep(1.5)
        # the huge message: a JointState with 200,000 names on the joint topic
        joints = hostile.writer("/joint_states", "sensor_msgs/msg/JointState")
        header = store.types["std_msgs/msg/Header"](
            stamp=store.types["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="x"
        )
        huge = store.types["sensor_msgs/msg/JointState"](
            header=header,
            name=["j"] * 200_000,
            position=np.zeros(0),
            velocity=np.zeros(0),
            effort=np.zeros(0),
        )
        raw = bytes(store.serialize_cdr(huge, "sensor_msgs/msg/JointState"))
        for _ in range(3):
            joints.write(raw)
        for text in ("not json", '{"object": "wood"}', '{"phase": "execute"}'):
            message = store.types[ANNOTATION_TYPE](data=text)
            annotations.write(bytes(store.serialize_cdr(message, ANNOTATION_TYPE)))
        _play(world, "S1", 3, wait=server)
        time.sleep(1.8)
        report = run.finish()
    assert report.oversize == {"/joint_states": 3}
    assert sum("larger than [joint_states] max_message_kib = 64" in line for line in run.notes)
    skipped = [line for line in run.notes if line.startswith("skipped topic /annotations")]
    assert len(skipped) == 3, skipped
    assert len(report.written) == 1, run.notes


def test_sigterm_keeps_the_open_action_and_exits_143(dds_domain: int, tmp_path: Path) -> None:
    import os  # noqa: PLC0415
    import signal  # noqa: PLC0415
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415

    map_path = _map(tmp_path)
    root = Path(__file__).parents[2]
    env = {**os.environ, "PYTHONPATH": str(root)}
    command = [sys.executable, "-m", "recorder", "listen", "--topic-map", str(map_path)]
    command += ["--out", str(tmp_path / "out"), "--domain-id", str(dds_domain)]
    with _served(map_path, dds_domain, 250, listen_process=True) as (world, server):
        process = forked.Popen(
            command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        assert process.stdout is not None
        first = process.stdout.readline()  # once subscribed
        assert first.startswith("listening on DDS domain"), first
        _play(world, "S1", 4)
        for _ in range(500):  # a hang guard (10 s of 20 ms waits), not a time check
            if any("execute" in t for _, t in server.annotated):
                break
            time.sleep(0.02)
        else:
            pytest.fail("the server announced no execute phase")
        time.sleep(0.3)
        process.send_signal(signal.SIGTERM)
        out, err = process.communicate(timeout=30)
    assert process.returncode == 143, err
    assert "Traceback" not in err
    lines = [first, *out.splitlines()]
    assert sum("interrupted (SIGTERM)" in line for line in lines) == 1
    kept = list((tmp_path / "out").rglob("*.incomplete.mcap"))
    assert len(kept) == 1, out
    assert lines[-1].endswith("1 kept as incomplete")


def test_an_action_begun_before_the_topics_arrived_is_incomplete(tmp_path: Path) -> None:
    from recorder.bagimport._listen import Listener, _Arrivals  # noqa: PLC0415
    from recorder.bagimport._windows import Window  # noqa: PLC0415

    topic_map = load_topic_map(_map(tmp_path))
    listener = Listener(topic_map, tmp_path / "out", load_objects(None), load_actions(None))
    listener._arrivals = {"/a": _Arrivals(4_000_000), "/b": _Arrivals(4_000_000)}
    window = Window("wood", "S1", None, (("execute", 10**9), ("end", 3 * 10**9)))
    listener._first_stamp = {"/a": 10**9 - 10**6, "/b": 10**9 + 8 * 10**6}
    assert listener._joined(window) == ""
    listener._first_stamp["/b"] = 10**9 + 600 * 10**6
    assert "joined part-way: /b begins 0.600 s after" in listener._joined(window)


def _sockets(pid: int) -> list[str]:
    """Return the local addresses of a process's UDP sockets (``ss -lunp``)."""
    import subprocess  # noqa: PLC0415

    out = subprocess.run(["ss", "-lunp"], capture_output=True, text=True, check=True).stdout  # noqa: S607
    return [line.split()[3] for line in out.splitlines() if f"pid={pid}," in line]


@pytest.mark.skipif(__import__("shutil").which("ss") is None, reason="needs ss (iproute2)")
def test_loopback_confines_listen_whatever_cyclonedds_uri_says(
    dds_domain: int, tmp_path: Path
) -> None:
    import os  # noqa: PLC0415
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415

    map_path = _map(tmp_path)
    root = Path(__file__).parents[2]
    wide = "<CycloneDDS><Domain><General><AllowMulticast>true</AllowMulticast></General>"
    wide += "</Domain></CycloneDDS>"
    env = {**os.environ, "PYTHONPATH": str(root), "CYCLONEDDS_URI": wide}
    command = [sys.executable, "-m", "recorder", "listen", "--topic-map", str(map_path)]
    command += ["--out", str(tmp_path / "out"), "--domain-id", str(dds_domain + 1)]
    command += ["--loopback", "--duration", "30"]
    with _served(map_path, dds_domain + 1, 50, listen_process=True):
        process = forked.Popen(
            command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        try:
            assert process.stdout is not None
            first = process.stdout.readline()
            assert first.startswith("listening on DDS domain"), first
            bound = _sockets(process.pid)
        finally:
            process.terminate()
            process.communicate(timeout=30)
    # what it sends from, it sends from 127.0.0.1; no multicast socket; Cyclone DDS 0.11 binds
    # its two unicast receive sockets to 0.0.0.0 whatever its configuration (it advertises
    # 127.0.0.1 only)
    specific = [a for a in bound if not a.startswith("0.0.0.0:")]
    assert specific, bound
    assert all(a.startswith("127.0.0.1:") for a in specific), bound
    assert len(bound) - len(specific) <= 2, bound


@pytest.mark.slow(10)
def test_the_soak_benchmark_runs_quick(dds_domain: int) -> None:
    import os  # noqa: PLC0415
    import subprocess  # noqa: PLC0415
    import sys  # noqa: PLC0415

    root = Path(__file__).parents[2]
    bench = root / "tests" / "bench" / "bench_listen_soak.py"
    env = {**os.environ, "PYTHONPATH": str(root)}
    done = subprocess.run(  # noqa: S603 (this interpreter, fixed arguments)
        # a domain of its own: another test's lab still shutting down publishes into none
        [sys.executable, str(bench), "--quick", "--domain", str(dds_domain)],
        env=env,
        capture_output=True,
        text=True,
        check=False,
        timeout=300,
    )
    assert done.returncode == 0, done.stderr
    written = re.search(r"pass check (\d+) of (\d+)", done.stdout)
    assert written is not None, done.stdout
    assert written.group(2) != "0"
    assert "accounting: missing 0, queue overflow 0" in done.stdout
    # a publisher held up across an action's edge is a counted pause, not a failed file
    # (test_listen_edges.py replays such streams deterministically)
    assert written.group(1) == written.group(2), done.stdout[-1500:]


@pytest.mark.slow(5)
def test_listen_serves_what_it_receives_to_foxglove(dds_domain: int, tmp_path: Path) -> None:
    pytest.importorskip("websockets.sync.client")
    pytest.importorskip("foxglove")
    from foxglove_client import FoxgloveClient  # noqa: PLC0415 (after the skips)

    from recorder.writing._foxglove import TopicView  # noqa: PLC0415
    from replay import read_recording  # noqa: PLC0415

    map_path = _map(tmp_path)
    store = typestore(load_topic_map(map_path))
    with TopicView("127.0.0.1:0") as view, _served(map_path, dds_domain, 250) as (world, server):
        assert view.url.startswith("ws://127.0.0.1:")
        client = FoxgloveClient(view.url)
        run = _Run(dds_domain, tmp_path, map_path, view)
        run.thread.start()

        def said() -> str:
            return (
                f"subscribed {sorted(view.subscribed)}; advertised to the client "
                f"{sorted(client.topics.values())} (its reader stopped: {client.error!r}); "
                f"listen: {run.error!r} {run.notes}; the view: {view.failure!r}"
            )

        # listen declares the topics once discovered; the client subscribes to what is
        # declared: the action starts once both are done, however long discovery takes
        for _ in range(1200):  # a hang guard (60 s of 50 ms waits), not a time check
            if view.subscribed >= {"/annotations", "/joint_states"}:
                break
            assert run.thread.is_alive(), said()
            time.sleep(0.05)
        else:
            pytest.fail(said())
        _play(world, "S1", 1, wait=server)
        time.sleep(1.8)  # max_delay_s + the import's margin
        report = run.finish()
        time.sleep(0.5)  # the view's thread serves what is queued
        client.close()
    assert client.error == ""
    assert view.dropped == 0
    assert view.failure == ""
    (path,) = report.written
    # the lab's own topics and types, as received: the joint states Foxglove got are the
    # lab's messages, and the recording's joint positions are among them, value for value
    assert client.schemas["/joint_states"] == ("cdr", "ros2msg")
    assert "/annotations" in client.received
    shown = {
        tuple(cast("Any", store.deserialize_cdr(raw, "sensor_msgs/msg/JointState")).position)
        for raw in client.received["/joint_states"]
    }
    joints = read_recording(path).joints
    assert joints is not None
    recorded = [tuple(row) for row in joints.position.tolist()]
    assert recorded
    assert set(recorded) <= shown


def test_the_virtual_lab_tool_pose_quaternion_is_scipys() -> None:
    from scipy.spatial.transform import Rotation  # noqa: PLC0415

    from recorder.virtuallab._ros2_server import _quaternion  # noqa: PLC0415

    rng = np.random.default_rng(0)
    rotvecs = [np.zeros(3), np.array([0.0, np.pi, 0.0]), *rng.uniform(-3, 3, (20, 3))]
    for rotvec in rotvecs:
        mine = np.array(_quaternion(rotvec))
        theirs = Rotation.from_rotvec(rotvec).as_quat()  # x, y, z, w
        assert np.allclose(mine, theirs) or np.allclose(mine, -theirs), rotvec


def test_a_dry_runs_topic_line_says_rates_off_the_map_and_losses() -> None:
    from recorder.bagimport._listen import TopicCheck  # noqa: PLC0415

    fine = TopicCheck("/skin", "atikt_msgs/msg/SkinCell", 1000, 1001.0, 1000.0, 0, 0)
    assert (
        fine.line() == "/skin (atikt_msgs/msg/SkinCell): 1000 received, 1001 Hz (the map: 1000 Hz)"
    )
    assert fine.lost == 0
    slow = TopicCheck("/skin", "T", 500, 500.0, 1000.0, 3, 2)
    assert slow.line() == (
        "/skin (T): 500 received, 500 Hz (the map: 1000 Hz); check the map's rate or the "
        "publisher; 3 dropped by a full queue; 2 larger than the topic's budget (max_message_kib)"
    )
    assert slow.lost == 5
    assert (
        TopicCheck("/annotations", "S", 0, None, None, 0, 0).line()
        == "/annotations (S): 0 received"
    )


def test_a_dry_run_whose_skin_sends_nothing_is_not_ready(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    # the skin's publishers exist but send nothing (a driver up, its sensor bus down): the
    # files would fail check, so the dry run says not ready, as `session --dry-run` does;
    # the annotations, idle between actions, are said, not refused
    from recorder._cli import main as record  # noqa: PLC0415
    from recorder.bagimport import _command  # noqa: PLC0415
    from recorder.bagimport._listen import TopicCheck  # noqa: PLC0415
    from recorder.bagimport._source import SkinTopic, extractors  # noqa: PLC0415

    map_path = _map(tmp_path)
    skin = [t for t, e in extractors(load_topic_map(map_path)).items() if isinstance(e, SkinTopic)]
    found = [TopicCheck(t, "T", 0, None, 250.0, 0, 0) for t in skin]
    found.append(TopicCheck("/annotations", "std_msgs/msg/String", 0, None, None, 0, 0))
    monkeypatch.setattr(_command, "check_listen", lambda *_a, **_k: tuple(found))
    argv = ["listen", "--topic-map", str(map_path), "--out", str(tmp_path / "out")]
    assert record([*argv, "--dry-run", "--duration", "1"]) == 1
    last = capsys.readouterr().out.splitlines()[-1]
    assert last == f"listen: not ready: {', '.join(skin)} sent nothing"
    found[:-1] = [TopicCheck(t, "T", 250, 250.0, 250.0, 0, 0) for t in skin]
    assert record([*argv, "--dry-run", "--duration", "1"]) == 0
    assert capsys.readouterr().out.splitlines()[-1] == (
        "listen: ready (/annotations sent nothing: idle, or slower than the check)"
    )
