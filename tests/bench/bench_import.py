"""Benchmark of ``import-bag`` on synthetic lab sessions at 1x, 4x and 16x a base size.

Run from the repository root::

    python tests/bench/bench_import.py                  # 16 MB, 64 MB, 256 MB bags
    python tests/bench/bench_import.py --base-mb 256    # 256 MB, 1 GB, 4 GB bags
    python tests/bench/bench_import.py --ros2 sqlite3 --factors 1,4   # ROS 2 bags (or mcap)

A generator writes a ROS 1 session bag of a UR10 with a 7-cell skin whose driver batches 22
acceleration samples per 100 Hz message (with the cell's 3 forces and temperature), joint
states at 125 Hz and a CSV of 5 s actions every 6 s. For each size it prints, measured side by
side in one run: rosbags' own read + deserialize of every message of the bag (``AnyReader``),
the import of the same bag (``atikt-record import-bag`` in a fresh process), the ratio of
their throughputs, and the import process's peak resident memory: ``ru_maxrss`` of
``resource.getrusage(RUSAGE_CHILDREN)`` in a small launcher process, and the ``VmHWM`` the
import process reports itself. With ``--ros2 sqlite3`` or ``--ros2 mcap`` the generator writes
the same session as a ROS 2 bag (rosbags' ``rosbag2.Writer``, CDR messages, that storage).
``--quick`` imports one bag of the shortest session (12 s; a check that the benchmark runs).
"""

from __future__ import annotations

import argparse
import json
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from rosbags.highlevel import AnyReader
from rosbags.rosbag1 import Writer
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

ROOT = Path(__file__).parents[2]
NS = 1_000_000_000
START = 1_700_000_000 * NS
CELL_TYPE = "lab_skin/msg/Batch"
CELL_MSG = "std_msgs/Header header\nfloat32[66] acc\nfloat32[3] force\nfloat32 temp\n"
CELLS = 7
JOINTS = ("shoulder_pan", "shoulder_lift", "elbow", "wrist_1", "wrist_2", "wrist_3")
MAP = """
[joint_states]
topic = "/joint_states"

[skin]
cells = [0, 1, 2, 3, 4, 5, 6]

[skin.acceleration]
topic = "/skin/cell_{cell}"
field = "acc"
samples_per_message = 22
rate_hz = 2200
scale = 9.80665

[skin.force]
topic = "/skin/cell_{cell}"
field = "force"
rate_hz = 100

[skin.temperature]
topic = "/skin/cell_{cell}"
field = "temp"
rate_hz = 100

[windows]
source = "csv"
time_unit = "ns"

[actions.C5]
kind = "static"
duration_s = 5.0

[objects.block]
name = "Block"
"""
_IMPORT = """
import sys, time
from recorder._cli import main
start = time.perf_counter()
status = main(sys.argv[1:])
elapsed = time.perf_counter() - start
hwm = next(l.split()[1] for l in open("/proc/self/status") if l.startswith("VmHWM"))
print("RESULT", elapsed, hwm, file=sys.stderr)
sys.exit(status)
"""
#: Starts the import from a small process: on Linux a child's ru_maxrss starts from the
#: high-water mark of the process it was forked from, and this benchmark's own process holds
#: the generator's and rosbags' memory.
_LAUNCH = """
import resource, subprocess, sys
result = subprocess.run([sys.executable, "-c", sys.argv[1], *sys.argv[2:]], check=False)
print("MAXRSS", resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr)
sys.exit(result.returncode)
"""


def _patcher(raw: bytes, sentinel: bytes) -> int:
    """Return the offset of a unique sentinel in a serialised message."""
    assert raw.count(sentinel) == 1
    return raw.index(sentinel)


def generate(path: Path, seconds: int, ros2: str | None = None) -> tuple[int, list[str]]:
    """Write a session bag of ``seconds``; return its message count and CSV rows of windows.

    ``ros2``: None for a ROS 1 bag, else the ROS 2 storage (``sqlite3`` or ``mcap``).
    """
    store = get_typestore(Stores.ROS2_HUMBLE if ros2 else Stores.ROS1_NOETIC)
    store.register(get_types_from_msg(CELL_MSG, CELL_TYPE))
    types = store.types
    rng = np.random.default_rng(0)
    serialize = store.serialize_cdr if ros2 else store.serialize_ros1
    sentinel = types["builtin_interfaces/msg/Time"](sec=1, nanosec=2)
    header = (
        types["std_msgs/msg/Header"](stamp=sentinel, frame_id="skin")
        if ros2
        else types["std_msgs/msg/Header"](seq=0, stamp=sentinel, frame_id="skin")
    )
    stamp_field = struct.Struct("<II")
    cell = types[CELL_TYPE](
        header=header,
        acc=np.full(66, 7.25, np.float32),
        force=np.zeros(3, np.float32),
        temp=np.float32(30.0),
    )
    cell_raw = bytearray(serialize(cell, CELL_TYPE))
    stamp_at = _patcher(bytes(cell_raw), stamp_field.pack(1, 2))
    acc_at = _patcher(bytes(cell_raw), np.full(66, 7.25, np.float32).tobytes())
    joint = types["sensor_msgs/msg/JointState"](
        header=header,
        name=list(JOINTS),
        position=np.full(6, 1.5),
        velocity=np.zeros(6),
        effort=np.zeros(6),
    )
    joint_raw = bytearray(serialize(joint, "sensor_msgs/msg/JointState"))
    joint_stamp = _patcher(bytes(joint_raw), stamp_field.pack(1, 2))
    noise = rng.normal(0, 0.1, (997, 66)).astype(np.float32).tobytes()
    count = 0
    plugin = StoragePlugin.MCAP if ros2 == "mcap" else StoragePlugin.SQLITE3
    bag = Writer(path) if ros2 is None else Writer2(path, version=9, storage_plugin=plugin)
    with bag as writer:
        cells = [
            writer.add_connection(f"/skin/cell_{c}", CELL_TYPE, typestore=store)
            for c in range(CELLS)
        ]
        joints = writer.add_connection(
            "/joint_states", "sensor_msgs/msg/JointState", typestore=store
        )
        robot_next = START
        for k in range(seconds * 100):
            stamp = START + k * 10_000_000
            while robot_next <= stamp:
                joint_raw[joint_stamp : joint_stamp + 8] = stamp_field.pack(*divmod(robot_next, NS))
                writer.write(joints, robot_next + 200_000, bytes(joint_raw))
                robot_next += 8_000_000
                count += 1
            cell_raw[stamp_at : stamp_at + 8] = stamp_field.pack(*divmod(stamp, NS))
            for c, connection in enumerate(cells):
                row = (k * CELLS + c) % 997
                cell_raw[acc_at : acc_at + 264] = noise[row * 264 : (row + 1) * 264]
                writer.write(connection, stamp + 10_300_000, bytes(cell_raw))
                count += 1
    rows = [
        f"{START + t * NS + NS // 2},{START + t * NS + NS // 2 + 5 * NS},block,C5,"
        for t in range(0, seconds - 6, 6)
    ]
    return count, rows


