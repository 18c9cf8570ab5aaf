"""``atikt-record serve-sim``: the virtual lab, a virtual UR10 served over a real rig's protocols.

RTDE and the URScript port are served here; ``--skin`` and ``--ros2`` start the skin's frame
server and the ROS 2 publisher when they are installed (imported only when asked for).

Objects: the faces of the objects with an ``[objects.X] pose`` in ``--rig-config`` lie 20 mm
below that pose; others are placed under the arm where their first action is announced
(``_skinmodel``). Faults (``--fault SERVER.NAME=VALUE``) are refused in one line for a server
that is not served; each fault injected is printed as one line (``fault: ...``); at exit a
JSON summary (``{"faults": {source: {fault: count}}}``) goes to ``--fault-summary FILE`` and,
as the last line, to ``--events FILE``, which receives every event as a JSON line as it
happens (programs, faults, stops, speeds reaching zero: see ``_events``).
"""

from __future__ import annotations

import contextlib
import dataclasses
import importlib
import json
import math
import signal
import socket
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING, Any

from recorder._catalog import load_actions, load_objects
from recorder._cli import CATALOG_ARGUMENTS, arg, command
from recorder._rigconfig import load_rig_config, thaw
from recorder.errors import RecorderError
from recorder.virtuallab._controller import VirtualController
from recorder.virtuallab._dashboard import DashboardServer
from recorder.virtuallab._events import Event, EventLog
from recorder.virtuallab._rtde_server import RtdeFaults, RtdeServer
from recorder.virtuallab._script_server import ScriptFaults, ScriptServer
from recorder.virtuallab._world import VirtualWorld
from schemas import cli

if TYPE_CHECKING:
    import argparse
    from collections.abc import Callable, Iterator, Mapping, Sequence
    from typing import TextIO

#: Faults of the RTDE and URScript servers (``--fault rtde.drop=3``...); others go to the
#: skin and ROS 2 servers by their prefix.
_RTDE_FAULTS = {
    "drop": "drop",
    "duplicate": "duplicate",
    "reorder": "reorder",
    "after": "after",
    "stall": "stall_s",
    "disconnect": "disconnect_after_s",
    "at_action": "at_action_s",
}
#: Faults that 0 turns off (an amount: none dropped, never stalled...); the others are when or
#: where a fault starts, and 0 is a time or a count like any other.
_OFF_AT_ZERO = frozenset(
    {"drop", "duplicate", "reorder", "truncate", "stall", "disconnect", "protective_stop", "gone"}
    | {"deaf"}
    | {"stop_after"}
)
#: The servers faults can be injected into, and the option that serves each.
SERVERS = {"rtde": "", "script": "", "skin": "--skin URL", "ros2": "--ros2"}


def parse_faults(items: Sequence[str]) -> dict[str, dict[str, float]]:
    """Parse ``--fault server.name=value`` items into server -> name -> value.

    Raises:
        RecorderError: An item is not ``server.name=number``.
    """
    faults: dict[str, dict[str, float]] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        server, dot, name = key.partition(".")
        try:
            value = float(raw)
        except ValueError:
            value = float("nan")
        if not (sep and dot and server and name) or not math.isfinite(value) or value < 0:
            msg = (
                f"--fault {item!r}: give server.name=number (finite, 0 or more), e.g. rtde.drop=3, "
                "rtde.stall=1.5, rtde.disconnect=2, script.protective_stop=1, skin.drop=5"
            )
            raise RecorderError(msg)
        if value == 0 and name in _OFF_AT_ZERO:
            msg = (
                f"--fault {item!r}: 0 turns {key} off, so it injects nothing; give a positive "
                f"value (e.g. {key}=1), or leave the fault out"
            )
            raise RecorderError(msg)
        faults.setdefault(server, {})[name] = value
    return faults


def rtde_faults(faults: dict[str, float]) -> RtdeFaults:
    """Return the RTDE server's faults.

    Raises:
        RecorderError: An unknown RTDE fault.
    """
    values: dict[str, Any] = {}
    for name, value in faults.items():
        field = _RTDE_FAULTS.get(name)
        if field is None:
            msg = f"--fault rtde.{name}: the RTDE faults are {', '.join(_RTDE_FAULTS)}"
            raise RecorderError(msg)
        values[field] = value if field.endswith("_s") else int(value)
    return RtdeFaults(**values)


