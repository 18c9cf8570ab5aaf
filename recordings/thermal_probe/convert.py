"""Bring the real heated-probe study (thermal-ambiguity-ToH) in through ``import-bag``.

Run from the repository root::

    PYTHONPATH=. python recordings/thermal_probe/convert.py                  # committed subset
    PYTHONPATH=. python recordings/thermal_probe/convert.py --all --out DIR  # all 270 trials
    PYTHONPATH=. python recordings/thermal_probe/convert.py --all --runs 1-10 --out DIR

``--runs A-B`` keeps the robot study's runs A..B (1..30; each run touches every material 3
times): two sessions of one rig, e.g. runs 1-10 to save a fusion study's hyperparameters and
runs 11-30 to study with them as a prior.

The study's ``robot_study.npz`` (see ``/work/shared/data/thermal-ambiguity-toh/README.md``) is
written as a ROS 2 bag (MCAP storage) as a lab's driver would have logged it: one probe
message per 5 ms sample (``thermal_probe/msg/ProbeSample``: the contact force in N and the
heated and passive thermistors in C), trials one after the other 10 s apart. A CSV of windows
(integer ns) marks each trial's execute phase from the force onset (the first sample above
1 N) for the 5 s hold of action ``H5`` (kind static); the material is the object (``W`` wood,
``M`` aluminium, ``CW`` cooled wood). Then ``atikt-record import-bag`` turns bag, map
(``topic_map.toml`` beside this script) and windows into a dataset. Trials whose hold is
shorter than 5 s within the recorded 7 s are left out and listed.
"""

# ruff: noqa: INP001 (a script beside the data it makes, not a package)

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from recorder._cli import main as record

if TYPE_CHECKING:
    from numpy.typing import NDArray

HERE = Path(__file__).parent
SOURCE = Path("/work/shared/data/thermal-ambiguity-toh")
DATA = HERE / "data"
MSGTYPE = "thermal_probe/msg/ProbeSample"
MSGDEF = "std_msgs/Header header\nfloat32 force_n\nfloat32[2] temperature_c\n"
TOPIC = "/probe/sample"
NS = 1_000_000_000
PERIOD_NS = 5_000_000  # 200 Hz
TRIAL_SPACING_NS = 10 * NS  # 8 s of samples, 2 s apart
START_NS = 1_600_000_000 * NS
HOLD_NS = 5 * NS
ONSET_N = 1.0
OBJECTS = {"W": "wood", "M": "aluminium", "CW": "cold_wood"}
SUBSET = 10  # trials per material in the committed subset


def _load(source: Path) -> dict[str, Any]:
    """Return the study's arrays.

    Raises:
        SystemExit: The file is missing, unreadable or lacks an array, in one line.
    """
    path = source / "robot_study.npz"
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {key: npz[key] for key in npz.files}
    except (OSError, ValueError) as err:
        reason = getattr(err, "strerror", None) or " ".join(str(err).split())
        msg = f"{path}: cannot read the study ({reason}); give --source the study's directory"
        raise SystemExit(msg) from err
    wanted = {"material", "run", "t_s", "force_n", "heated_c", "passive_c", "source_file"}
    missing = sorted(wanted - data.keys())
    if missing:
        msg = f"{path}: no array {', '.join(missing)}; give --source the study's directory"
        raise SystemExit(msg)
    unknown = sorted({str(code) for code in data["material"].tolist()} - OBJECTS.keys())
    if unknown:
        msg = (
            f"{path}: material codes {', '.join(unknown)} are not the study's "
            f"({', '.join(OBJECTS)}); give --source the study's directory"
        )
        raise SystemExit(msg)
    return data


def _select(
    material: NDArray[np.str_],
    per_material: int | None,
    run: NDArray[np.integer[Any]] | None = None,
    runs: range | None = None,
) -> list[int]:
    """Return trial indices: all, or the first ``per_material`` of each material (file order).

    With ``runs``, only the trials of those robot-study runs.
    """
    chosen = []
    counts = dict.fromkeys(OBJECTS, 0)
    for index, code in enumerate(material.tolist()):
        if runs is not None and run is not None and int(run[index]) not in runs:
            continue
        if per_material is None or counts[code] < per_material:
            chosen.append(index)
            counts[code] += 1
    return chosen


