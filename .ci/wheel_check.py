"""Build the wheel and sdist, install the wheel in a fresh virtualenv outside the checkout, use it.

What a lab gets from ``pip install atikt-*.whl`` must work without this checkout: the package
data (the contract, the message definitions, the catalogs, the example configurations) must be
in the wheel and be found there. Run from anywhere (CI: ``.ci/run``)::

    python3 .ci/wheel_check.py [--keep DIR]

Steps, each timed and printed: ``python -m build`` (wheel and sdist); the wheel's files; a
new virtualenv in a temporary directory with the wheel installed (its dependencies from the
package index); then, in that directory, with no ``PYTHONPATH`` and a user cache of its own
(``ATIKT_CACHE``, ``XDG_CACHE_HOME``): ``atikt-record serve-sim`` with the shipped UR and UDP
skin examples and a ``session`` against it (10x faster than real time), ``check`` and
``info --json`` of what it wrote; a ``session --rig sim-ur10`` (the simulated UR10 in
process, the shipped example configuration) and its ``check``; ``import-bag`` of a small
ROS 1 bag laid out as the shipped example topic map expects, with that map; and
``atikt-record dataset`` of a small simulated dataset with ``atikt-replay study transfer
--quick`` on it (on the whole default dataset the quick study took 294 s of CPU, 19 min on the
loaded 2-core machine: too long for every CI run).
Exit 1 on the first failure, with its output.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: Files the wheel must hold besides the modules (pyproject's package data).
PACKAGE_DATA = (
    "schemas/contract.toml",
    "schemas/msg/SkinForce.msg",
    "schemas/msg/ActionEvent.msg",
    "recorder/data/objects.toml",
    "recorder/data/actions.toml",
    "recorder/data/ur_rig.example.toml",
    "recorder/data/skin_udp.example.toml",
    "recorder/data/topic_map.example.toml",
    "recorder/_sim/CALIBRATION.md",
    "atikt/py.typed",
)
#: Seconds any one step may take before the check fails (a hang is a failure).
STEP_TIMEOUT_S = 1800
#: The study's dataset: 3 old and 3 new objects of the catalog, 2 actions, 4 trials each.
STUDY_OBJECTS = (
    "wood",
    "soft_sponge",
    "metal_toolbox",
    "pine_board",
    "foam_block",
    "aluminium_plate",
)
STUDY_ACTIONS = ("P1", "S2")
STUDY_TRIALS = 4
#: Writes a small ROS 1 session laid out as the example topic map expects.
LAB_BAG = Path(__file__).with_name("lab_bag.py")


class CheckError(Exception):
    """A step of the check failed; the message says which and what it printed."""


def _run(command: list[str], cwd: Path, env: dict[str, str] | None = None) -> str:
    """Run ``command``; return its stdout, or raise :class:`CheckError` with its output."""
    done = subprocess.run(  # noqa: S603 (the wheel's own commands and this interpreter)
        command,
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=STEP_TIMEOUT_S,
        check=False,
    )
    if done.returncode != 0:
        msg = f"{' '.join(command)} exited {done.returncode}:\n{done.stdout}\n{done.stderr}"
        raise CheckError(msg)
    return done.stdout


def _step(title: str, started: float) -> float:
    """Print a finished step with its seconds; return the time now."""
    now = time.monotonic()
    print(f"  {title}: {now - started:.1f} s", flush=True)
    return now


def build(work: Path) -> Path:
    """Build the wheel and the sdist into ``work/dist``; return the wheel."""
    dist = work / "dist"
    _run([sys.executable, "-m", "build", "--outdir", str(dist), str(ROOT)], cwd=work)
    wheels, sdists = sorted(dist.glob("*.whl")), sorted(dist.glob("*.tar.gz"))
    if len(wheels) != 1 or len(sdists) != 1:
        msg = f"{dist}: expected one wheel and one sdist, found {[p.name for p in dist.iterdir()]}"
        raise CheckError(msg)
    names = set(zipfile.ZipFile(wheels[0]).namelist())
    if missing := [name for name in PACKAGE_DATA if name not in names]:
        msg = f"{wheels[0].name} lacks package data: {', '.join(missing)} (pyproject.toml)"
        raise CheckError(msg)
    return wheels[0]


def install(work: Path, wheel: Path) -> Path:
    """Create a virtualenv in ``work/venv`` with the wheel installed; return its bin directory."""
    venv = work / "venv"
    _run([sys.executable, "-m", "venv", str(venv)], cwd=work)
    python = venv / "bin" / "python"
    _run([str(python), "-m", "pip", "install", "--quiet", str(wheel)], cwd=work)
    return venv / "bin"


def environment(work: Path) -> dict[str, str]:
    """The commands' environment: no checkout on the path, a user cache of their own."""
    env = {k: v for k, v in os.environ.items() if k not in {"PYTHONPATH", "VIRTUAL_ENV"}}
    return env | {
        "ATIKT_CACHE": str(work / "cache"),
        "XDG_CACHE_HOME": str(work / "xdg-cache"),
        "MPLBACKEND": "Agg",
    }


