"""Live ROS 2 recording over loopback DDS: samples missing, latency and recorder CPU.

A publisher process sends, for ``--seconds`` (default 60), what a UR e-Series driver and a
7-cell skin driver publish: JointState at 500 Hz, and per cell force and acceleration at
1 kHz, temperature at 20 Hz, proximity at 50 Hz (one topic per cell and modality, one sample
per message: 15 k messages/s). This process runs ``listen``'s :class:`Listener` on them (the
readers, the queues, the import's conversion) and prints samples expected / received /
missing, the p99 latency from a sample's stamp to its hand-off by the reader queue to the
conversion, and the recorder's CPU time per second. DDS stays on loopback.

    python tests/bench/bench_live_dds.py --seconds 10

``--quick`` publishes for one second (a check that the benchmark runs).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

LOOPBACK_URI = (
    '<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General><Discovery><Peers>"
    '<Peer address="127.0.0.1"/></Peers><ParticipantIndex>auto</ParticipantIndex>'
    "</Discovery></Domain></CycloneDDS>"
)
os.environ["CYCLONEDDS_URI"] = LOOPBACK_URI  # before cyclonedds is imported

import numpy as np  # noqa: E402

NS = 1_000_000_000
CELLS = 7
#: modality -> (topic pattern, type, rate Hz)
SKIN = {
    "force": ("/skin/force_{cell}", "bench_msgs/msg/Vec3", 1000),
    "acceleration": ("/skin/acc_{cell}", "bench_msgs/msg/Vec3", 1000),
    "temperature": ("/skin/temp_{cell}", "bench_msgs/msg/Scalar", 20),
    "proximity": ("/skin/prox_{cell}", "bench_msgs/msg/Scalar", 50),
}
JOINT_HZ = 500
TYPES = {
    "bench_msgs/msg/Vec3": "std_msgs/Header header\nfloat32[3] data\n",
    "bench_msgs/msg/Scalar": "std_msgs/Header header\nfloat32 data\n",
}


def write_map(root: Path) -> Path:
    """Write the topic map (and its message definitions) of the benchmark."""
    lines = ["[time]", 'stamps = "header"', "max_delay_s = 0.5", "", "[joint_states]"]
    lines += ['topic = "/joint_states"', "", "[skin]", f"cells = {list(range(CELLS))}", ""]
    for modality, (topic, _, rate) in SKIN.items():
        lines += [f"[skin.{modality}]", f'topic = "{topic}"', 'field = "data"']
        lines += [f"rate_hz = {rate}", ""]
    lines += ["[windows]", 'source = "topic"', 'topic = "/annotations"', "", "[types]"]
    for name, text in TYPES.items():
        file = root / (name.rsplit("/", 1)[-1] + ".msg")
        file.write_text(text, encoding="utf-8")
        lines.append(f'"{name}" = "{file.name}"')
    path = root / "map.toml"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _template(store: Any, msgtype: str, value: Any) -> bytearray:
    """Return a serialized message whose stamp (bytes 4..12) is patched per sample."""
    types = store.types
    header = types["std_msgs/msg/Header"](
        stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="bench"
    )
    if msgtype == "sensor_msgs/msg/JointState":
        names = [f"joint_{i}" for i in range(6)]
        message = types[msgtype](
            header=header, name=names, position=value, velocity=value, effort=value
        )
    else:
        message = types[msgtype](header=header, data=value)
    return bytearray(store.serialize_cdr(message, msgtype))


def publish(map_path: Path, domain_id: int, seconds: float) -> None:
    """Publish the rig's topics in real time; print the counts sent per topic as JSON."""
    import struct  # noqa: PLC0415

    from recorder.bagimport._source import typestore  # noqa: PLC0415
    from recorder.bagimport._topicmap import load_topic_map  # noqa: PLC0415
    from recorder.live.dds import DdsDomain  # noqa: PLC0415

    store = typestore(load_topic_map(map_path))
    domain = DdsDomain(domain_id, store)
    plan: list[tuple[int, Any, bytearray, str]] = []  # (period ns, writer, template, topic)
    joint = "sensor_msgs/msg/JointState"
    plan.append(
        (
            NS // JOINT_HZ,
            domain.writer("/joint_states", joint),
            _template(store, joint, np.zeros(6)),
            "/joint_states",
        )
    )
    for topic, msgtype, rate in SKIN.values():
        value: Any = np.zeros(3, np.float32) if msgtype.endswith("Vec3") else 0.0
        for cell in range(CELLS):
            name = topic.format(cell=cell)
            plan.append(
                (NS // rate, domain.writer(name, msgtype), _template(store, msgtype, value), name)
            )
    # the windows' topic, announced and silent (no action is annotated): the listener finds
    # every topic of the map at once instead of waiting out its discovery_s (10 s) for it
    writers = [w for _, w, _, _ in plan] + [domain.writer("/annotations", "std_msgs/msg/String")]
    deadline = time.monotonic() + 20
    while any(w.matched() == 0 for w in writers) and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.5)
    pack = struct.Struct("<iI").pack_into
    start = (time.time_ns() // NS + 1) * NS
    stop = start + round(seconds * NS)
    sent = dict.fromkeys((p[3] for p in plan), 0)
    tick = start
    while tick < stop:
        delay = (tick - time.time_ns()) / NS
        if delay > 0:
            time.sleep(delay)
        offset = tick - start
        for period, writer, template, name in plan:
            if offset % period == 0:
                pack(template, 4, tick // NS, tick % NS)
                writer.write(bytes(template))
                sent[name] += 1
        tick += NS // 1000
    print(json.dumps(sent))


def record(map_path: Path, domain_id: int, seconds: float) -> None:
    """Run the listener while a publisher process sends; print the figures."""
    from recorder import load_actions, load_objects  # noqa: PLC0415
    from recorder.bagimport._listen import Listener  # noqa: PLC0415
    from recorder.bagimport._topicmap import load_topic_map  # noqa: PLC0415

    topic_map = load_topic_map(map_path)
    out = Path(tempfile.mkdtemp(prefix="bench-dds-"))
    listener = Listener(topic_map, out, load_objects(None), load_actions(None), domain_id)
    publisher = subprocess.Popen(  # noqa: S603 (this script, fixed arguments)
        [
            sys.executable,
            __file__,
            "--publish",
            str(map_path),
            "--domain",
            str(domain_id),
            "--seconds",
            str(seconds),
        ],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "CYCLONEDDS_URI": LOOPBACK_URI},
    )
    listener.start()
    latencies: list[int] = []
    received: dict[str, int] = {}
    take = listener._take

    def measured(wait_s: float) -> Any:
        items = take(wait_s)
        now = listener.clock.now_ns()
        for item in items:
            topic, raw = item.payload
            received[topic] = received.get(topic, 0) + 1
            sec, nanosec = int.from_bytes(raw[4:8], "little"), int.from_bytes(raw[8:12], "little")
            latencies.append(now - (sec * NS + nanosec))
        return items

    listener._take = measured  # type: ignore[method-assign]
    cpu0, wall0 = _cpu(), time.monotonic()
    while publisher.poll() is None:
        listener.step()
    listener.step(0.5)
    cpu, wall = _cpu() - cpu0, time.monotonic() - wall0
    listener.stop()
    stdout, _ = publisher.communicate()
    sent: dict[str, int] = json.loads(stdout.strip().splitlines()[-1])
    expected, got = sum(sent.values()), sum(received.get(t, 0) for t in sent)
    overflowed = sum(r.overflowed for r in listener._readers)
    p99 = float(np.percentile(np.asarray(latencies), 99)) / 1e6 if latencies else float("nan")
    print(f"topics {len(sent)}, {expected / seconds:,.0f} samples/s for {seconds:g} s")
    print(
        f"samples expected {expected}, received {got}, missing {expected - got}, "
        f"queue overflow {overflowed}"
    )
    print(
        f"latency stamp -> conversion hand-off: p50 "
        f"{np.percentile(latencies, 50) / 1e6:.2f} ms, p99 {p99:.2f} ms"
    )
    print(f"recorder CPU {cpu / wall:.2f} s per s (wall {wall:.1f} s, includes discovery)")


def _cpu() -> float:
    """Return this process's CPU time (user + system), s."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    """Run the benchmark (or, with ``--publish``, its publisher)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--domain", type=int, default=1 + os.getpid() % 200)
    parser.add_argument("--publish", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--quick", action="store_true", help="one second (untimed)")
    args = parser.parse_args()
    if args.quick:
        args.seconds = 1.0
    if args.publish is not None:
        publish(args.publish, args.domain, args.seconds)
        return
    with tempfile.TemporaryDirectory() as root:
        record(write_map(Path(root)), args.domain, args.seconds)


if __name__ == "__main__":
    main()
