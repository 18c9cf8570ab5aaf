"""Bring the real heated-probe study (thermal-ambiguity-ToH) in through ``import-bag``.

Run from the repository root, with a clone of the study's repository::

    git clone https://github.com/Healthcare-Robotics/thermal-ambiguity-ToH toh
    git -C toh checkout 70dbe35
    PYTHONPATH=. python recordings/thermal_probe/convert.py --source toh  # committed subset
    PYTHONPATH=. python recordings/thermal_probe/convert.py --source toh --all --out DIR
    PYTHONPATH=. python recordings/thermal_probe/convert.py --source toh --all --runs 1-10 --out DIR

``--runs A-B`` keeps the robot study's runs A..B (1..30; each run touches every material 3
times): two sessions of one rig, e.g. runs 1-10 to save a fusion study's hyperparameters and
runs 11-30 to study with them as a prior.

``--source`` is a checkout of the study's repository (MIT licence): its 270
``robot_study/test/R_<run>/<material>_count_<k>_sensor_29.5.pkl`` files (Python 2 pickles of
one float64 array of 1601 x 5: time in s, passive thermistor in C, heated thermistor in C, a
third thermistor, force in N; 200 Hz) are read without running code from them and become the
study's arrays (values as float32, files in path order). A directory holding those arrays as
``robot_study.npz`` (t_s, force_n, heated_c, passive_c, material, run, count, source_file)
works too. The arrays are written as a ROS 2 bag (MCAP storage) as a lab's driver would have
logged them: one probe message per 5 ms sample (``thermal_probe/msg/ProbeSample``: the
contact force in N and the heated and passive thermistors in C), trials one after the other
10 s apart. A CSV of windows (integer ns) marks each trial's execute phase from the force onset
(the first sample above 1 N) for the 5 s hold of action ``H5`` (kind static); the material is
the object (``W`` wood, ``M`` aluminium, ``CW`` cooled wood). Then ``atikt-record import-bag``
turns bag, map (``topic_map.toml`` beside this script) and windows into a dataset. Trials
whose hold is shorter than 5 s within the recorded 7 s are left out and listed.
"""

# ruff: noqa: INP001 (a script beside the data it makes, not a package)

from __future__ import annotations

import argparse
import pickle
import re
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
UPSTREAM = "https://github.com/Healthcare-Robotics/thermal-ambiguity-ToH"
COMMIT = "70dbe35"
WHERE = (
    f"the study's files are in {UPSTREAM} at commit {COMMIT} (MIT licence): clone it, "
    f"git checkout {COMMIT}, and give --source the clone"
)
STUDY = "robot_study/test"
PICKLE = re.compile(
    r"R_(?P<run>[0-9]+)/(?P<material>[A-Z]+)_count_(?P<count>[0-9]+)_sensor_29\.5\.pkl"
)
#: Columns of a study pickle (1dof_fixed.py saves [t, T0, T1, T3, F]; T0 is the passive
#: thermistor, T1 the heated one held at 29.5 C, T3 is not used by the study).
TIME, PASSIVE, HEATED, FORCE = 0, 1, 2, 4
COLUMNS = 5
#: The only globals a study pickle may name: numpy's array reconstruction (nothing that runs
#: other code). Anything else is refused instead of imported.
ALLOWED = frozenset(
    {("numpy.core.multiarray", "_reconstruct"), ("numpy", "ndarray"), ("numpy", "dtype")}
)
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


class _ArrayUnpickler(pickle.Unpickler):
    """An unpickler that rebuilds numpy arrays and nothing else.

    Unpickling can run any code a file names; the study's files are data from a public
    repository, so only the three globals an ndarray pickle needs are resolved.
    """

    def find_class(self, module: str, name: str, /) -> Any:  # noqa: ANN401 (pickle's signature)
        """Return an allowed global, refuse every other one.

        Raises:
            pickle.UnpicklingError: The file names a global outside :data:`ALLOWED`.
        """
        if (module, name) not in ALLOWED:
            msg = f"global {module}.{name} is not a numpy array's"
            raise pickle.UnpicklingError(msg)
        return super().find_class(module, name)


