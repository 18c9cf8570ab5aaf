"""``listen`` soaked by a jittery 1 kHz publisher: check passes, nothing missing, flat memory.

A publisher process sends, for ``--seconds`` (default 600), per skin cell force and
acceleration at 1 kHz, temperature at 20 Hz and proximity at 50 Hz, and joint states at
500 Hz, each stamped with the wall clock when it is sent (a Python publisher: its stamps
jitter by the scheduler, and it pauses now and then for 2-8 ms, as a loaded lab computer
does), and one annotated action (``execute`` then ``end``, 2 s) every 4 s. This process runs
``listen``'s :class:`Listener` on it and prints: actions announced and recordings written,
how many pass ``check`` (and with how many warnings), the accounting's missing samples and
counted gaps, the reader queues' overflow, and the recorder's resident memory every 30 s
(flat: the first and the last figure, and the largest). DDS stays on loopback.

    python tests/bench/bench_listen_soak.py --seconds 600
    python tests/bench/bench_listen_soak.py --quick      # a few actions, no figures judged

``--keep DIR`` keeps the recordings (else they go with a temporary directory).
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import struct
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
CELLS = 2
#: modality -> (topic pattern, type, rate Hz)
SKIN = {
    "force": ("/skin/force_{cell}", "bench_msgs/msg/Vec3", 1000),
    "acceleration": ("/skin/acc_{cell}", "bench_msgs/msg/Vec3", 1000),
    "temperature": ("/skin/temp_{cell}", "bench_msgs/msg/Scalar", 20),
    "proximity": ("/skin/prox_{cell}", "bench_msgs/msg/Scalar", 50),
}
JOINT_HZ = 500
ACTION_EVERY_S = 4.0
ACTION_S = 2.0
#: Chance per 1 ms tick that the publisher pauses, and how long, s.
PAUSE_CHANCE = 0.002
PAUSE_S = (0.002, 0.008)
TYPES = {
    "bench_msgs/msg/Vec3": "std_msgs/Header header\nfloat32[3] data\n",
    "bench_msgs/msg/Scalar": "std_msgs/Header header\nfloat32 data\n",
}
MEMORY_EVERY_S = 30.0
#: How long the listener waits for the publisher's topics (a loaded machine starts it slowly).
DISCOVERY_S = 120.0


def write_map(root: Path) -> Path:
    """Write the topic map (and its message definitions) of the soak."""
    lines = ["[time]", 'stamps = "header"', "max_delay_s = 0.5", "", "[joint_states]"]
    lines += ['topic = "/joint_states"', "", "[skin]", f"cells = {list(range(CELLS))}", ""]
    for modality, (topic, _, rate) in SKIN.items():
        lines += [f"[skin.{modality}]", f'topic = "{topic}"', 'field = "data"']
        lines += [f"rate_hz = {rate}", ""]
    lines += ["[windows]", 'source = "topic"', 'topic = "/annotations"', ""]
    lines += ["[actions.tap]", 'kind = "static"', f"duration_s = {ACTION_S}", ""]
    lines += ["[objects.wood]", 'name = "Wood"', "", "[types]"]
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
        stamp=types["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="soak"
    )
    if msgtype == "sensor_msgs/msg/JointState":
        names = [f"joint_{i}" for i in range(6)]
        message = types[msgtype](
            header=header, name=names, position=value, velocity=value, effort=value
        )
    else:
        message = types[msgtype](header=header, data=value)
    return bytearray(store.serialize_cdr(message, msgtype))


def _writers(domain: Any, store: Any) -> list[tuple[int, Any, bytearray, str]]:
    """Return (period ns, writer, template, topic) of every data topic."""
    joint = "sensor_msgs/msg/JointState"
    plan: list[tuple[int, Any, bytearray, str]] = [
        (
            NS // JOINT_HZ,
            domain.writer("/joint_states", joint),
            _template(store, joint, np.zeros(6)),
            "/joint_states",
        )
    ]
    for topic, msgtype, rate in SKIN.values():
        value: Any = np.zeros(3, np.float32) if msgtype.endswith("Vec3") else 0.0
        for cell in range(CELLS):
            name = topic.format(cell=cell)
            writer = domain.writer(name, msgtype)
            plan.append((NS // rate, writer, _template(store, msgtype, value), name))
    return plan


def publish(map_path: Path, domain_id: int, seconds: float) -> None:
    """Publish in real time with wall-clock stamps and pauses; print what was sent (JSON)."""
    from recorder.bagimport._source import typestore  # noqa: PLC0415
    from recorder.bagimport._topicmap import load_topic_map  # noqa: PLC0415
    from recorder.live.dds import DdsDomain  # noqa: PLC0415

    store = typestore(load_topic_map(map_path))
    domain = DdsDomain(domain_id, store)
    plan = _writers(domain, store)
    notes = domain.writer("/annotations", "std_msgs/msg/String")
    deadline = time.monotonic() + DISCOVERY_S
    while any(w.matched() == 0 for _, w, _, _ in plan) and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.5)
    pack = struct.Struct("<iI").pack_into
    rng = random.Random(7)  # noqa: S311 (a benchmark's jitter, not security)
    start, wall = time.monotonic_ns(), time.time_ns()
    stop = start + round(seconds * NS)
    sent = dict.fromkeys((p[3] for p in plan), 0)
    actions, tick, trial = 0, 0, 0
    while start + tick < stop:
        delay = (start + tick - time.monotonic_ns()) / NS
        if delay > 0:
            time.sleep(delay)
        if rng.random() < PAUSE_CHANCE:
            time.sleep(rng.uniform(*PAUSE_S))
        offset = tick % round(ACTION_EVERY_S * NS)
        for phase, at in (("execute", NS // 2), ("end", NS // 2 + round(ACTION_S * NS))):
            if offset == at:
                trial += phase == "execute"
                actions += phase == "execute"
                text = {"object": "wood", "action": "tap", "phase": phase, "trial": trial}
                text["stamp_ns"] = wall + tick  # the lab's schedule, not the late send
                message = store.types["std_msgs/msg/String"](data=json.dumps(text))
                notes.write(bytes(store.serialize_cdr(message, "std_msgs/msg/String")))
        for period, writer, template, name in plan:
            if tick % period == 0:
                now = time.time_ns()
                pack(template, 4, now // NS, now % NS)
                writer.write(bytes(template))
                sent[name] += 1
        tick += NS // 1000
    print(json.dumps({"sent": sent, "actions": actions}))


def _rss_mb() -> float:
    """Return this process's resident memory now, MB (Linux /proc; else the peak)."""
    statm = Path("/proc/self/statm")
    if statm.is_file():
        pages = int(statm.read_text().split()[1])
        return pages * os.sysconf("SC_PAGE_SIZE") / 1e6
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3


