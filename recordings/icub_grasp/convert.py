"""Bring the real iCub grasp dataset (Soh, Su and Demiris, IROS 2012) in through ``import-bag``.

Run from the repository root, with a clone of the dataset's repository::

    git clone https://github.com/clear-nus/icub_grasp_dataset icub
    PYTHONPATH=. python recordings/icub_grasp/convert.py --source icub                 # subset
    PYTHONPATH=. python recordings/icub_grasp/convert.py --source icub --all --out DIR # 180

``--source`` holds ``iCubGraspDataset/<object>_<n>.txt`` and the author's ``README.txt``
(copied beside the dataset: its terms ask for the copyright to be kept intact). One file is one
grasp of the iCub hand: a first line ``-10000``, then 7 lines per time slice: the 9 hand joint
encoders (joints 7-15, degrees), per finger max(255 - taxel), and 12 capacitive taxels (raw
0-255, 255 = no contact) for each of the thumb, index, middle, ring and little fingertip.

The grasps are written as a ROS 2 bag (MCAP storage) as a lab's driver would have logged them,
one time slice every 100 ms (the source has no time stamps: a nominal 10 Hz, stated in the
README and the topic map): the encoders as a ``sensor_msgs/msg/JointState`` of 9 joints in
degrees, and each fingertip as an ``icub_grasp/msg/Fingertip`` (the 12 raw taxels and the
finger's summary value) on its own topic, grasps one after the other 5 s apart. The topic map
turns the fingertips into a skin of 5 cells (thumb, index, middle, ring, little) with a force
of 12 values per cell, ``255 - raw`` (a pressure-like count, not newtons), and the encoders
into radians. A CSV of windows gives every grasp one action ``G1`` (kind press: the contract's
kind that needs only force): contact at the grasp's first slice, execute for the grasp's last
0.7 s (7 slices, what the shortest grasp has), end after its last slice. Objects: the 9
objects of the dataset; ``full_coke`` (unreliable, its author says) and ``none`` (the hand
closing on nothing) are left out.
"""

# ruff: noqa: INP001 (a script beside the data it makes, not a package)

from __future__ import annotations

import argparse
import math
import shutil
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from recorder._cli import main as record

HERE = Path(__file__).parent
DATA = HERE / "data"
UPSTREAM = "https://github.com/clear-nus/icub_grasp_dataset"
COMMIT = "87dceec"
WHERE = (
    f"the dataset is in {UPSTREAM} (commit {COMMIT}; free use and distribution with the "
    "copyright kept intact, README.txt): clone it and give --source the clone"
)
FOLDER = "iCubGraspDataset"
AUTHOR_README = "README.txt"
#: The dataset's objects in the author's order (loadGraspData.m), without ``none`` and
#: ``full_coke``; names and default roles are in topic_map.toml.
OBJECTS = (
    "empty_vitamin_water",
    "med_vitamin_water",
    "full_vitamin_water",
    "empty_coke",
    "med_coke",
    "blue_bear",
    "monkey_toy",
    "book",
    "lotion",
)
TRIALS = 20  # grasps per object (files 1..20; the author's loader reads these)
SUBSET = 6  # grasps per object in the committed subset
#: iCub arm joints 7-15: the hand's encoders, in the order of the file.
JOINTS = (
    "hand_finger",
    "thumb_oppose",
    "thumb_proximal",
    "thumb_distal",
    "index_proximal",
    "index_distal",
    "middle_proximal",
    "middle_distal",
    "pinky",
)
FINGERS = ("thumb", "index", "middle", "ring", "little")
TAXELS = 12
LINES_PER_SLICE = 2 + len(FINGERS)
FIRST_LINE = "-10000"
MSGTYPE = "icub_grasp/msg/Fingertip"
MSGDEF = "std_msgs/Header header\nfloat32[12] taxels\nfloat32 max_response\n"
JOINT_TOPIC = "/icub/hand/joint_states"
FINGER_TOPIC = "/icub/hand/fingertip_{cell}"
NS = 1_000_000_000
PERIOD_NS = 100_000_000  # nominal 10 Hz: the source states no rate
GRASP_SPACING_NS = 5 * NS  # the longest grasp has 24 slices (2.4 s)
START_NS = 1_340_000_000 * NS  # 2012
DELAY_NS = 1_000_000  # each message reaches the bag 1 ms after its stamp
EXECUTE_SLICES = 7  # the shortest grasp of the 9 objects (med_coke) has 7 slices
ACTION = "G1"