def read_pickle(path: Path) -> NDArray[np.float64]:
    """Return the array of one study pickle (Python 2, protocol 0), read safely.

    Raises:
        SystemExit: Unreadable, not an array pickle, or not samples x 5 floats, in one line.
    """
    try:
        with path.open("rb") as handle:
            # latin1: Python 2 pickles hold an array's bytes as a str (numpy's own advice)
            array = _ArrayUnpickler(handle, encoding="latin1").load()
    except (OSError, pickle.UnpicklingError, EOFError, ValueError) as err:
        reason = getattr(err, "strerror", None) or " ".join(str(err).split())
        msg = f"{path}: cannot read the trial ({reason}); {WHERE}"
        raise SystemExit(msg) from err
    if not (
        isinstance(array, np.ndarray)
        and array.ndim == 2  # noqa: PLR2004
        and array.shape[1] == COLUMNS
        and array.dtype == np.float64
    ):
        shape = getattr(array, "shape", type(array).__name__)
        msg = f"{path}: holds {shape}, not samples x {COLUMNS} float64; {WHERE}"
        raise SystemExit(msg)
    return array


def _trial_files(source: Path) -> list[tuple[str, re.Match[str]]]:
    """Return (path relative to ``source``, name match) of every study pickle, in path order."""
    files = []
    for path in (source / STUDY).glob("R_*/*.pkl"):
        relative = path.relative_to(source).as_posix()
        if match := PICKLE.search(relative):
            files.append((relative, match))
    return sorted(files, key=lambda item: item[0])


def load_pickles(source: Path) -> dict[str, Any]:
    """Return the study's arrays from a checkout of its repository (``robot_study.npz``'s).

    Raises:
        SystemExit: No trial files, a file that is not a trial, or trials on different
            time axes, in one line.
    """
    files = _trial_files(source)
    if not files:
        msg = f"{source / STUDY}: no R_<run>/<material>_count_<k>_sensor_29.5.pkl; {WHERE}"
        raise SystemExit(msg)
    arrays = [read_pickle(source / relative) for relative, _ in files]
    t_s = arrays[0][:, TIME]
    for (relative, _), array in zip(files, arrays, strict=True):
        if not np.array_equal(array[:, TIME], t_s):
            msg = f"{source / relative}: its time axis differs from {files[0][0]}'s; {WHERE}"
            raise SystemExit(msg)
    stacked = np.stack(arrays)
    return {
        "t_s": t_s,
        "force_n": stacked[:, :, FORCE].astype(np.float32),
        "heated_c": stacked[:, :, HEATED].astype(np.float32),
        "passive_c": stacked[:, :, PASSIVE].astype(np.float32),
        "material": np.array([match["material"] for _, match in files]),
        "run": np.array([int(match["run"]) for _, match in files]),
        "count": np.array([int(match["count"]) for _, match in files]),
        "source_file": np.array([relative for relative, _ in files]),
    }


def _load(source: Path) -> dict[str, Any]:
    """Return the study's arrays: from a checkout's pickles, or a ``robot_study.npz``.

    Raises:
        SystemExit: The files are missing, unreadable or lack an array, in one line.
    """
    if (source / STUDY).is_dir():
        data = load_pickles(source)
        _check_materials(data, source / STUDY)
        return data
    path = source / "robot_study.npz"
    if not path.exists():
        msg = f"{source}: holds neither {STUDY}/ (a checkout) nor robot_study.npz; {WHERE}"
        raise SystemExit(msg)
    try:
        with np.load(path, allow_pickle=False) as npz:
            data = {key: npz[key] for key in npz.files}
    except (OSError, ValueError) as err:
        reason = getattr(err, "strerror", None) or " ".join(str(err).split())
        msg = f"{path}: cannot read the study ({reason}); {WHERE}"
        raise SystemExit(msg) from err
    wanted = {"material", "run", "t_s", "force_n", "heated_c", "passive_c", "source_file"}
    missing = sorted(wanted - data.keys())
    if missing:
        msg = f"{path}: no array {', '.join(missing)}; {WHERE}"
        raise SystemExit(msg)
    _check_materials(data, path)
    return data