def check_served(faults: Mapping[str, object], served: Mapping[str, bool]) -> None:
    """Refuse faults for a server that is unknown or not served, in one line.

    Raises:
        RecorderError: The first such server, and how to serve it.
    """
    for server in faults:
        if server not in SERVERS:
            msg = f"--fault {server}.*: no such server; faults go to {', '.join(SERVERS)}"
            raise RecorderError(msg)
        if not served.get(server, True):
            msg = (
                f"--fault {server}.*: the {server} server is not served; add {SERVERS[server]} "
                "or drop the fault"
            )
            raise RecorderError(msg)


def ros2_faults(cls: Any, faults: dict[str, float], topic_map: Path) -> Any:  # noqa: ANN401
    """Return the ROS 2 server's faults; ``drop=N`` drops N samples of every mapped topic.

    Raises:
        RecorderError: An unknown fault, or an unreadable topic map.
    """
    values = dict(faults)
    count = values.pop("drop", None)
    made = typed_faults(cls, values, "ros2", ("drop",))
    if count is None:
        return made
    from recorder.bagimport._source import extractors  # noqa: PLC0415 (with --ros2 only)
    from recorder.bagimport._topicmap import load_topic_map  # noqa: PLC0415

    mapped = load_topic_map(topic_map)
    topics = set(extractors(mapped))
    if mapped.joints is not None:
        topics.add(mapped.joints.topic)
    return dataclasses.replace(made, drop=dict.fromkeys(sorted(topics), int(count)))


def script_faults(faults: dict[str, float]) -> ScriptFaults:
    """Return the URScript server's faults.

    Raises:
        RecorderError: An unknown URScript fault.
    """
    unknown = set(faults) - {"protective_stop", "drop", "gone", "deaf"}
    if unknown:
        msg = (
            f"--fault script.{min(unknown)}: the URScript faults are protective_stop, drop, "
            "gone, deaf"
        )
        raise RecorderError(msg)
    return ScriptFaults(
        faults.get("protective_stop", 0.0),
        faults.get("drop", 0.0),
        faults.get("gone", 0.0),
        faults.get("deaf", 0.0),
    )


def typed_faults(
    cls: Any,  # noqa: ANN401
    faults: dict[str, float],
    server: str,
    extra: tuple[str, ...] = (),
) -> Any:  # noqa: ANN401
    """Return a server's fault dataclass from ``--fault server.name=number`` values.

    ``name`` is a field of ``cls`` or a field without its ``_s`` suffix (``stall`` ->
    ``stall_s``); integer fields get integers. ``extra``: faults handled by the caller, named
    in the message.

    Raises:
        RecorderError: No such numeric field.
    """
    known = {f.name: f for f in dataclasses.fields(cls)}
    values: dict[str, Any] = {}
    for name, value in faults.items():
        field = known.get(name) or known.get(f"{name}_s")
        default = getattr(field, "default", None)
        if field is None or isinstance(default, bool) or not isinstance(default, int | float):
            numeric = [n for n, f in known.items() if isinstance(f.default, int | float)]
            numeric = [*extra, *numeric]
            msg = f"--fault {server}.{name}: the {server} faults are {', '.join(numeric)}"
            raise RecorderError(msg)
        values[field.name] = int(value) if isinstance(default, int) else value
    return cls(**values)


def _lab_sections(path: Path | None) -> Mapping[str, Any]:
    """Return the rig configuration's tables (``skin`` for the skin server).

    The file is read as every command reads a rig configuration (``load_rig_config``).

    Raises:
        RecorderError: The file is unreadable, too large or malformed.
    """
    return {} if path is None else thaw(load_rig_config(path).sections)