@dataclass(frozen=True, slots=True)
class Grasp:
    """One grasp of the dataset.

    Attributes:
        object_id: The object (the file's prefix).
        trial: The grasp's number (the file's suffix, 1..20).
        encoders: Shape (slices, 9), degrees.
        summary: Shape (slices, 5): per finger max(255 - taxel) as the file states it.
        taxels: Shape (slices, 5, 12): raw capacitive values, 255 = no contact.
    """

    object_id: str
    trial: int
    encoders: np.ndarray[tuple[int, int], np.dtype[np.float32]]
    summary: np.ndarray[tuple[int, int], np.dtype[np.float32]]
    taxels: np.ndarray[tuple[int, int, int], np.dtype[np.float32]]


def _row(text: str, width: int, where: str) -> list[float]:
    """Return the ``width`` numbers of one line.

    Raises:
        SystemExit: Another count, or not numbers, in one line.
    """
    try:
        values = [float(item) for item in text.split()]
    except ValueError:
        values = []
    if len(values) != width or not all(math.isfinite(v) for v in values):
        msg = f"{where}: {text.strip()[:40]!r} is not {width} numbers; {WHERE}"
        raise SystemExit(msg)
    return values


def read_grasp(path: Path, object_id: str, trial: int) -> Grasp:
    """Read one grasp file (format in the author's README.txt).

    Raises:
        SystemExit: Unreadable or not in the dataset's format, in one line.
    """
    try:
        lines = [line for line in path.read_text("ascii").splitlines() if line.strip()]
    except (OSError, UnicodeDecodeError) as err:
        reason = getattr(err, "strerror", None) or str(err)
        msg = f"{path}: cannot read the grasp ({reason}); {WHERE}"
        raise SystemExit(msg) from err
    if not lines or lines[0].strip() != FIRST_LINE or (len(lines) - 1) % LINES_PER_SLICE:
        msg = f"{path}: not a grasp (a line {FIRST_LINE}, then 7 lines per slice); {WHERE}"
        raise SystemExit(msg)
    count = (len(lines) - 1) // LINES_PER_SLICE
    widths = (len(JOINTS), len(FINGERS), *([TAXELS] * len(FINGERS)))
    rows = [
        _row(lines[1 + k], widths[k % LINES_PER_SLICE], f"{path} slice {k // 7 + 1}")
        for k in range(count * LINES_PER_SLICE)
    ]
    encoders = np.array(rows[0::LINES_PER_SLICE], dtype=np.float32)
    summary = np.array(rows[1::LINES_PER_SLICE], dtype=np.float32)
    taxels = np.array(
        [rows[s * LINES_PER_SLICE + 2 : (s + 1) * LINES_PER_SLICE] for s in range(count)],
        dtype=np.float32,
    )
    return Grasp(object_id, trial, encoders, summary, taxels)


def load(source: Path, per_object: int | None) -> list[Grasp]:
    """Return the grasps: all 20 per object, or the first ``per_object``, objects in order.

    Raises:
        SystemExit: A grasp file is missing or malformed, in one line.
    """
    folder = source / FOLDER
    if not folder.is_dir():
        msg = f"{source}: no {FOLDER}/; {WHERE}"
        raise SystemExit(msg)
    trials = range(1, (per_object or TRIALS) + 1)
    return [
        read_grasp(folder / f"{obj}_{trial}.txt", obj, trial) for obj in OBJECTS for trial in trials
    ]