def _check_materials(data: dict[str, Any], path: Path) -> None:
    """Refuse material codes that are not the study's.

    Raises:
        SystemExit: An unknown code, in one line.
    """
    unknown = sorted({str(code) for code in data["material"].tolist()} - OBJECTS.keys())
    if unknown:
        msg = (
            f"{path}: material codes {', '.join(unknown)} are not the study's "
            f"({', '.join(OBJECTS)}); {WHERE}"
        )
        raise SystemExit(msg)


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
    """Convert the selected trials into a dataset at ``out``; return the import's status.

    Raises:
        SystemExit: The source is unusable or no trial is selected, in one line.
    """
    return _convert(source, _load(source), out, per_material, work, runs=runs)


def _convert(
    source: Path,
    data: dict[str, Any],
    out: Path,
    per_material: int | None,
    work: Path,
    *,
    runs: range | None,
) -> int:
    """Convert the selected trials of ``data`` (read from ``source``); see :func:`convert`."""
    trials = _select(data["material"], per_material, data["run"], runs)
    if not trials:
        found = sorted({int(run) for run in data["run"].tolist()})
        msg = (
            f"{source}: no trial in runs {runs.start}-{runs.stop - 1}"
            f" (the study has runs {found[0]}-{found[-1]}); give --runs within them"
            if runs is not None and found
            else f"{source}: no trials to convert"
        )
        raise SystemExit(msg)
    bag = work / "thermal_probe"
    rows = write_bag(data, trials, bag)
    windows = work / "windows.csv"
    windows.write_text("start,stop,object,action,trial\n" + "\n".join(rows) + "\n", "utf-8")
    argv = ["import-bag", str(bag), "--topic-map", str(HERE / "topic_map.toml")]
    return record([*argv, "--windows", str(windows), "--out", str(out)])


def _licence(source: Path) -> Path:
    """Return the study's licence file in ``source`` (a checkout's or a copy's).

    Raises:
        SystemExit: There is none, in one line.
    """
    for name in ("License.txt", "LICENSE"):
        if (source / name).is_file():
            return source / name
    msg = f"{source}: no License.txt (the study's MIT licence goes with its data); {WHERE}"
    raise SystemExit(msg)


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


def main(argv: list[str] | None = None) -> int:
    """Parse the command line and convert.

    Raises:
        SystemExit: No ``--source``, or an unusable one, in one line.
    """
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--all", action="store_true", help="all 270 trials (else 10 per material)")
    parser.add_argument(
        "--out", type=Path, default=None, help=f"dataset directory (default {DATA})"
    )
    parser.add_argument(
        "--source", type=Path, default=None, help=f"a checkout of {UPSTREAM} at {COMMIT}"
    )
    parser.add_argument(
        "--runs", type=_runs, default=None, help="only the study's runs A-B (1..30), e.g. 1-10"
    )
    args = parser.parse_args(argv)
    if args.source is None:
        msg = f"no --source: {WHERE}"
        raise SystemExit(msg)
    data, licence = _load(args.source), _licence(args.source)  # before anything is removed
    out = args.out or DATA
    if args.out is None and out.exists():
        shutil.rmtree(out)  # the committed subset is regenerated whole
    with tempfile.TemporaryDirectory() as work:
        per_material = None if args.all else SUBSET
        status = _convert(args.source, data, out, per_material, Path(work), runs=args.runs)
    if status == 0:
        shutil.copyfile(licence, out / "LICENSE")
    return status


if __name__ == "__main__":
    sys.exit(main())
