"""How fast the arm gets its stop: from each cause to the ``stopl`` at the controller.

The virtual lab (``atikt-record serve-sim`` in its own process, as a controller is) executes
the URScript it receives and writes what happened with both clocks (``--events``); the UR rig
of this process records actions against it and meets one cause per action:

* ``limit``: the TCP leaves the ``[limits]`` workspace during the approach (the cause: the
  first state sample outside, as it arrived);
* ``protective``: a protective stop injected by the lab after the action began (the cause: the
  lab's stop);
* ``silence``: the RTDE stream stalls (the cause: the moment it had been silent ``silence_s``);
* ``drop``: the lab closes the URScript connection during the action (the cause: the lab's
  drop; the stop goes over a new connection);
* ``gone``: the lab closes its URScript port during the action (the cause: the lab's fault; no
  new connection is taken, the stop goes to the dashboard server, its arrival is the lab's
  ``halt``);
* ``replaced``: another client sends a program during the action (the cause: its arrival at
  the lab; the controller's key message names it, and the stop replaces it);
* ``sigint`` / ``sigterm``: Ctrl-C or SIGTERM sent to this process during the action;
* ``write``: the file writer fails (a full disk) during the action;
* ``error``: the skin raises an unexpected error during the action.

Every cause comes during the approach, while the arm moves. For each: the time from the cause
to the arrival of the stop program at the controller, in controller cycles and ms (p99 and
median over the runs), and the median time from that arrival to the arm's measured TCP speed
at zero (``zero ms``; empty when the arm was at rest before the stop arrived: a protective
stop halts it itself), printed as a table; below it, the bound the deceleration gives (the
approach's top speed over the acceleration, in real time at the lab's time scale, plus a
cycle).

    python tests/bench/bench_stop_latency.py --runs 20            # 125 and 500 Hz
    python tests/bench/bench_stop_latency.py --quick              # one run of three causes
    python tests/bench/bench_stop_latency.py --runs 20 --causes sigint,sigterm --frequencies 125

A run that yields no figure is counted as missed, with one line on stderr saying why (the lab
too loaded to present the object, no stop recorded, or no stop program in the lab's log).
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import tomllib
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
sys.path.append(str(ROOT / "tests"))  # the tests' helpers (ports), after the packages

from ports import free_port  # noqa: E402

from recorder import RecorderError, load_actions, load_objects, record_action  # noqa: E402
from recorder._rigconfig import load_rig_config  # noqa: E402
from recorder.ur import build_ur_rig  # noqa: E402
from recorder.writing._writer import RecordingWriter  # noqa: E402

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from recorder.live import RecorderClock


CAUSES = (
    "limit",
    "protective",
    "silence",
    "drop",
    "gone",
    "replaced",
    "sigint",
    "sigterm",
    "write",
    "error",
)
SCALE = 0.2
#: When a cause happens, s after the action is asked for (this process's causes) and after the
#: lab saw the action begin (the lab's faults): during the approach, which lasts about 1 s at
#: this time scale, while the arm moves, so the time to its speed at zero is measured too.
CAUSE_S, LAB_CAUSE_S = 0.6, 0.4
OBJECT, ACTION = load_objects()["wood"], load_actions()["C1"]
POSE_Z = 0.15  # the example configuration's pose of wood


#: ``--rt-priority`` and ``--lab-rt-priority`` (0: normal scheduling).
PRIORITY = {"recorder": 0, "lab": 0}


def _lab_files(tmp: Path, frequency: int, cause: str) -> tuple[Path, list[str], Path]:
    """Return the rig configuration, the serve-sim command and its events file."""
    rtde, script = free_port(socket.SOCK_STREAM), free_port(socket.SOCK_STREAM)
    udp, dashboard = free_port(socket.SOCK_DGRAM), free_port(socket.SOCK_STREAM)
    text = (ROOT / "recorder/data/ur_rig.example.toml").read_text("utf-8")
    text = text.replace("rtde_port = 30004", f"rtde_port = {rtde}")
    text = text.replace("script_port = 30001", f"script_port = {script}")
    text = text.replace("dashboard_port = 29999", f"dashboard_port = {dashboard}")
    text = text.replace("frequency = 125", f"frequency = {frequency}")
    text = text.replace("# time_scale = 0.1", f"time_scale = {SCALE}")
    text = text.replace("contact_force_n = 0.05", "contact_force_n = 0.15")
    text = text.replace("silence_s = 0.5", "silence_s = 1.0")  # a loaded machine's lab
    if PRIORITY["recorder"]:
        text = text.replace(
            "silence_s = 1.0", f"silence_s = 1.0\nrt_priority = {PRIORITY['recorder']}"
        )
    if cause == "limit":  # 3 mm into the approach the TCP leaves the box
        text = text.replace(
            "workspace_min_m = [-0.9, -0.5, 0.0]",
            f"workspace_min_m = [-0.9, -0.5, {POSE_Z - 0.003}]",
        )
    skin = (ROOT / "recorder/data/skin_udp.example.toml").read_text("utf-8")
    skin = skin.replace('bind = "127.0.0.1:5005"', f'bind = "127.0.0.1:{udp}"')
    text = text[: text.index("\n[skin]\n") + 1] + skin[skin.index("\n[skin]\n") + 1 :]
    lab = tmp / "lab.toml"
    lab.write_text(text, "utf-8")
    events = tmp / "events.jsonl"
    command = [sys.executable, "-m", "recorder", "serve-sim", "--time-scale", str(SCALE)]
    if PRIORITY["lab"]:  # a controller is a real-time system: the virtual one too
        command = ["chrt", "--fifo", str(PRIORITY["lab"]), *command]
    command += [
        "--frequency",
        str(frequency),
        "--rtde-port",
        str(rtde),
        "--script-port",
        str(script),
        "--dashboard-port",
        str(dashboard),
    ]
    command += [
        "--rig-config",
        str(lab),
        "--skin",
        f"udp://127.0.0.1:{udp}",
        "--events",
        str(events),
    ]
    if cause == "protective":
        command += ["--fault", f"script.protective_stop={LAB_CAUSE_S}"]
    if cause == "silence":
        command += ["--fault", "rtde.stall=3", "--fault", f"rtde.at_action={LAB_CAUSE_S}"]
    if cause == "drop":
        command += ["--fault", f"script.drop={LAB_CAUSE_S}"]
    if cause == "gone":
        command += ["--fault", f"script.gone={LAB_CAUSE_S}"]
    return lab, command, events


@contextlib.contextmanager
def _serving(command: list[str]) -> Iterator[None]:
    env = os.environ | {"PYTHONPATH": str(ROOT)}
    lab = subprocess.Popen(  # noqa: S603 (this project's command)
        command, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    try:
        assert lab.stdout is not None
        line = lab.stdout.readline()
        if not line.startswith("virtual lab listening"):
            raise RuntimeError(line + (lab.stderr.read() if lab.stderr else ""))
        yield
    finally:
        lab.send_signal(signal.SIGINT)
        lab.communicate(timeout=30)


def _after(seconds: float, then: Callable[[], None]) -> dict[str, int]:
    """Call ``then`` after ``seconds`` (a thread); return the monotonic time it did."""
    seen: dict[str, int] = {}

    def run() -> None:
        time.sleep(seconds)
        seen["ns"] = time.monotonic_ns()
        then()

    threading.Thread(target=run, daemon=True).start()
    return seen


def _set_cause(rig: Any, cause: str) -> dict[str, int]:
    """Arrange for ``cause`` to happen during the approach; return where its time goes."""
    cause_ns: dict[str, int] = {}
    start = time.monotonic_ns()
    if cause in {"sigint", "sigterm"}:
        number = signal.SIGINT if cause == "sigint" else signal.SIGTERM
        return _after(CAUSE_S, lambda: os.kill(os.getpid(), number))
    if cause == "replaced":  # a colleague's computer: a connection and a program of its own
        link = rig.arm.connection

        def send() -> None:
            with socket.create_connection((link.host, link.script_port), timeout=5) as sock:
                sock.sendall(b"def theirs():\n  sleep(100.0)\nend\n")
                time.sleep(0.5)  # its connection stays while the lab takes the program

        return _after(CAUSE_S, send)
    if cause == "write":

        def full(self: RecordingWriter, item: Any) -> None:
            if time.monotonic_ns() - start > CAUSE_S * 1e9:
                cause_ns.setdefault("ns", time.monotonic_ns())
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            WRITE(self, item)

        RecordingWriter.write = full  # type: ignore[method-assign]
    elif cause == "error":
        poll = rig.skin.poll

        def broken() -> Any:
            if time.monotonic_ns() - start > CAUSE_S * 1e9:
                cause_ns.setdefault("ns", time.monotonic_ns())
                msg = "a bug in the skin"
                raise RuntimeError(msg)
            return poll()

        rig.skin.poll = broken
    return cause_ns


WRITE = RecordingWriter.write


def _clock_offset(rig: Any) -> int:
    """Return the rig's clock minus the monotonic clock, ns.

    Each reading is at most the true offset (the monotonic clock is read after the rig's);
    the largest of several is it, whatever thread ran in between.
    """
    clock: RecorderClock = rig.clock
    return max(clock.now_ns() - time.monotonic_ns() for _ in range(20))


def _one(tmp: Path, frequency: int, cause: str) -> dict[str, float] | None:
    """Record one action meeting ``cause``; return its latencies (None: it did not stop)."""
    lab, command, events_file = _lab_files(tmp, frequency, cause)
    with _serving(command), build_ur_rig(0, load_rig_config(lab)) as rig:
        try:
            rig.present(OBJECT)
        except RecorderError as err:  # a lab too loaded to keep its cycle: not this run's
            print(f"  ({cause}: {err})", file=sys.stderr)
            return None
        offset = _clock_offset(rig)
        cause_ns = _set_cause(rig, cause)
        try:
            record_action(rig, OBJECT, ACTION, 1, tmp / "out" / "001.mcap", seed=0)
        except BaseException:  # noqa: BLE001, S110 (every cause ends the action: measured below)
            pass
        finally:
            RecordingWriter.write = WRITE  # type: ignore[method-assign]
        stops = list(rig.stops_sent)
        time.sleep(0.5)  # the lab notes the arm's speed at zero before it is stopped
    if not stops:
        print(f"  ({cause}: the rig recorded no stop)", file=sys.stderr)
        return None
    cause_rig, sent_rig, _why = stops[0]
    events = [json.loads(line) for line in events_file.read_text().splitlines()]
    if cause == "protective":
        cause_mono = next(e["monotonic_ns"] for e in events if e["event"] == "stop")
    elif cause in {"drop", "gone"}:
        cause_mono = next(
            e["monotonic_ns"] for e in events if e["event"] == "fault" and e["fault"] == cause
        )
    elif cause == "replaced":
        cause_mono = next(
            int(e["received_monotonic_ns"])
            for e in events
            if e["event"] == "program" and e.get("name") == "theirs"
        )
    else:  # a signal, a failed write, an error; or the rig's own: a sample, the silence
        cause_mono = cause_ns.get("ns", cause_rig - offset)
    sent_mono = sent_rig - offset
    arrived = [  # the stop the rig sent (not the contact's stopl before it)
        int(e["received_monotonic_ns"])
        for e in events
        if e["event"] == "program"
        and str(e.get("name", "")).startswith("atikt_stop_")
        and int(e.get("received_monotonic_ns", 0)) >= sent_mono - 1_000_000
    ]
    if cause == "protective":  # the stopped controller refuses programs: the rig's send time
        arrived = [round(sent_mono)]
    if cause == "gone":  # the dashboard's stop: the lab's halt
        arrived = [int(e["monotonic_ns"]) for e in events if e["event"] == "halt"]
    if not arrived:
        print(
            f"  ({cause}: no stop program reached the lab after the rig sent it)", file=sys.stderr
        )
        return None
    arrival, period = arrived[0], 1e9 / frequency
    zeros = [e for e in events if e["event"] == "actual_zero" and e["monotonic_ns"] >= arrival]
    return {
        "cycles": (arrival - cause_mono) / period,
        "ms": (arrival - cause_mono) / 1e6,
        "zero_ms": (zeros[0]["monotonic_ns"] - arrival) / 1e6 if zeros else float("nan"),
    }


def _row(cause: str, frequency: int, found: list[dict[str, float]], missed: int) -> str:
    if not found:
        return f"{cause:<11}{frequency:>5}{'-':>12}{'-':>8}{'-':>9}{'-':>9}{missed:>8}"
    cycles = np.array([r["cycles"] for r in found])
    ms = np.array([r["ms"] for r in found])
    zero = np.array([r["zero_ms"] for r in found])
    to_zero = float(np.nanmedian(zero)) if np.isfinite(zero).any() else float("nan")
    return (
        f"{cause:<11}{frequency:>5}{np.percentile(cycles, 99):>12.2f}{np.median(cycles):>8.2f}"
        f"{np.percentile(ms, 99):>9.2f}{to_zero:>9.1f}{missed:>8}"
    )


def main() -> None:
    """Run every cause, print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=10, help="actions per cause and frequency")
    parser.add_argument("--quick", action="store_true", help="one run of three causes, 125 Hz")
    parser.add_argument("--causes", default=",".join(CAUSES), help="comma-separated causes")
    parser.add_argument("--frequencies", default="125,500", help="comma-separated, Hz")
    parser.add_argument(
        "--rt-priority",
        type=int,
        default=0,
        help="the rig option rt_priority: the readers and the runner under SCHED_FIFO (1-99)",
    )
    parser.add_argument(
        "--lab-rt-priority",
        type=int,
        default=0,
        help="serve-sim (the controller) under SCHED_FIFO at this priority (chrt)",
    )
    args = parser.parse_args()
    PRIORITY.update(recorder=args.rt_priority, lab=args.lab_rt_priority)
    # Ctrl-C is a cause: a shell starting this in the background ignores SIGINT for it
    signal.signal(signal.SIGINT, signal.default_int_handler)
    chosen = tuple(c for c in args.causes.split(",") if c)
    if unknown := sorted(set(chosen) - set(CAUSES)):
        parser.error(f"unknown cause {unknown[0]!r}; use some of {', '.join(CAUSES)}")
    rates = tuple(int(f) for f in args.frequencies.split(",") if f)
    runs, frequencies = (1, (125,)) if args.quick else (args.runs, rates)
    causes = ("limit", "sigint", "write") if args.quick else chosen
    print(
        f"load {os.getloadavg()[0]:.1f}; virtual lab time scale {SCALE}; {runs} runs each; "
        f"real-time priority: recorder {args.rt_priority or 'none'}, "
        f"lab {args.lab_rt_priority or 'none'}"
    )
    head = ("cause", "Hz", "p99 cycles", "median", "p99 ms", "zero ms", "missed")
    print(f"{head[0]:<11}{head[1]:>5}{head[2]:>12}{head[3]:>8}{head[4]:>9}{head[5]:>9}{head[6]:>8}")
    for frequency in frequencies:
        for cause in causes:
            found, missed = [], 0
            for _ in range(runs):
                with tempfile.TemporaryDirectory() as tmp:
                    result = _one(Path(tmp), frequency, cause)
                if result is None:
                    missed += 1
                else:
                    found.append(result)
            print(_row(cause, frequency, found, missed), flush=True)
    motion = tomllib.loads((ROOT / "recorder/data/ur_rig.example.toml").read_text("utf-8"))
    speed, acceleration = (motion["options"][k] for k in ("approach_max_m_s", "acceleration_m_s2"))
    for frequency in frequencies:
        bound = speed / acceleration * SCALE * 1e3 + 1e3 / frequency
        print(
            f"bound at {frequency} Hz: {bound:.1f} ms from the stop to zero speed "
            f"({speed:g} m/s / {acceleration:g} m/s^2 at time scale {SCALE}, plus a cycle)"
        )


if __name__ == "__main__":
    main()
