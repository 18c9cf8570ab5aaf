"""A live learning run on a rig: its configuration, the run itself and its live view."""

from __future__ import annotations

import contextlib
import difflib
import os
import socket
import subprocess
import sys
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Self

from recorder import (
    FoxgloveView,
    RecorderError,
    RigCheck,
    check_object_poses,
    check_rig_ready,
    find_rig,
    load_actions,
    load_objects,
    load_rig_config,
    refuse_unrecordable,
    stale_parts,
)
from recorder import rig_factory as make_factory
from replay.errors import ReplayError
from replay.learning._session import run_learning
from replay.live._executor import LiveExecutor, refuse_unpresented
from replay.live._outputs import free_file
from replay.live._stream import CLOSE_S, ViewSink
from replay.outputs._view import (
    ViewedRecording,
    log_recording,
    new_stream,
    send_properties,
    unique_key,
)
from replay.recording._reader import read_recording
from schemas import ContractError, cli, is_incomplete
from schemas import check_rig as rig_description

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path
    from types import TracebackType

    import polars as pl

    from recorder import ActionSpec, ObjectSpec, RigConfig, Viewer
    from replay.learning._session import RunSpec


def configured_rig(path: Path | None, name: str | None, options: Sequence[str]) -> RigConfig:
    """Return the live rig's configuration (``--rig-config``, ``--rig``, ``--rig-option``).

    Raises:
        ReplayError: The configuration is refused; the recorder's one-line reason.
    """
    try:
        return load_rig_config(path, name, options)
    except RecorderError as err:
        raise ReplayError(cli.one_line(str(err))) from err


def check_rig(name: str) -> None:
    """Refuse a rig that cannot be found or loaded, before any work.

    Raises:
        ReplayError: Unknown rig (the message lists the known ones) or a broken plug-in.
    """
    try:
        find_rig(name)
    except RecorderError as err:
        raise ReplayError(cli.one_line(str(err))) from err


def foxglove_view(address: str) -> FoxgloveView:
    """Return a started Foxglove view on ``address`` (``HOST:PORT``).

    Raises:
        ReplayError: The address is malformed or cannot be bound, or foxglove-sdk is missing.
    """
    try:
        return FoxgloveView(address).__enter__()
    except RecorderError as err:  # the recorder's error, at the edge of the replay
        raise ReplayError(cli.one_line(str(err))) from err