def _check(paths: list[Path]) -> tuple[int, int, list[str]]:
    """Return (files passing check, files with a warning, the failures)."""
    from replay.cli._main import _check_one  # noqa: PLC0415

    passed, warned, failures = 0, 0, []
    for path in paths:
        problem, warning, _ = _check_one(path)
        if problem is None:
            passed += 1
            warned += warning is not None
        else:
            failures.append(problem)
    return passed, warned, failures


def _accounting(paths: list[Path]) -> dict[str, int]:
    """Return the summed accounting of the files: missing, overflow, gaps, out of order."""
    from replay.errors import ReplayError  # noqa: PLC0415
    from replay.recording._reader import read_recording  # noqa: PLC0415

    totals = dict.fromkeys(("missing", "overflowed", "gaps", "duplicated", "out_of_order"), 0)
    for path in paths:
        try:
            sources = read_recording(path).sources
        except ReplayError:  # refused by check: counted there
            continue
        for item in sources:
            for key in totals:
                totals[key] += getattr(item, key)
    return totals


def soak(map_path: Path, out: Path, domain_id: int, seconds: float) -> None:
    """Run the listener while a publisher process sends; print the figures."""
    from recorder import load_actions, load_objects  # noqa: PLC0415
    from recorder.bagimport._listen import Listener  # noqa: PLC0415
    from recorder.bagimport._topicmap import load_topic_map  # noqa: PLC0415

    topic_map = load_topic_map(map_path)
    notes: list[str] = []
    listener = Listener(
        topic_map,
        out,
        load_objects(None),
        load_actions(None),
        domain_id,
        discovery_s=DISCOVERY_S,
        on_note=notes.append,
    )
    command = [sys.executable, __file__, "--publish", str(map_path), "--domain", str(domain_id)]
    publisher = subprocess.Popen(  # noqa: S603 (this script, fixed arguments)
        [*command, "--seconds", str(seconds)],
        stdout=subprocess.PIPE,
        text=True,
        env={**os.environ, "CYCLONEDDS_URI": LOOPBACK_URI},
    )
    try:
        listener.start()
    except BaseException:  # the publisher would send on for --seconds, to nobody
        publisher.kill()
        publisher.wait()
        raise
    memory = [(0.0, _rss_mb())]
    began = next_sample = time.monotonic()
    cpu0 = _cpu()
    while publisher.poll() is None:
        listener.step()
        if time.monotonic() >= next_sample:
            memory.append((time.monotonic() - began, _rss_mb()))
            next_sample += min(MEMORY_EVERY_S, max(seconds / 4, 1.0))
    for _ in range(40):  # the last windows: max_delay_s and the import's margin
        listener.step()
    listener.stop()
    wall, cpu = time.monotonic() - began, _cpu() - cpu0
    report = listener.finish()
    memory.append((wall, _rss_mb()))
    stdout, _ = publisher.communicate()
    published = json.loads(stdout.strip().splitlines()[-1])
    passed, warned, failures = _check(list(report.written))
    totals = _accounting(list(report.written))
    rate = sum(published["sent"].values()) / seconds
    print(f"published {rate:,.0f} messages/s for {seconds:g} s; {published['actions']} actions")
    print(
        f"written {len(report.written)}, incomplete {len(report.incomplete)}, skipped "
        f"{len(report.skipped)}; pass check {passed} of {len(report.written)} "
        f"({warned} with a warning)"
    )
    print(
        f"accounting: missing {totals['missing']}, queue overflow {totals['overflowed']}, "
        f"gaps {totals['gaps']}, duplicated {totals['duplicated']}, out of order "
        f"{totals['out_of_order']}"
    )
    shown = ", ".join(f"{t:.0f} s {m:.0f}" for t, m in memory)
    print(f"resident memory MB: {shown} (largest {max(m for _, m in memory):.0f})")
    print(f"recorder CPU {cpu / wall:.2f} s per s")
    dropped = ", ".join(f"{m} {n}" for m, n in sorted(report.dropped_rows.items()))
    print(f"skin rows left out by the cell alignment: {dropped or 'none'}")
    for line in failures[:5] + [n for n in notes if not n.startswith("listening")][:5]:
        print("  " + line)


def _cpu() -> float:
    """Return this process's CPU time (user + system), s."""
    usage = resource.getrusage(resource.RUSAGE_SELF)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    """Run the soak (or, with ``--publish``, its publisher)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=600.0)
    parser.add_argument("--quick", action="store_true", help="a few actions (6 s)")
    parser.add_argument("--domain", type=int, default=1 + os.getpid() % 200)
    parser.add_argument("--keep", type=Path, help="write the recordings here and keep them")
    parser.add_argument("--publish", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    seconds = 6.0 if args.quick else args.seconds
    if args.publish is not None:
        publish(args.publish, args.domain, seconds)
        return
    with tempfile.TemporaryDirectory() as root:
        out = args.keep if args.keep is not None else Path(root) / "out"
        soak(write_map(Path(root)), out, args.domain, seconds)


if __name__ == "__main__":
    main()
