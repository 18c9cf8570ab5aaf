"""A live learning run on a rig: its configuration, the run itself and its live view."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Self

from recorder import RecorderError, find_rig, load_actions, load_objects, load_rig_config
from recorder import rig_factory as make_factory
from replay.errors import ReplayError
from replay.learning._session import run_learning
from replay.live._executor import LiveExecutor
from replay.live._stream import StreamingRig
from replay.outputs._view import (
    ViewedRecording,
    log_recording,
    new_stream,
    send_properties,
    unique_key,
)
from replay.recording._reader import read_recording
from schemas import cli

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path
    from types import TracebackType

    import polars as pl

    from recorder import RigConfig
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


class LiveView:
    """Shows a live run in rerun: the signals as they arrive, and each file once written.

    While the rig records, its items are streamed (:class:`replay.live._stream.StreamingRig`,
    under ``live/...``); each finished file is then read with the replay's reader and logged
    with the rerun view's code (``atikt-replay view``), so the viewer also shows the same
    signals as a view of the session later.
    """

    def __init__(self, name: str, save: Path | None = None) -> None:
        """Open a rerun stream into ``save`` (an ``.rrd`` file), else a spawned viewer.

        Raises:
            ReplayError: rerun cannot start the viewer or write the file.
        """
        self.stream = new_stream(name)
        self.viewed: list[ViewedRecording] = []
        try:
            if save is not None:
                self.stream.save(save)
            else:
                self.stream.spawn()
        except (OSError, RuntimeError, ValueError) as err:
            how = f"--view {save}" if save is not None else "--view"
            msg = f"{how}: rerun could not start ({err}); give --view FILE.rrd to write a file"
            raise ReplayError(msg) from err

    def __call__(self, path: Path) -> None:
        """Log one finished recording under its own key."""
        recording = read_recording(path)
        key = unique_key(recording, {item.key for item in self.viewed})
        log_recording(self.stream, recording, key)
        self.viewed.append(ViewedRecording(key, recording.path, recording.metadata))

    def __enter__(self) -> Self:
        """Return the view."""
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Send the recordings' properties and flush the stream."""
        if self.viewed:
            send_properties(self.stream, self.viewed)
        self.stream.flush()


def learn_live(
    config: RigConfig,
    spec: RunSpec,
    models: Any,  # noqa: ANN401 (the prior models of replay.learning._session.fit_priors)
    session: Path,
    *,
    test_trials: int,
    on_step: Callable[[dict[str, Any]], Any],
    view: LiveView | None = None,
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
        view: Shows each recording once written.

    Returns:
        The run's history.

    Raises:
        ReplayError: An object the catalog lacks, or the recorder refused (one line).
    """
    try:
        objects = load_objects()
        if unknown := [o for o in spec.new_objects if o not in objects]:
            msg = (
                f"--new {','.join(unknown)}: not in the object catalog, so the rig cannot "
                f"perform on it; choose from {', '.join(objects)}"
            )
            raise ReplayError(msg)
        rig = make_factory(config)(spec.seed)
        executor = LiveExecutor(
            rig if view is None else StreamingRig(rig, view.stream),
            [objects[o] for o in spec.new_objects],
            load_actions(),
            session,
            seed=spec.seed,
            on_recorded=view,
        )
        with executor:
            test = executor.record_test_set(spec.actions, test_trials)
            return run_learning(spec, executor, test, models, on_step=on_step).frame()
    except RecorderError as err:  # the recorder's error, at the edge of the replay
        msg = f"--rig {config.name}: {cli.one_line(str(err))}"
        raise ReplayError(msg) from err