def _onset(force: NDArray[np.float32]) -> int | None:
    """Return the index of the first sample above 1 N, or None."""
    above = np.flatnonzero(force > ONSET_N)
    return int(above[0]) if above.size else None


def write_bag(data: dict[str, Any], trials: list[int], bag: Path) -> list[str]:
    """Write the trials as one ROS 2 bag; return the CSV rows of their windows."""
    store = get_typestore(Stores.ROS2_HUMBLE)
    store.register(get_types_from_msg(MSGDEF, MSGTYPE))
    types = store.types
    count = data["t_s"].size
    rows, trial_of = [], dict.fromkeys(OBJECTS.values(), 0)
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connection = writer.add_connection(TOPIC, MSGTYPE, typestore=store)
        for k, index in enumerate(trials):
            base = START_NS + k * TRIAL_SPACING_NS
            force, heated = data["force_n"][index], data["heated_c"][index]
            passive = data["passive_c"][index]
            for i in range(count):
                stamp = base + i * PERIOD_NS
                time = types["builtin_interfaces/msg/Time"](sec=stamp // NS, nanosec=stamp % NS)
                message = types[MSGTYPE](
                    header=types["std_msgs/msg/Header"](stamp=time, frame_id="probe"),
                    force_n=float(force[i]),
                    temperature_c=np.array([heated[i], passive[i]], dtype=np.float32),
                )
                writer.write(connection, stamp + 1_000_000, store.serialize_cdr(message, MSGTYPE))
            onset = _onset(force)
            obj = OBJECTS[str(data["material"][index])]
            if onset is None or (count - onset) * PERIOD_NS < HOLD_NS:
                print(f"left out {data['source_file'][index]}: no 5 s hold after a 1 N onset")  # noqa: T201
                continue
            trial_of[obj] += 1
            start = base + onset * PERIOD_NS
            rows.append(f"{start},{start + HOLD_NS},{obj},H5,{trial_of[obj]}")
    return rows


def convert(
    source: Path, out: Path, per_material: int | None, work: Path, runs: range | None = None
) -> int:
    """Convert the selected trials into a dataset at ``out``; return the import's status."""
    data = _load(source)
    trials = _select(data["material"], per_material, data["run"], runs)
    if not trials:
        found = sorted({int(run) for run in data["run"].tolist()})
        msg = (
            f"{source / 'robot_study.npz'}: no trial in runs {runs.start}-{runs.stop - 1}"
            f" (the study has runs {found[0]}-{found[-1]}); give --runs within them"
            if runs is not None and found
            else f"{source / 'robot_study.npz'}: no trials to convert"
        )
        raise SystemExit(msg)
    bag = work / "thermal_probe"
    rows = write_bag(data, trials, bag)
    windows = work / "windows.csv"
    windows.write_text("start,stop,object,action,trial\n" + "\n".join(rows) + "\n", "utf-8")
    argv = ["import-bag", str(bag), "--topic-map", str(HERE / "topic_map.toml")]
    return record([*argv, "--windows", str(windows), "--out", str(out)])


def _runs(text: str) -> range:
    """Parse ``A-B`` (or ``A``) into the runs A..B."""
    first, _, last = text.partition("-")
    try:
        runs = range(int(first), int(last or first) + 1)
    except ValueError:
        runs = range(0)
    if not runs:
        msg = f"--runs {text!r}: give the first and last run, e.g. 1-10"
        raise argparse.ArgumentTypeError(msg)
    return runs


def main() -> int:
    """Parse the command line and convert."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--all", action="store_true", help="all 270 trials (else 10 per material)")
    parser.add_argument(
        "--out", type=Path, default=None, help=f"dataset directory (default {DATA})"
    )
    parser.add_argument("--source", type=Path, default=SOURCE, help="the study's directory")
    parser.add_argument(
        "--runs", type=_runs, default=None, help="only the study's runs A-B (1..30), e.g. 1-10"
    )
    args = parser.parse_args()
    out = args.out or DATA
    if args.out is None and out.exists():
        shutil.rmtree(out)  # the committed subset is regenerated whole
    with tempfile.TemporaryDirectory() as work:
        per_material = None if args.all else SUBSET
        status = convert(args.source, out, per_material, Path(work), args.runs)
    if status == 0 and args.out is None:
        shutil.copy(args.source / "LICENSE", out / "LICENSE")
    return status


if __name__ == "__main__":
    sys.exit(main())