def has_display() -> bool:
    """Return whether a viewer window can open here (a display on Linux; always elsewhere)."""
    if not sys.platform.startswith("linux"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


class LiveView:
    """Shows a live run in rerun: the signals as they arrive, and each file once written.

    While the rig records, its items go through a bounded, non-blocking sink
    (:class:`replay.live._stream.ViewSink`): a slow or blocked viewer drops frames (counted),
    it never delays the robot. Each finished file is then read with the replay's reader and
    logged with the rerun view's code (``atikt-replay view``), so the viewer also shows the
    same signals as a view of the session later.

    Where it goes: ``--view FILE.rrd`` writes a file; ``--view`` opens a viewer that listens on
    127.0.0.1 only; without a display (a server, ssh, CI) one line says so and the stream is
    written to ``fallback`` instead, so the run goes on.
    """

    def __init__(self, name: str, save: Path | None = None, *, fallback: Path) -> None:
        """Open a rerun stream into ``save``, a loopback viewer, or ``fallback`` (headless).

        Raises:
            ReplayError: rerun cannot start the viewer or write the file.
        """
        self.stream = new_stream(name)
        self.viewed: list[ViewedRecording] = []
        self.note = ""
        self._viewer: subprocess.Popen[bytes] | None = None
        target = save
        if save is None and not has_display():
            target = fallback
            self.note = (
                f"--view: no display here; the live view is written to {fallback} "
                f"(open it with: rerun {fallback})"
            )
        try:
            if target is not None:
                self.stream.save(target)
            else:
                self._viewer = _spawn_loopback_viewer(self.stream)
        except (OSError, RuntimeError, ValueError) as err:
            how = f"--view {save}" if save is not None else "--view"
            msg = f"{how}: rerun could not start ({err}); give --view FILE.rrd to write a file"
            raise ReplayError(msg) from err
        to_file = target is not None  # a file never blocks: everything is written
        self.sink = ViewSink(self.stream, self._log_file, close_s=None if to_file else CLOSE_S)

    @property
    def dropped(self) -> int:
        """Items the view could not take in time (counted, never waited for)."""
        return self.sink.dropped

    def _log_file(self, path: Path) -> None:
        """Log one finished recording under its own key (in the sink's thread)."""
        recording = read_recording(path)
        key = unique_key(recording, {item.key for item in self.viewed})
        log_recording(self.stream, recording, key)
        self.viewed.append(ViewedRecording(key, recording.path, recording.metadata))

    def __enter__(self) -> Self:
        """Start the sink's thread."""
        self.sink.__enter__()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Send the recordings' properties, flush (a bounded wait for a viewer) and close.

        Closing ends a file with rerun's footer (its index): until the stream lets go of the
        file, a reader in this process (a library user, a test) finds a file without it.
        """
        self.sink.__exit__(exc_type, exc, tb)
        with contextlib.suppress(Exception):  # the viewer's trouble never fails the run
            if self.viewed:
                send_properties(self.stream, self.viewed)
            self.stream.flush(timeout_sec=CLOSE_S if self._viewer is not None else 1e38)
        with contextlib.suppress(Exception):  # nor does closing it (the file stays readable)
            self.stream.disconnect()


def session_view(title: str, save: Path | None, *, fallback: Path) -> LiveView:
    """Return the rerun view of ``atikt-record session --view`` (the recorder finds it by name).

    Without a display the stream goes to the first free name of ``fallback``.

    Raises:
        RecorderError: rerun cannot start the viewer or write the file (the recorder's error:
            its command says it in one line).
    """
    try:
        return LiveView(title, save, fallback=free_file(fallback))
    except ReplayError as err:
        raise RecorderError(str(err)) from err


def _spawn_loopback_viewer(stream: Any) -> subprocess.Popen[bytes]:  # noqa: ANN401 (rerun's)
    """Start a rerun viewer that listens on 127.0.0.1 only and connect ``stream`` to it.

    Written by hand: rerun's own ``spawn`` starts the viewer listening on every interface
    (0.0.0.0) and has no option to say otherwise; its command line has ``--bind``.
    """
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = int(probe.getsockname()[1])
    command = [sys.executable, "-m", "rerun", "--bind", "127.0.0.1", "--port", str(port)]
    viewer = subprocess.Popen(command, stdin=subprocess.DEVNULL, start_new_session=True)  # noqa: S603
    stream.connect_grpc(f"rerun+http://127.0.0.1:{port}/proxy")
    return viewer


def _catalog(spec: RunSpec, config: RigConfig) -> tuple[list[ObjectSpec], dict[str, ActionSpec]]:
    """The run's new objects (in order) and the action catalog.

    Raises:
        ReplayError: An object or an action the catalogs lack (the rig cannot perform it).
        RecorderError: The rig configuration gives a pose to an object of no catalog.
    """
    objects, actions = load_objects(), load_actions()
    check_object_poses(config, objects)  # a typo would leave the real object without a pose
    for option, asked, known in (
        ("--new", spec.new_objects, objects),
        ("--actions", spec.actions, actions),
    ):
        if unknown := [name for name in asked if name not in known]:
            close = difflib.get_close_matches(unknown[0], list(known), n=1)
            guess = f"; did you mean {close[0]}?" if close else ""
            msg = (
                f"{option} {','.join(unknown)}: not in the catalog, so the rig cannot "
                f"perform it; choose from {', '.join(known)}{guess}"
            )
            raise ReplayError(msg)
    return [objects[o] for o in spec.new_objects], actions


def rig_configuration(config: RigConfig, seed: int) -> dict[str, object]:
    """Return the rig's configuration as the rig describes itself before connecting.

    What identifies a live run's rig, as ``atikt-record session`` identifies a dataset's
    (its claim): the settings' content, whatever the configuration file is called.

    Raises:
        ReplayError: The rig cannot be made or describes itself wrongly (one line).
    """
    try:
        return dict(rig_description(make_factory(config)(seed).describe()))
    except (RecorderError, ContractError) as err:
        msg = f"--rig {config.name}: {cli.one_line(str(err))}"
        raise ReplayError(msg) from err


def check_plan(config: RigConfig, spec: RunSpec) -> None:
    """Refuse what a live run would refuse before anything moves, connecting nothing.

    The new objects and actions (in the catalogs), each new object's pose and every action
    against the rig's skin: checked before the run claims its directory, so that a refused
    run leaves none behind.

    Raises:
        ReplayError: One line: what is refused and how to fix it.
    """
    try:
        objects, catalog = _catalog(spec, config)
        rig = make_factory(config)(spec.seed)
        refuse_unpresented(rig, objects, config.source)
        refuse_unrecordable(rig, [catalog[a] for a in spec.actions])
    except RecorderError as err:  # the recorder's error, at the edge of the replay
        msg = f"--rig {config.name}: {cli.one_line(str(err))}"
        raise ReplayError(msg) from err


@dataclass(frozen=True, slots=True)
class LiveCheck:
    """What a live run would do and what the rig showed (``learn --dry-run``).

    Attributes:
        test: Held-out recordings the run makes first.
        initial: Observations every (new object, action) gets before the learner chooses.
        budget: Observations the learner then chooses.
        on_disk: Recordings of an earlier, interrupted run of the same command (reused).
        stale: Unfinished files of a killed run it would set aside.
        rig: What the rig showed.
    """

    test: int
    initial: int
    budget: int
    on_disk: int
    stale: tuple[Path, ...]
    rig: RigCheck


def check_live(config: RigConfig, spec: RunSpec, session: Path, *, test_trials: int) -> LiveCheck:
    """Check a live run as it would begin, moving nothing and writing nothing.

    The new objects (in the catalog, each presentable by the rig), every action against the
    rig's limits, the disk, the arm's state and a second of the arm's and the skin's streams
    (:func:`recorder.check_rig_ready`).

    Raises:
        ReplayError: What the run would refuse, or a check of the rig failed (one line).
    """
    try:
        objects, catalog = _catalog(spec, config)
        factory = make_factory(config)
        refuse_unpresented(factory(spec.seed), objects, config.source)
        actions = [catalog[a] for a in spec.actions]
        found = check_rig_ready(factory, spec.seed, objects, actions, session)
    except RecorderError as err:  # the recorder's error, at the edge of the replay
        msg = f"--rig {config.name}: {cli.one_line(str(err))}"
        raise ReplayError(msg) from err
    pairs = len(objects) * len(actions)
    here = session.is_dir()
    on_disk = sum(1 for p in session.glob("*/*/*.mcap") if not is_incomplete(p)) if here else 0
    stale = stale_parts(session) if here else ()
    return LiveCheck(pairs * test_trials, pairs, spec.learner.budget, on_disk, stale, found)


def learn_live(
    config: RigConfig,
    spec: RunSpec,
    models: Any,  # noqa: ANN401 (the prior models of replay.learning._session.fit_priors)
    session: Path,
    *,
    test_trials: int,
    on_step: Callable[[dict[str, Any]], Any],
    viewers: Sequence[Viewer] = (),
) -> pl.DataFrame:
    """Run live: record the test trials, then every observation the learner asks for.

    Any rig works, exclusive hardware too: one rig in this process, one action at a time.

    Args:
        config: The rig.
        spec: The run (new objects, actions, budget, seed, ...).
        models: The prior objects' models (None without transfer).
        session: Where the recordings and ``session.parquet`` go.
        test_trials: Held-out trials per (new object, action).
        on_step: Called with each step's row.
        viewers: Live views (rerun, Foxglove): every item as it arrives (never blocking).

    Returns:
        The run's history.

    Raises:
        ReplayError: An object the catalog lacks, or the recorder refused (one line).
    """
    try:
        objects, actions = _catalog(spec, config)
        rig = make_factory(config)(spec.seed)
        refuse_unrecordable(rig, [actions[a] for a in spec.actions])  # before anything moves
        executor = LiveExecutor(
            rig,
            objects,
            actions,
            session,
            seed=spec.seed,
            viewers=viewers,
        )
        with executor:
            test = executor.record_test_set(spec.actions, test_trials)
            return run_learning(spec, executor, test, models, on_step=on_step).frame()
    except RecorderError as err:  # the recorder's error, at the edge of the replay
        msg = f"--rig {config.name}: {cli.one_line(str(err))}"
        raise ReplayError(msg) from err