def _size(bag: Path) -> int:
    """Return the bytes of a bag file or a ROS 2 bag directory."""
    if bag.is_dir():
        return sum(f.stat().st_size for f in bag.rglob("*") if f.is_file())
    return bag.stat().st_size


def rosbags_read(path: Path) -> float:
    """Return the seconds rosbags takes to read and deserialize every message."""
    start = time.perf_counter()
    with AnyReader([path]) as reader:
        for connection, _, raw in reader.messages():
            reader.deserialize(raw, connection.msgtype)
    return time.perf_counter() - start


def run_import(bag: Path, work: Path, rows: list[str]) -> tuple[float, int, int]:
    """Import in a fresh process; return its seconds, ru_maxrss and VmHWM in kB."""
    (work / "map.toml").write_text(MAP, "utf-8")
    (work / "windows.csv").write_text("start,stop,object,action,trial\n" + "\n".join(rows) + "\n")
    argv = ["import-bag", str(bag), "--topic-map", str(work / "map.toml")]
    argv += ["--windows", str(work / "windows.csv"), "--out", str(work / "out")]
    result = subprocess.run(  # noqa: S603 (this interpreter, a fixed script)
        [sys.executable, "-c", _LAUNCH, _IMPORT, *argv],
        capture_output=True,
        text=True,
        check=True,
        cwd=ROOT,
    )
    lines = result.stderr.splitlines()
    _, seconds, hwm = next(x for x in lines if x.startswith("RESULT")).split()
    maxrss = next(x for x in lines if x.startswith("MAXRSS")).split()[1]
    return float(seconds), int(maxrss), int(hwm)


def main() -> None:
    """Generate, read and import bags at 1x, 4x and 16x; print the figures."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--base-mb", type=float, default=16.0, help="size of the 1x bag, MB")
    parser.add_argument("--factors", default="1,4,16", help="sizes as multiples of the base")
    parser.add_argument(
        "--ros2", choices=("sqlite3", "mcap"), help="write ROS 2 bags with this storage"
    )
    parser.add_argument(
        "--quick", action="store_true", help="one bag of the shortest session (untimed)"
    )
    args = parser.parse_args()
    if args.quick:
        args.base_mb, args.factors = 0.1, "1"
    per_second = 100 * CELLS * 380 + 125 * 300  # bytes of one second of session, roughly
    results = []
    for factor in (int(f) for f in args.factors.split(",")):
        seconds = max(12, round(args.base_mb * factor * 1e6 / per_second))
        with tempfile.TemporaryDirectory() as directory:
            work = Path(directory)
            bag = work / ("session" if args.ros2 else "session.bag")
            start = time.perf_counter()
            messages, rows = generate(bag, seconds, args.ros2)
            generated = time.perf_counter() - start
            size = _size(bag)
            t_rosbags = rosbags_read(bag)
            t_import, rss, hwm = run_import(bag, work, rows)
        row = {
            "bag": f"ROS 2 ({args.ros2})" if args.ros2 else "ROS 1",
            "factor": factor,
            "bag_mb": round(size / 1e6, 1),
            "messages": messages,
            "session_s": seconds,
            "windows": len(rows),
            "generate_s": round(generated, 1),
            "rosbags_read_deserialize_s": round(t_rosbags, 2),
            "import_s": round(t_import, 2),
            "throughput_ratio": round(t_rosbags / t_import, 3),
            "import_msgs_per_s": round(messages / t_import),
            "import_peak_rss_mb": round(rss / 1024, 1),
            "import_vm_hwm_mb": round(hwm / 1024, 1),
        }
        results.append(row)
        print(json.dumps(row), flush=True)
    print(
        f"{'size':>9} {'rosbags':>9} {'import':>9} {'ratio':>6} {'msg/s':>8} "
        f"{'ru_maxrss':>10} {'VmHWM':>9}"
    )
    for r in results:
        print(
            f"{r['bag_mb']:>7} MB {r['rosbags_read_deserialize_s']:>8}s {r['import_s']:>8}s "
            f"{r['throughput_ratio']:>6} {r['import_msgs_per_s']:>8} "
            f"{r['import_peak_rss_mb']:>7} MB {r['import_vm_hwm_mb']:>6} MB"
        )


if __name__ == "__main__":
    main()