def _poses(sections: Mapping[str, Any]) -> dict[str, list[float]]:
    """Return the objects' poses of the rig configuration (those given as 6 finite numbers)."""
    poses: dict[str, list[float]] = {}
    for object_id, entry in (sections.get("objects") or {}).items():
        pose = entry.get("pose") if isinstance(entry, dict) else None
        if (
            isinstance(pose, list)
            and len(pose) == 6  # noqa: PLR2004 (x, y, z, rx, ry, rz)
            and all(isinstance(v, int | float) and not isinstance(v, bool) for v in pose)
            and all(math.isfinite(v) for v in pose)
        ):
            poses[object_id] = [float(v) for v in pose]
    return poses


def _print_fault(event: Event) -> None:
    """Print one injected fault, or one stop program received, as one line."""
    seconds = event.controller_ns / 1e9
    if event.kind == "program":
        said = " ".join(f"{k}={v}" for k, v in (event.details.get("announced") or {}).items())
        name = event.details.get("name", "")
        print(f"stop: {name} at controller {seconds:.3f} s {said}".rstrip(), flush=True)  # noqa: T201
        return
    details = " ".join(
        f"{key}={value}" for key, value in event.details.items() if key not in {"source", "fault"}
    )
    where = f"{event.details.get('source')}.{event.details.get('fault')}"
    print(f"fault: {where} at controller {seconds:.3f} s {details}".rstrip(), flush=True)  # noqa: T201


@contextlib.contextmanager
def _event_files(events: Path | None, summary: Path | None) -> Iterator[EventLog]:
    """Open the events file (JSON lines) and write the fault summary at exit.

    Raises:
        RecorderError: A file cannot be written (one line naming it).
    """
    sink: TextIO | None = None
    try:
        if events is not None:
            sink = events.open("x", encoding="utf-8")
    except OSError as err:
        msg = f"--events {events}: cannot create it ({err.strerror}); give a new file"
        raise RecorderError(msg) from err
    log = EventLog(sink, echo=_print_fault)
    try:
        yield log
    finally:
        record = json.dumps({"event": "summary", "faults": log.faults()})
        if sink is not None:
            sink.write(record + "\n")
            sink.close()
        if summary is not None:
            try:
                summary.write_text(json.dumps({"faults": log.faults()}) + "\n", "utf-8")
            except OSError as err:
                msg = f"--fault-summary {summary}: cannot write it ({err.strerror})"
                raise RecorderError(msg) from err


def _optional_server(module: str, name: str, what: str) -> Callable[..., Any]:
    """Import a server written elsewhere (skin frames, ROS 2) only when asked for.

    Raises:
        RecorderError: It is not installed.
    """
    try:
        return getattr(importlib.import_module(module), name)  # type: ignore[no-any-return]
    except (ImportError, AttributeError) as err:
        msg = f"serve-sim: the {what} server is not available in this installation ({err})"
        raise RecorderError(msg) from err


def _wait_for_a_stop(failed: Callable[[], bool]) -> None:
    """Block until a signal ends the lab, or ``failed()``.

    The signals: Ctrl-C (SIGINT), SIGTERM or SIGHUP (its terminal closed; not under nohup).
    ``failed()``: a server stopped serving (the lab ends, and the server says why). Each
    signal is handled explicitly: a shell starts background jobs with SIGINT ignored, and the
    virtual lab must still stop on the first Ctrl-C or ``kill`` sent to it.
    """
    handled = cli.handled_signals()
    previous = {number: signal.signal(number, signal.default_int_handler) for number in handled}
    wake = threading.Event()
    try:
        while not failed():
            wake.wait(FAILED_POLL_S)
    except KeyboardInterrupt:
        return
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)


#: How often the lab looks whether a server stopped serving, s.
FAILED_POLL_S = 0.5


def _switch_within_a_cycle(frequency: int) -> None:
    """Let the lab's threads take turns within a quarter of a controller cycle.

    A controller takes a stop program at its next cycle. The lab's threads (the world's
    cycles, the RTDE stream, the script port) share one interpreter, which hands it over every
    5 ms by default: longer than two cycles at 500 Hz, so a stop that arrived could wait for
    the world's cycle in another thread. serve-sim is a process of its own: its switch
    interval is set for it alone.
    """
    sys.setswitchinterval(min(sys.getswitchinterval(), 0.25 / frequency))


