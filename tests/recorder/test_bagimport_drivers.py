"""Real drivers' shapes through import-bag: receive-stamped batched frames (stamped from the
sensor's rate, with jitter, lost frames and clock drift), several fields into one modality,
several cells by index of one field, and bags whose messages are out of time order."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import pytest
from labbags import NS, START, header
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Ros2Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from recorder import load_actions, load_objects
from recorder._cli import main
from recorder.bagimport._importer import import_bag
from recorder.bagimport._topicmap import load_topic_map
from recorder.errors import BagImportError
from replay import read_recording

if TYPE_CHECKING:
    from recorder.bagimport._report import ImportReport

TYPES = {
    "tip_msgs/msg/Frame": "std_msgs/Header header\nfloat32[22] samples\n",
    "tip_msgs/msg/CountedFrame": "std_msgs/Header header\nuint8 frame\nfloat32[22] samples\n",
    "probe_msgs/msg/Thermistors": (
        "std_msgs/Header header\nfloat32 force\nfloat32 thermistor_a\nfloat32 thermistor_b\n"
    ),
    "tip_msgs/msg/Electrodes": "std_msgs/Header header\nfloat32[19] electrodes\n",
    "tip_msgs/msg/CountedPressure": "std_msgs/Header header\nuint16 seq\nfloat32 pressure\n",
}
Message = tuple[int, str, str, Any]
PERIOD = NS / 2200  # exact sample period of the fingertip's vibration sensor, ns


def _store(*, ros1: bool) -> Any:
    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    for name, text in TYPES.items():
        store.register(get_types_from_msg(text, name))
    return store


def _write(path: Path, storage: str, messages: list[Message], store: Any, chunk: int = 0) -> Path:
    """Write (receive, topic, type, message) in the order given (not sorted by time)."""
    ros1 = storage == "ros1"
    if ros1:
        path = path.with_suffix(".bag")
        writer: Any = Ros1Writer(path)
        if chunk:
            writer.chunk_threshold = chunk
    else:
        plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
        writer = Ros2Writer(path, version=9, storage_plugin=plugin)
    serialize = store.serialize_ros1 if ros1 else store.serialize_cdr
    with writer:
        connections: dict[str, Any] = {}
        for receive, topic, msgtype, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], receive, serialize(message, msgtype))
    return path


def _import(bag: Path, map_text: str, directory: Path, windows: str = "") -> ImportReport:
    path = directory / "map.toml"
    path.write_text(map_text, encoding="utf-8")
    if windows:
        (directory / "windows.csv").write_text(windows, encoding="utf-8")
    return import_bag(
        bag, load_topic_map(path), directory / "out", objects=load_objects(), actions=load_actions()
    )


def _windows(count: int, execute_s: float, gap_s: float, obj: str, action: str) -> str:
    """Return windows from 0.5 s on, each with an approach phase 0.4 s before execute."""
    rows = ["start,stop,object,action,trial,approach"]
    step, length = round((execute_s + gap_s) * NS), round(execute_s * NS) + NS // 20
    for trial in range(1, count + 1):
        start = START + NS // 2 + (trial - 1) * step
        rows.append(f"{start},{start + length},{obj},{action},{trial},{start - 4 * NS // 10}")
    return "\n".join(rows) + "\n"


# ----------------------------------------------------------------- 1. receive-stamped frames

FRAMES = 4000  # 40 s of 10 ms frames of 22 samples at 2200 Hz
#: Frames the driver never delivered (three gaps), in the approach phases of windows 4, 7 and
#: 11 (a pause inside an execute phase makes the reader refuse the recording).
LOST = (780, 1530, 1531, 2530)
DRIFT = 40e-6  # the sensor's crystal runs 40 ppm slow against the receive clock
LATENCY_NS = 1_940_000  # receive latency uniform in [0, 1.94 ms]: spacing 8.06..11.94 ms


@dataclass(frozen=True)
class Frames:
    """A receive-stamped fingertip session and the truth it was made from."""

    messages: list[Message]
    truth: np.ndarray  # true time of every sample (also its value: its index), ns
    latencies: np.ndarray  # receive latency of every delivered frame, ns


def _frames(*, ros1: bool, seed: int = 11, spikes: bool = False) -> tuple[Frames, Any]:
    """Return frames stamped on arrival: the last sample's true time plus a random latency.

    Frame spacing is then 10 ms * (1 + drift) plus the difference of two latencies: it varies
    in about 8.06..11.94 ms with a mean of 10 ms (a spacing drawn independently per frame
    would be a random walk away from the sensor's clock, which no receive clock does).
    """
    rng = np.random.default_rng(seed)
    store = _store(ros1=ros1)
    truth = START + np.round(np.arange(FRAMES * 22) * PERIOD * (1 + DRIFT)).astype(np.int64)
    latencies = rng.uniform(0, LATENCY_NS, FRAMES).round().astype(np.int64)
    if spikes:  # a few frames 7 ms late (the receiving computer was busy)
        latencies[[300, 1700, 3100]] += 7_000_000
    out: list[Message] = []
    msgtype = "tip_msgs/msg/CountedFrame" if spikes else "tip_msgs/msg/Frame"
    for m in range(FRAMES):
        if m in LOST:
            continue
        stamp = int(truth[22 * m + 21] + latencies[m])
        samples = np.arange(22 * m, 22 * m + 22, dtype=np.float32)
        extra = {"frame": m % 256} if spikes else {}
        msg = store.types[msgtype](header=header(store, stamp, ros1=ros1), samples=samples, **extra)
        out.append((stamp + 300_000, "/tip/frames", msgtype, msg))
    delivered = np.array([m not in LOST for m in range(FRAMES)])
    return Frames(out, truth, latencies[delivered]), store


FRAMES_MAP = """
[skin]
cells = [0]

[skin.acceleration]
topic = "/tip/frames"
field = "samples"
samples_per_message = 22
rate_hz = 2200
batch_stamp = "last"        # a frame is sent after its last sample
timing = "{timing}"

[windows]
source = "csv"
csv = "windows.csv"
time_unit = "ns"

[actions.SL]
kind = "slide"
duration_s = 2.0

[objects.felt]
name = "Felt"
"""
FRAMES_WINDOWS = _windows(15, 2.0, 0.5, "felt", "SL")


@pytest.mark.parametrize("storage", ["ros1", "mcap"])
def test_receive_stamped_frames_are_stamped_from_the_rate(storage: str, tmp_path: Path) -> None:
    frames, store = _frames(ros1=storage == "ros1")
    bag = _write(tmp_path / "tip", storage, frames.messages, store)
    report = _import(bag, FRAMES_MAP.format(timing="rate"), tmp_path, FRAMES_WINDOWS)
    assert len(report.written) == 15
    gaps_seen = 0
    for path in report.written:
        skin = read_recording(path).skin("acceleration")
        stamps, index = skin.stamps_ns, skin.data[:, 0, 0].astype(np.int64)
        assert (np.diff(stamps) > 0).all()
        # every sample within 60 us (0.13 sample periods) of its true time on the receive
        # clock, though the receive stamps jitter by 1.94 ms
        assert np.abs(stamps - frames.truth[index]).max() < 60_000
        step = np.diff(index)
        within = np.diff(stamps)[step == 1]
        assert np.abs(within - PERIOD * (1 + DRIFT)).max() < 250  # evenly spaced in a run
        for k in np.flatnonzero(step > 1):  # a lost frame stays a gap of its samples
            gaps_seen += 1
            lost = int(step[k]) - 1
            assert lost % 22 == 0
            gap = stamps[k + 1] - stamps[k]
            assert round(gap / PERIOD) == lost + 1
            assert abs(gap - (lost + 1) * PERIOD * (1 + DRIFT)) < 0.1 * PERIOD
    assert gaps_seen == 3
    timing = report.timing["/tip/frames"]["acceleration"]
    # without a counter a gap is not counted as lost frames (it may be a pause of the
    # driver); its length is reported: the 4 lost frames' samples, ~10 ms each
    assert (timing["runs"], timing["gaps"], timing["lost_frames"]) == (4, 3, 0)
    assert timing["gap_s"] == pytest.approx(4 * 22 * PERIOD / 1e9, rel=0.5)
    assert timing["drift_ppm"] == pytest.approx(DRIFT * 1e6, abs=2.0)
    spread = np.ptp(frames.latencies) / 1e6  # the largest latency beyond the smallest
    assert timing["jitter_max_ms"] == pytest.approx(spread, abs=0.01)
    assert timing["jitter_sd_ms"] == pytest.approx(np.std(frames.latencies) / 1e6, abs=0.03)
    assert report.json_path is not None
    saved = json.loads(report.json_path.read_text("utf-8"))
    assert saved["timing"]["/tip/frames"]["acceleration"]["runs"] == 4


@pytest.mark.parametrize("storage", ["ros1", "sqlite3"])
def test_a_frame_counter_keeps_one_run_across_lost_and_late_frames(
    storage: str, tmp_path: Path
) -> None:
    frames, store = _frames(ros1=storage == "ros1", spikes=True)
    bag = _write(tmp_path / "tip", storage, frames.messages, store)
    text = FRAMES_MAP.format(timing="rate").replace(
        'timing = "rate"', 'timing = "rate"\ncounter = "frame"\ncounter_modulo = 256'
    )
    if storage == "sqlite3":  # no definitions in a ROS 2 sqlite3 bag: the map gives them
        (tmp_path / "frame.msg").write_text(TYPES["tip_msgs/msg/CountedFrame"], "utf-8")
        text += '[types]\n"tip_msgs/msg/CountedFrame" = "frame.msg"\n'
    report = _import(bag, text, tmp_path, FRAMES_WINDOWS)
    timing = report.timing["/tip/frames"]["acceleration"]
    assert (timing["runs"], timing["gaps"], timing["lost_frames"]) == (1, 0, 4)
    assert timing["drift_ppm"] == pytest.approx(DRIFT * 1e6, abs=2.0)
    spread = np.ptp(frames.latencies) / 1e6  # the largest latency beyond the smallest
    assert timing["jitter_max_ms"] == pytest.approx(spread, abs=0.01)
    gaps = 0
    for path in report.written:
        skin = read_recording(path).skin("acceleration")
        stamps, index = skin.stamps_ns, skin.data[:, 0, 0].astype(np.int64)
        assert np.abs(stamps - frames.truth[index]).max() < 60_000
        step = np.diff(index)
        assert np.abs(np.diff(stamps) - step * PERIOD * (1 + DRIFT)).max() < 250
        gaps += int((step > 1).sum())
    assert gaps == 3


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ('timing = "rate"\ncounter = "samples"', "counter 'samples' is not an integer field"),
        # with timing = "message" the counter only counts listen's loss: checked all the same
        ('timing = "message"\ncounter = "samples"', "counter 'samples' is not an integer field"),
        ('timing = "rate"\ncounter_modulo = 256', "counter_modulo = 256 needs counter"),
    ],
)
def test_counter_mistakes_are_refused(change: str, message: str, tmp_path: Path) -> None:
    frames, store = _frames(ros1=True, spikes=True)
    bag = _write(tmp_path / "tip", "ros1", frames.messages[:50], store)
    text = FRAMES_MAP.replace('timing = "{timing}"', change)
    with pytest.raises(BagImportError, match=message):
        _import(bag, text, tmp_path, FRAMES_WINDOWS)


def test_receive_stamped_frames_without_timing_rate_are_refused_naming_it(
    tmp_path: Path,
) -> None:
    frames, store = _frames(ros1=True)
    bag = _write(tmp_path / "tip.bag", "ros1", frames.messages, store)
    with pytest.raises(BagImportError, match=r'go back .*set timing = "rate"'):
        _import(bag, FRAMES_MAP.format(timing="message"), tmp_path, FRAMES_WINDOWS)


# --------------------------------------------------- 2. several fields, several cells by index

PROBE_MAP = """
[skin]
cells = [0]

[skin.force]
topic = "/probe"
field = "force"

[skin.temperature]
topic = "/probe"
field = ["thermistor_a", "thermistor_b"]

[windows]
source = "csv"
csv = "windows.csv"
time_unit = "ns"

[actions.hold]
kind = "static"
duration_s = 1.0

[objects.wood]
name = "Wood"
"""

ELECTRODES_MAP = """
[skin]
cells = [{cells}]

[skin.force]
topic = "/tip/electrodes"
field = "electrodes[{{cell}}]"
scale = 0.5

[windows]
source = "csv"
csv = "windows.csv"
time_unit = "ns"

[actions.P]
kind = "press"
duration_s = 1.0

[objects.wood]
name = "Wood"
"""


def _probe(*, ros1: bool) -> tuple[list[Message], Any, np.ndarray]:
    rng = np.random.default_rng(7)
    store = _store(ros1=ros1)
    values = rng.normal(25.0, 2.0, (500, 3)).astype(np.float32)
    out: list[Message] = []
    for i, (force, a, b) in enumerate(values.tolist()):
        stamp = START + i * 10_000_000
        msg = store.types["probe_msgs/msg/Thermistors"](
            header=header(store, stamp, ros1=ros1), force=force, thermistor_a=a, thermistor_b=b
        )
        out.append((stamp + 1_000_000, "/probe", "probe_msgs/msg/Thermistors", msg))
    return out, store, values


def _electrodes(*, ros1: bool) -> tuple[list[Message], Any, np.ndarray]:
    rng = np.random.default_rng(8)
    store = _store(ros1=ros1)
    values = rng.uniform(0, 4000, (500, 19)).astype(np.float32)
    out: list[Message] = []
    for i, row in enumerate(values):
        stamp = START + i * 10_000_000
        msg = store.types["tip_msgs/msg/Electrodes"](
            header=header(store, stamp, ros1=ros1), electrodes=row
        )
        out.append((stamp + 1_000_000, "/tip/electrodes", "tip_msgs/msg/Electrodes", msg))
    return out, store, values


def _published(stamps: np.ndarray) -> np.ndarray:
    """Return the index of each recorded stamp among the published messages (10 ms apart)."""
    index = (stamps - START) // 10_000_000
    assert ((stamps - START) % 10_000_000 == 0).all()
    return index.astype(np.int64)


@pytest.mark.parametrize("storage", ["ros1", "mcap"])
def test_two_fields_feed_one_modality(storage: str, tmp_path: Path) -> None:
    messages, store, values = _probe(ros1=storage == "ros1")
    bag = _write(tmp_path / "probe", storage, messages, store)
    report = _import(bag, PROBE_MAP, tmp_path, _windows(2, 1.0, 0.5, "wood", "hold"))
    assert len(report.written) == 2
    for path in report.written:
        recording = read_recording(path)
        temperature = recording.skin("temperature")
        assert temperature.data.shape[1:] == (1, 2)
        index = _published(temperature.stamps_ns)
        np.testing.assert_array_equal(temperature.data[:, 0, :], values[index, 1:])
        force = recording.skin("force")
        np.testing.assert_array_equal(force.data[:, 0, 0], values[_published(force.stamps_ns), 0])
        assert json.loads(str(recording.metadata.rig["widths"])) == {"force": 1, "temperature": 2}


@pytest.mark.parametrize(("storage", "cells"), [("ros1", range(19)), ("mcap", (18, 3, 7))])
def test_cells_by_index_of_one_field(
    storage: str, cells: range | tuple[int, ...], tmp_path: Path
) -> None:
    messages, store, values = _electrodes(ros1=storage == "ros1")
    bag = _write(tmp_path / "tip", storage, messages, store)
    text = ELECTRODES_MAP.format(cells=", ".join(map(str, cells)))
    report = _import(bag, text, tmp_path, _windows(2, 1.0, 0.5, "wood", "P"))
    assert len(report.written) == 2
    for path in report.written:
        force = read_recording(path).skin("force")
        assert force.data.shape[1:] == (len(cells), 1)
        index = _published(force.stamps_ns)
        np.testing.assert_array_equal(force.data[:, :, 0], values[index][:, list(cells)] * 0.5)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (('field = "electrodes[{cell}]"', 'field = "electrodes[cell]"'), "not a field path"),
        (('field = "electrodes[{cell}]"', "field = []"), r"field = \[\] must be a field or a list"),
        (('topic = "/tip/electrodes"', 'topic = "/tip/e{cell}"'), "both name {cell}"),
        (('field = "electrodes[{cell}]"', 'field = "electrodes"'), "mapped to 3 cells; .*{cell}"),
        (("scale = 0.5", "scale = 0.5\nsamples_per_message = 2\nrate_hz = 10"), "picks elements"),
        (("cells = [18, 3, 7]", "cells = [19]"), "has 19 values, no element 19"),
        # -19 indexed from the end is element 0: another cell's values, written without a word
        (("cells = [18, 3, 7]", "cells = [3, -19]"), r"cells \[-19\]: give cell ids 0\.\."),
        (("cells = [18, 3, 7]", "cells = [2147483648]"), r"cells \[2147483648\]: give cell"),
        (("scale = 0.5", 'scale = 0.5\ntiming = "rate"'), "needs rate_hz"),
        (("scale = 0.5", 'scale = 0.5\ntiming = "sensor"'), "timing = 'sensor' must be one of"),
    ],
)
def test_mapping_mistakes_are_refused_in_one_line(
    change: tuple[str, str], message: str, tmp_path: Path
) -> None:
    messages, store, _ = _electrodes(ros1=True)
    bag = _write(tmp_path / "tip.bag", "ros1", messages, store)
    text = ELECTRODES_MAP.format(cells="18, 3, 7").replace(*change)
    with pytest.raises(BagImportError, match=message) as caught:
        _import(bag, text, tmp_path, _windows(1, 1.0, 0.5, "wood", "P"))
    assert "\n" not in str(caught.value)


def test_an_index_into_a_number_is_refused(tmp_path: Path) -> None:
    messages, store, _ = _probe(ros1=True)
    bag = _write(tmp_path / "probe.bag", "ros1", messages, store)
    text = PROBE_MAP.replace('field = "force"', 'field = "force[0]"')
    with pytest.raises(BagImportError, match=r"'force' is a number, not an array; remove the \["):
        _import(bag, text, tmp_path, _windows(1, 1.0, 0.5, "wood", "hold"))


# ------------------------------------------------------------------- 3. out-of-order bags


@pytest.mark.parametrize("storage", ["ros1", "mcap", "sqlite3"])
def test_a_bag_merged_from_two_recorders_is_read_in_time_order(
    storage: str, tmp_path: Path
) -> None:
    """Two recorders' bags concatenated: every force message, then every temperature one
    (in small chunks that overlap in time), and inside each a few messages swapped."""
    messages, store, values = _probe(ros1=storage == "ros1")
    force, temperature = messages[::2], messages[1::2]
    force[10], force[11] = force[11], force[10]
    merged = [(r, "/a/probe", t, m) for r, _, t, m in force]
    merged += [(r, "/b/probe", t, m) for r, _, t, m in temperature]
    bag = _write(tmp_path / "merged", storage, merged, store, chunk=4096)
    text = PROBE_MAP.replace(
        'topic = "/probe"\nfield = "force"', 'topic = "/a/probe"\nfield = "force"'
    ).replace('topic = "/probe"', 'topic = "/b/probe"')
    report = _import(bag, text, tmp_path, _windows(2, 1.0, 0.5, "wood", "hold"))
    assert len(report.written) == 2
    recording = read_recording(report.written[0])
    force_index = _published(recording.skin("force").stamps_ns)
    assert (force_index % 2 == 0).all()
    np.testing.assert_array_equal(recording.skin("force").data[:, 0, 0], values[force_index, 0])


def test_messages_that_go_back_in_time_are_refused_naming_the_cause() -> None:
    from recorder.bagimport._importer import _Counts, _ticked  # noqa: PLC0415

    @dataclass(frozen=True)
    class Connection:
        topic: str
        owner: object

    owner = object()
    connection = Connection("/x", owner)
    counts = _Counts({id(owner): "merged.bag"}, None)
    messages = [(connection, 5, b""), (connection, 7, b""), (connection, 6, b"")]
    routes = {id(connection): "route"}
    with pytest.raises(BagImportError, match=r"merged.bag: messages on /x go back in time at t=6 "):
        list(_ticked(messages, counts, routes))  # type: ignore[arg-type]


def test_cli_prints_runs_jitter_and_drift(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    frames, store = _frames(ros1=True)
    bag = _write(tmp_path / "tip", "ros1", frames.messages, store)
    (tmp_path / "map.toml").write_text(FRAMES_MAP.format(timing="rate"), encoding="utf-8")
    (tmp_path / "windows.csv").write_text(FRAMES_WINDOWS, encoding="utf-8")
    argv = ["import-bag", str(bag), "--topic-map", str(tmp_path / "map.toml")]
    assert main([*argv, "--out", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    row = next(line for line in printed.splitlines() if "/tip/frames" in line)
    cells = [cell.strip() for cell in row.split("│")[1:-1]]
    assert cells[:3] == ["/tip/frames", "acceleration", "4"]
    assert cells[3].split()[0] == "3"  # gaps (s): without a counter, not lost frames
    assert cells[4] == "0"
    assert cells[5].startswith("1.93")
    assert cells[6] == "+40.2"


PRESSURE_MAP = """
[skin]
cells = [0]

[skin.force]
topic = "/tip/pressure"
field = "pressure"
rate_hz = 100
counter = "seq"
counter_modulo = 65536

[windows]
source = "csv"
csv = "windows.csv"
time_unit = "ns"

[actions.SL]
kind = "press"
duration_s = 2.0

[objects.felt]
name = "Felt"
"""


@pytest.mark.parametrize(
    ("storage", "counter"), [("ros1", "seq"), ("mcap", "seq"), ("ros1", "header.seq")]
)
def test_a_message_counter_counts_what_a_sensor_stamped_topic_lost(
    storage: str, counter: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    # 100 Hz pressure stamped by the sensor (timing = "message"), counting its messages in
    # seq (or, in ROS 1, in its header's seq): 4 of 4000 never reached the bag, and the
    # driver restarted at message 3500 (seq from 0 again). The report counts the 4 lost and
    # 1 reset, nothing lost at the reset
    ros1 = storage == "ros1"
    store = _store(ros1=ros1)
    msgtype = "tip_msgs/msg/CountedPressure"
    messages: list[Message] = []
    for m in range(4000):
        if m in LOST:
            continue
        stamp = START + m * NS // 100
        seq = m if m < 3500 else m - 3500  # the restart
        head = header(store, stamp, ros1=ros1)
        if counter == "header.seq":
            head.seq, seq = seq, 0
        msg = store.types[msgtype](header=head, seq=seq, pressure=1.0)
        messages.append((stamp + 300_000, "/tip/pressure", msgtype, msg))
    bag = _write(tmp_path / "tip", storage, messages, store)
    text = PRESSURE_MAP.replace('counter = "seq"', f'counter = "{counter}"')
    (tmp_path / "map.toml").write_text(text, encoding="utf-8")
    (tmp_path / "windows.csv").write_text(FRAMES_WINDOWS, encoding="utf-8")
    argv = ["import-bag", str(bag), "--topic-map", str(tmp_path / "map.toml")]
    assert main([*argv, "--out", str(tmp_path / "out")]) == 0
    printed = capsys.readouterr().out
    row = next(line for line in printed.splitlines() if line.startswith("│ /tip/pressure"))
    assert [cell.strip() for cell in row.split("│")[1:-1]] == [
        "/tip/pressure",
        "3996",
        "4",
        "0",
        "1",
    ]
    (report,) = (tmp_path / "out" / "imports").glob("*.json")
    counted = json.loads(report.read_text("utf-8"))["counted"]["/tip/pressure"]
    assert counted == {"messages": 3996, "lost": 4, "duplicated": 0, "resets": 1}


def test_the_documented_examples_parse(tmp_path: Path) -> None:
    example = Path(__file__).parents[2] / "recorder" / "data" / "topic_map.example.toml"
    text = example.read_text("utf-8")
    block = text[text.index("#   The same fingertip") : text.index("#   A fixed probe")]
    lines = [line[6:] for line in block.splitlines() if line.startswith("#     ")]
    path = tmp_path / "map.toml"
    path.write_text("\n".join([*lines, '[windows]\nsource = "csv"\n']), encoding="utf-8")
    skin = load_topic_map(path).skin
    assert skin["force"].per_cell
    assert skin["acceleration"].timing == "rate"
    assert skin["acceleration"].counter_modulo == 256
    probe = text[text.index("#   A fixed probe") : text.index("[time]")]
    lines = [line[6:] for line in probe.splitlines() if line.startswith("#     ")]
    lines = [line[2:] if line.startswith("# field") else line for line in lines]
    assert 'field = ["thermistor_a", "thermistor_b"]   # side by side: width 2' in lines
    lines.remove('field = "temperatures"                 # float32[2]: width 2')
    path.write_text("\n".join(lines), encoding="utf-8")
    assert [p.path for p in load_topic_map(path).skin["temperature"].fields] == [
        "thermistor_a",
        "thermistor_b",
    ]


def test_live_sessions_stamp_receive_stamped_frames_as_the_import_does(tmp_path: Path) -> None:
    """``listen`` feeds the same conversion (``feed``, ``Route``, a live ``_Session``) in
    batches, trimming what no window needs: its files equal the bag import's."""
    from recorder.bagimport._importer import _plans, _Session, feed, routes, tally  # noqa: PLC0415
    from recorder.bagimport._report import ImportReport as Report  # noqa: PLC0415
    from recorder.bagimport._source import extractors  # noqa: PLC0415
    from recorder.bagimport._windows import windows_from_csv  # noqa: PLC0415

    frames, store = _frames(ros1=False)
    bag = _write(tmp_path / "tip", "mcap", frames.messages, store)
    imported = _import(bag, FRAMES_MAP.format(timing="rate"), tmp_path, FRAMES_WINDOWS)
    topic_map = load_topic_map(tmp_path / "map.toml")
    out = tmp_path / "live"
    report = Report(imported.bags, out, topic_map.path)
    found = extractors(topic_map)
    windows = windows_from_csv(tmp_path / "windows.csv", "ns", 0)
    plans = _plans(windows, topic_map, out, load_objects(), load_actions())
    session = _Session([], topic_map, found, report.bags, report, None, live=True)
    for plan in plans:
        session.add(plan)
    channel = [("/tip/frames", "/tip/frames", "tip_msgs/msg/Frame")]
    route = routes(store, channel, found, clock="header", deserialize=store.deserialize_cdr)
    data = [
        (route["/tip/frames"], receive, store.serialize_cdr(message, msgtype))
        for receive, _, msgtype, message in frames.messages
    ]
    for start in range(0, len(data), 50):
        feed(data[start : start + 50], session)
        now = data[min(start + 50, len(data)) - 1][1]
        session.advance(now)
        session.trim(now - topic_map.max_delay_ns - 1_000_000_000)
    while session.done < len(session.plans):
        session.finish_one()
    tally(found, report)
    assert len(report.written) == len(imported.written) == 15
    assert report.timing["/tip/frames"]["acceleration"]["runs"] == 4
    for live, bagged in zip(report.written, imported.written, strict=True):
        a, b = (
            read_recording(live).skin("acceleration"),
            read_recording(bagged).skin("acceleration"),
        )
        np.testing.assert_array_equal(a.data, b.data)
        assert np.abs(a.stamps_ns - b.stamps_ns).max() < 30_000  # fits differ only by when


def test_a_rate_the_stamps_contradict_is_refused_with_the_measured_rate(tmp_path: Path) -> None:
    frames, store = _frames(ros1=True)
    bag = _write(tmp_path / "tip", "ros1", frames.messages, store)
    text = FRAMES_MAP.format(timing="rate").replace("rate_hz = 2200", "rate_hz = 2205")
    wrong = r"is \+23\d\d ppm off rate_hz = 2205 \(they say 2199\.9 Hz\); fix rate_hz"
    with pytest.raises(BagImportError, match=wrong):
        _import(bag, text, tmp_path, FRAMES_WINDOWS)


def test_without_jitter_the_samples_are_exactly_on_the_rate() -> None:
    from fractions import Fraction  # noqa: PLC0415

    from recorder.bagimport._timing import Timeline  # noqa: PLC0415

    period = Fraction(NS, 2200)
    timeline = Timeline("t", period, 22, 0)
    frames = [m for m in range(3000) if m not in LOST]
    for m in frames:
        timeline.push(START + int(22 * m * period))
    stamps = timeline.stamps(0, len(frames)).reshape(len(frames), 22)
    truth = START + np.array([[int((22 * m + i) * period) for i in range(22)] for m in frames])
    assert np.abs(stamps - truth).max() <= 1
    summary = timeline.summary()
    assert (summary["runs"], summary["lost_frames"]) == (4, 0)
    assert summary["gap_s"] == pytest.approx(len(LOST) * 22 * float(period) / 1e9, rel=0.2)
    assert summary["jitter_max_ms"] < 1e-6
    assert abs(summary["drift_ppm"]) < 0.01


def test_the_pause_between_recordings_is_a_gap_not_lost_frames() -> None:
    from fractions import Fraction  # noqa: PLC0415

    from recorder.bagimport._timing import Timeline  # noqa: PLC0415

    period = Fraction(NS, 2200)
    timeline = Timeline("t", period, 22, 0)
    pause = 600 * NS  # ten minutes between two slides
    for m in range(2000):
        timeline.push(START + int(22 * m * period) + (pause if m >= 1000 else 0))
    summary = timeline.summary()
    assert (summary["runs"], summary["gaps"], summary["lost_frames"]) == (2, 1, 0)
    assert summary["gap_s"] == pytest.approx(600, abs=0.01)