def _port(kind: socket.SocketKind) -> int:
    """Return a free port on 127.0.0.1 (of a TCP or UDP socket)."""
    with socket.socket(socket.AF_INET, kind) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def _lab(bin_dir: Path, run: Path, ports: tuple[int, int, int]) -> Path:
    """Write the shipped UR example with the shipped UDP skin, on ``ports``, 10x faster."""
    code = (
        "import importlib.resources as r; d = r.files('recorder') / 'data';"
        "print(str(d / 'ur_rig.example.toml')); print(str(d / 'skin_udp.example.toml'))"
    )
    ur_path, skin_path = _run([str(bin_dir / "python"), "-c", code], cwd=run).split()
    if str(ROOT) in ur_path:
        msg = f"the virtualenv reads the package data of the checkout ({ur_path})"
        raise CheckError(msg)
    rtde, script, udp = ports
    text = Path(ur_path).read_text("utf-8")
    text = text.replace("rtde_port = 30004", f"rtde_port = {rtde}")
    text = text.replace("script_port = 30001", f"script_port = {script}")
    text = text.replace("# time_scale = 0.1", "time_scale = 0.1")
    skin = Path(skin_path).read_text("utf-8")
    skin = skin.replace('bind = "127.0.0.1:5005"', f'bind = "127.0.0.1:{udp}"')
    text = text[: text.index("\n[skin]\n") + 1] + skin[skin.index("\n[skin]\n") + 1 :]
    lab = run / "lab.toml"
    lab.write_text(text, "utf-8")
    return lab