@command(
    "serve-sim",
    "serve the simulator over a UR's RTDE and URScript ports (a virtual lab, on loopback)",
    arg("--host", default="127.0.0.1", help="address to bind (default: 127.0.0.1, loopback)"),
    arg("--rtde-port", type=cli.port, default=30004, help="RTDE port (default: 30004)"),
    arg(
        "--script-port",
        type=cli.port,
        default=30001,
        help="URScript port, a primary interface (default: 30001)",
    ),
    arg(
        "--frequency",
        type=int,
        choices=(125, 500),
        default=125,
        help="controller generation: 125 (CB3) or 500 Hz (e-Series) (default: 125)",
    ),
    arg(
        "--dashboard-port",
        type=cli.port,
        default=None,
        help="also serve the dashboard subset (robotmode, safetymode, stop, play, unlock "
        "protective stop) on this port (a UR's: 29999)",
    ),
    arg(
        "--rig-config",
        type=Path,
        default=None,
        help="the lab's rig configuration (its [skin], and the [objects] poses)",
    ),
    arg(
        "--time-scale",
        type=float,
        default=1.0,
        help="real s per world s: 0.1 runs the arm and the skin ten times faster than the "
        "controller's clock (tests; the rig then sets time_scale = 0.1) (default: 1.0)",
    ),
    arg(
        "--skin",
        default=None,
        metavar="URL",
        help="also serve skin frames, e.g. udp://127.0.0.1:5005",
    ),
    arg("--ros2", action="store_true", help="also publish the rig's ROS 2 topics over DDS"),
    arg("--topic-map", type=Path, default=None, help="topic map of the ROS 2 topics (--ros2)"),
    arg(
        "--domain-id",
        type=cli.domain_id,
        default=0,
        help="DDS domain of the ROS 2 topics (default: 0)",
    ),
    arg("--seed", type=cli.rig_seed, default=0, help="seed of the simulated rig (default: 0)"),
    arg(
        "--fault",
        action="append",
        default=[],
        metavar="SERVER.NAME=VALUE",
        help="inject a fault (tests): rtde.drop/duplicate/reorder=N, rtde.stall=S, "
        "rtde.disconnect=S, rtde.at_action=S, script.protective_stop=S, script.drop=S, "
        "script.gone=S, script.deaf=S, skin.* and ros2.* for those servers (skin.at_action=S, "
        "ros2.at_action=S: counted from S s after the first action)",
    ),
    arg("--events", type=Path, default=None, help="write every event as a JSON line (new file)"),
    arg(
        "--fault-summary",
        type=Path,
        default=None,
        help="write what was injected as JSON at exit",
    ),
    *CATALOG_ARGUMENTS,
)
def _serve_sim(args: argparse.Namespace) -> int:
    from recorder._sim import SimulatedRig  # noqa: PLC0415 (loads scipy)

    faults = parse_faults(args.fault)
    check_served(faults, {"skin": bool(args.skin), "ros2": bool(args.ros2)})
    if args.ros2 and args.topic_map is None:
        msg = "serve-sim --ros2 needs --topic-map MAP: the topics the rig reads"
        raise RecorderError(msg)
    sections = _lab_sections(args.rig_config)
    _switch_within_a_cycle(args.frequency)
    with contextlib.ExitStack() as stack:
        events = stack.enter_context(_event_files(args.events, args.fault_summary))
        sim = stack.enter_context(SimulatedRig(args.seed))
        world = VirtualWorld(
            sim,
            load_objects(args.objects_catalog),
            load_actions(args.actions_catalog),
            time_scale=args.time_scale,
            frequency=args.frequency,
            poses=_poses(sections),
            seed=args.seed,
            events_log=events,
        )
        stack.enter_context(world)
        where = _serve_arm(stack, world, args, faults)
        failed: list[Callable[[], bool]] = []
        if args.skin:
            where.append(_serve_skin(stack, world, args, faults, sections, failed=failed))
        if args.ros2:
            serve = _optional_server("recorder.virtuallab._ros2_server", "serve_ros2", "ROS 2")
            kind = _optional_server("recorder.virtuallab._ros2_server", "Ros2Faults", "ROS 2")
            ros2 = ros2_faults(kind, faults.get("ros2", {}), args.topic_map)
            server = stack.enter_context(
                serve(world, args.topic_map, ros2, domain_id=args.domain_id)
            )
            stack.callback(_ros2_summary, events, world, server)
            where.append("ROS 2 topics")
        print(f"virtual lab listening: {', '.join(where)}; Ctrl-C stops it", flush=True)  # noqa: T201
        _wait_for_a_stop(lambda: any(test() for test in failed))
    print("virtual lab stopped", flush=True)  # noqa: T201
    return 0