def write_bag(grasps: list[Grasp], bag: Path) -> list[str]:
    """Write the grasps as one ROS 2 bag; return the CSV rows of their windows.

    Raises:
        SystemExit: A grasp shorter than the execute phase, in one line.
    """
    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(MSGDEF, MSGTYPE))
    types = store.types
    header, stamp_type = types["std_msgs/msg/Header"], types["builtin_interfaces/msg/Time"]
    joint_state, fingertip = types["sensor_msgs/msg/JointState"], types[MSGTYPE]
    empty = np.zeros(0, dtype=np.float64)
    rows = []
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        joints = writer.add_connection(JOINT_TOPIC, joint_state.__msgtype__, typestore=store)
        fingers = [
            writer.add_connection(FINGER_TOPIC.format(cell=cell), MSGTYPE, typestore=store)
            for cell in range(len(FINGERS))
        ]
        for g, grasp in enumerate(grasps):
            slices = grasp.encoders.shape[0]
            if slices < EXECUTE_SLICES:
                msg = (
                    f"{grasp.object_id}_{grasp.trial}.txt: {slices} slices, fewer than the "
                    f"{EXECUTE_SLICES} of action {ACTION}'s execute phase; leave the object out"
                )
                raise SystemExit(msg)
            base = START_NS + g * GRASP_SPACING_NS
            for s in range(slices):
                stamp = base + s * PERIOD_NS
                time = stamp_type(sec=stamp // NS, nanosec=stamp % NS)
                message = joint_state(
                    header=header(stamp=time, frame_id=""),
                    name=list(JOINTS),
                    position=grasp.encoders[s].astype(np.float64),
                    velocity=empty,
                    effort=empty,
                )
                serialized = store.serialize_cdr(message, joint_state.__msgtype__)
                writer.write(joints, stamp + DELAY_NS, serialized)
                for cell, connection in enumerate(fingers):
                    tip = fingertip(
                        header=header(stamp=time, frame_id=FINGERS[cell]),
                        taxels=grasp.taxels[s, cell],
                        max_response=float(grasp.summary[s, cell]),
                    )
                    writer.write(connection, stamp + DELAY_NS, store.serialize_cdr(tip, MSGTYPE))
            execute = base + (slices - EXECUTE_SLICES) * PERIOD_NS
            contact = str(base) if slices > EXECUTE_SLICES else ""
            stop = execute + EXECUTE_SLICES * PERIOD_NS
            rows.append(f"{execute},{stop},{grasp.object_id},{ACTION},{grasp.trial},{contact}")
    return rows


def convert(source: Path, out: Path, per_object: int | None, work: Path) -> int:
    """Convert the selected grasps into a dataset at ``out``; return the import's status.

    Raises:
        SystemExit: The source is unusable, in one line.
    """
    grasps = load(source, per_object)
    bag = work / "icub_grasp"
    rows = write_bag(grasps, bag)
    windows = work / "windows.csv"
    text = "start,stop,object,action,trial,contact\n" + "\n".join(rows) + "\n"
    windows.write_text(text, "utf-8")
    argv = ["import-bag", str(bag), "--topic-map", str(HERE / "topic_map.toml")]
    return record([*argv, "--windows", str(windows), "--out", str(out)])


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and convert.

    Raises:
        SystemExit: No ``--source``, or an unusable one, in one line.
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--all", action="store_true", help=f"all {len(OBJECTS) * TRIALS} grasps (else 6/object)"
    )
    parser.add_argument(
        "--out", type=Path, default=None, help=f"dataset directory (default {DATA})"
    )
    parser.add_argument("--source", type=Path, default=None, help=f"a clone of {UPSTREAM}")
    args = parser.parse_args(argv)
    if args.source is None:
        msg = f"no --source: {WHERE}"
        raise SystemExit(msg)
    readme = args.source / AUTHOR_README
    if not readme.is_file():
        msg = f"{readme}: missing (its copyright goes with any copy of the data); {WHERE}"
        raise SystemExit(msg)
    per_object = None if args.all else SUBSET
    load(args.source, per_object)  # refuse a bad source before anything is removed
    out = args.out or DATA
    if args.out is None and out.exists():
        shutil.rmtree(out)  # the committed subset is regenerated whole
    with tempfile.TemporaryDirectory() as work:
        status = convert(args.source, out, per_object, Path(work))
    if status == 0:
        shutil.copyfile(readme, out / AUTHOR_README)
    return status


if __name__ == "__main__":
    sys.exit(main())