def session(bin_dir: Path, run: Path, env: dict[str, str]) -> None:
    """Record one action with ``session`` against ``serve-sim``; check and inspect the file."""
    ports = (_port(socket.SOCK_STREAM), _port(socket.SOCK_STREAM), _port(socket.SOCK_DGRAM))
    lab = _lab(bin_dir, run, ports)
    serve = [str(bin_dir / "atikt-record"), "serve-sim", "--rig-config", str(lab)]
    serve += ["--rtde-port", str(ports[0]), "--script-port", str(ports[1])]
    serve += ["--skin", f"udp://127.0.0.1:{ports[2]}", "--time-scale", "0.1"]
    lab_process = subprocess.Popen(  # noqa: S603 (the wheel's command)
        serve, cwd=run, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        first = lab_process.stdout.readline() if lab_process.stdout is not None else ""
        if "listening" not in first:
            msg = f"serve-sim did not start: {first}{lab_process.communicate(timeout=10)}"
            raise CheckError(msg)
        record = [str(bin_dir / "atikt-record"), "session", "--rig-config", str(lab)]
        record += ["--objects", "wood", "--actions", "P1", "--trials", "1"]
        record += ["--out", "lab", "--yes"]
        _run(record, cwd=run, env=env)
    finally:
        lab_process.send_signal(signal.SIGINT)
        try:
            lab_process.communicate(timeout=20)
        except subprocess.TimeoutExpired:
            lab_process.kill()
            lab_process.communicate()
    recording = run / "lab" / "wood" / "P1" / "001.mcap"
    _run([str(bin_dir / "atikt-replay"), "check", "lab", "--workers", "1"], cwd=run, env=env)
    info = json.loads(
        _run([str(bin_dir / "atikt-replay"), "info", "--json", str(recording)], cwd=run, env=env)
    )
    if info["metadata"]["rig"].get("kind") != "ur" or not info["sources"]:
        msg = f"{recording}: not a UR session with live sources: {info['metadata']['rig']}"
        raise CheckError(msg)


def rehearsal(bin_dir: Path, run: Path, env: dict[str, str]) -> None:
    """Record one action on the simulated UR10 in process (the shipped example configuration)."""
    record = [str(bin_dir / "atikt-record"), "session", "--rig", "sim-ur10", "--rig-option"]
    record += ["time_scale=0.2", "--objects", "wood", "--actions", "P1", "--trials", "1"]
    record += ["--out", "rehearsal", "--yes"]
    _run(record, cwd=run, env=env)
    _run([str(bin_dir / "atikt-replay"), "check", "rehearsal", "--workers", "1"], cwd=run, env=env)


def import_bag(bin_dir: Path, run: Path, env: dict[str, str]) -> None:
    """Import a small lab bag with the shipped example topic map; check the result."""
    _run([str(bin_dir / "python"), str(LAB_BAG), "session.bag"], cwd=run, env=env)
    code = "import importlib.resources as r; print(r.files('recorder') / 'data')"
    data = Path(_run([str(bin_dir / "python"), "-c", code], cwd=run, env=env).strip())
    command = [str(bin_dir / "atikt-record"), "import-bag", "session.bag"]
    command += ["--topic-map", str(data / "topic_map.example.toml"), "--out", "imported"]
    _run(command, cwd=run, env=env)
    _run([str(bin_dir / "atikt-replay"), "check", "imported", "--workers", "1"], cwd=run, env=env)
    if not (run / "imported" / "wood" / "P1" / "001.mcap").is_file():
        msg = f"import-bag wrote no imported/wood/P1/001.mcap: {sorted(run.rglob('*.mcap'))}"
        raise CheckError(msg)


def study(bin_dir: Path, run: Path, env: dict[str, str]) -> None:
    """Record a small simulated dataset with ``dataset``, run ``study transfer --quick`` on it.

    README's main job records the whole default dataset (1,950 recordings, about 300 s of CPU)
    before its study; the same commands on :data:`STUDY_OBJECTS` x :data:`STUDY_ACTIONS` x
    :data:`STUDY_TRIALS` go through the same code in a few seconds.
    """
    record = [str(bin_dir / "atikt-record"), "dataset", "--out", "sim", "--workers", "1"]
    record += ["--objects", ",".join(STUDY_OBJECTS), "--actions", ",".join(STUDY_ACTIONS)]
    record += ["--trials", str(STUDY_TRIALS)]
    _run(record, cwd=run, env=env)
    command = [str(bin_dir / "atikt-replay"), "study", "transfer", "--quick", "--recordings"]
    command += ["sim", "--out", "study", "--workers", "1"]
    _run(command, cwd=run, env=env)
    if not (run / "study" / "results.parquet").is_file():
        msg = "study transfer --quick wrote no study/results.parquet"
        raise CheckError(msg)


def check(work: Path) -> None:
    """Run every step in ``work``, printing the seconds of each."""
    started = total = time.monotonic()
    wheel = build(work)
    started = _step(f"python -m build -> {wheel.name} and its sdist", started)
    bin_dir = install(work, wheel)
    started = _step("fresh virtualenv, wheel installed", started)
    run = work / "run"
    run.mkdir()
    env = environment(work)
    session(bin_dir, run, env)
    started = _step("serve-sim + session (1 action), check, info --json", started)
    rehearsal(bin_dir, run, env)
    started = _step("session --rig sim-ur10 (1 action, in process), check", started)
    import_bag(bin_dir, run, env)
    started = _step("import-bag with the example topic map, check", started)
    study(bin_dir, run, env)
    started = _step("dataset (48 recordings) + study transfer --quick on it", started)
    print(f"wheel check passed in {time.monotonic() - total:.1f} s", flush=True)


def main() -> int:
    """Run the check in a temporary directory (or ``--keep DIR``); return the exit status."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--keep", type=Path, help="work in this new directory and keep it")
    args = parser.parse_args()
    work = args.keep or Path(tempfile.mkdtemp(prefix="atikt-wheel-"))
    work.mkdir(parents=True, exist_ok=args.keep is None)
    print(f"wheel check in {work}", flush=True)
    try:
        check(work.resolve())
    except (CheckError, subprocess.TimeoutExpired) as err:
        print(f"wheel check FAILED: {err}", file=sys.stderr)
        return 1
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