def _serve_arm(
    stack: contextlib.ExitStack,
    world: VirtualWorld,
    args: argparse.Namespace,
    faults: Mapping[str, dict[str, float]],
) -> list[str]:
    """Serve RTDE and the URScript port; return where they listen.

    Raises:
        RecorderError: A port cannot be bound.
    """
    controller = VirtualController(world)
    rtde = RtdeServer(
        controller,
        args.host,
        args.rtde_port,
        frequency=args.frequency,
        faults=rtde_faults(faults.get("rtde", {})),
    )
    script = ScriptServer(
        controller, args.host, args.script_port, faults=script_faults(faults.get("script", {}))
    )
    dashboard = None
    if args.dashboard_port is not None:
        dashboard = DashboardServer(controller, args.host, args.dashboard_port)
    try:
        stack.enter_context(rtde)
        stack.enter_context(script)
        if dashboard is not None:
            stack.enter_context(dashboard)
    except OSError as err:
        ports = [args.rtde_port, args.script_port]
        ports += [] if args.dashboard_port is None else [args.dashboard_port]
        fix = "give --host an address of this machine (default: 127.0.0.1)"
        if isinstance(err, socket.gaierror):
            msg = f"serve-sim: --host {args.host!r} is not an address here ({err}); {fix}"
        else:
            addresses = ", ".join(f"{args.host}:{p}" for p in ports)
            msg = f"serve-sim: cannot listen on {addresses} ({err}); choose other ports or {fix}"
        raise RecorderError(msg) from err
    where = [f"RTDE {rtde.address[0]}:{rtde.address[1]}", f"URScript {script.address[1]}"]
    if dashboard is not None:
        where.append(f"dashboard {dashboard.address[1]}")
    return where


def _serve_skin(
    stack: contextlib.ExitStack,
    world: VirtualWorld,
    args: argparse.Namespace,
    faults: Mapping[str, dict[str, float]],
    sections: Mapping[str, Any],
    *,
    failed: list[Callable[[], bool]],
) -> str:
    """Serve the skin's frames; return where they go; ``failed`` gets its failure test."""
    serve = _optional_server("recorder.virtuallab._skin_server", "serve_skin", "skin")
    kind = _optional_server("recorder.virtuallab._skin_server", "SkinFaults", "skin")
    skin_faults = typed_faults(kind, faults.get("skin", {}), "skin")

    def report(fault: str, controller_ns: int, **details: object) -> None:
        world.events_log.add("fault", controller_ns, source="skin", fault=fault, **details)

    server = stack.enter_context(
        serve(
            world,
            args.skin,
            sections.get("skin", {}),
            skin_faults,
            action_start=lambda: world.first_action_ns,
            on_fault=report,
        )
    )
    failed.append(lambda: server.error is not None)  # the lab ends, serve_skin says why
    return f"skin {args.skin}"


def _ros2_summary(events: EventLog, world: VirtualWorld, server: Any) -> None:  # noqa: ANN401
    """Record the ROS 2 server's drops (it counts them itself) as fault events."""
    dropped_at = getattr(server, "dropped_at", {})
    for topic, count in sorted(getattr(server, "dropped", {}).items()):
        at = dropped_at.get(topic, world.controller_ns())
        events.add("fault", at, source="ros2", fault="drop", topic=topic, count=count)
