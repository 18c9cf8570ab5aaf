"""Rerun views of recordings and learning runs.

Recordings are logged on their own clock: one timestamp timeline named ``log_time`` holding
the recording's stamps (int64 ns, as the reader decodes them; the skin's per-sample stamps
unpacked from the blocks), and rerun's own wall-clock timelines (``log_time``, ``log_tick``)
switched off, so a view shows when things happened on the rig, not when they were logged.
Bulk data goes through rerun's columnar API (``send_columns``): one call per skin cell and
modality, per joint quantity, for the TCP pose and for the phases.

Entities of a recording, under its key ``<object>/<action>/<trial>``::

    <key>/skin/<modality>/cell_<id>   Scalars: one series per channel (force: 3 sensors, N;
                                      acceleration: x, y, z, m/s^2; temperature: C;
                                      proximity: m), named by SeriesLines
    <key>/robot/joints/<quantity>     Scalars: position (rad), velocity (rad/s), effort (N m),
                                      one series per joint
    <key>/robot/tcp                   Transform3D: the TCP pose in the robot base frame
    <key>/robot/trajectory            LineStrips3D (static): the TCP's whole path
    <key>/action/phases               TextLog: one event per phase start

The recording properties ``object``, ``action`` and ``recording`` describe what was viewed (one
value per recording, in the order of the keys). A learning run is logged on a sequence
timeline ``step`` under ``run/`` (see :func:`log_run`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
import polars as pl
import rerun as rr

from schemas import VOCABULARY

if TYPE_CHECKING:
    from collections.abc import Container, Iterable, Sequence
    from pathlib import Path

    from numpy.typing import NDArray

    from replay.learning._run_history import LearnRun
    from replay.recording._reader import (
        ActionRecording,
        JointStates,
        SkinSeries,
        TcpPoses,
    )
    from schemas import RecordingMetadata

#: Application id of every view.
APPLICATION_ID = "atikt"
#: Timeline of recordings: the recording's own clock, as timestamps.
TIMELINE = "log_time"
#: Timeline of learning runs: the step number.
STEP_TIMELINE = "step"


def series_names(modality: str, width: int) -> tuple[str, ...]:
    """Return the series names of a modality's values with units (names from the contract)."""
    spec = VOCABULARY.modalities[modality]
    return tuple(f"{name} ({spec.units})" for name in spec.value_names(width))


#: Length of the TCP's axes in the 3D view, m.
TCP_AXIS_LENGTH = 0.05


def new_stream(name: str, *, recording_id: str | None = None) -> rr.RecordingStream:
    """Return a recording stream without wall-clock timelines, named ``name``.

    The stream buffers until a sink is set (``save``, ``serve_grpc``, ``spawn``); nothing
    is lost by logging first.

    Args:
        name: Recording name shown by the viewer.
        recording_id: Rerun recording id (random when None).

    Returns:
        The stream.
    """
    stream = rr.RecordingStream(APPLICATION_ID, recording_id=recording_id, send_properties=False)
    stream.set_log_time_enabled(False)
    stream.set_log_tick_enabled(False)
    stream.send_recording_name(name)
    return stream


def recording_key(recording: ActionRecording) -> str:
    """Return the entity path of a recording: ``<object>/<action>/<trial>`` (trial 3 digits)."""
    meta = recording.metadata
    parts = (meta.object_id, meta.action_id, f"{meta.trial:03d}")
    return "/".join(rr.escape_entity_path_part(part) for part in parts)


def _times(stamps_ns: NDArray[np.int64]) -> list[rr.TimeColumn]:
    """Return the ``log_time`` index column of int64 nanosecond stamps."""
    stamps = np.ascontiguousarray(stamps_ns, dtype=np.int64).view("datetime64[ns]")
    return [rr.TimeColumn(TIMELINE, timestamp=stamps)]


def _series(
    stream: rr.RecordingStream,
    entity: str,
    stamps_ns: NDArray[np.int64],
    values: NDArray[np.floating],
    names: Sequence[str],
) -> None:
    """Send a (samples, series) array as scalar series with their names (static)."""
    stream.log(entity, rr.SeriesLines(names=list(names)), static=True)
    stream.send_columns(
        entity,
        indexes=_times(stamps_ns),
        columns=rr.Scalars.columns(scalars=np.ascontiguousarray(values)),
    )


def log_skin(stream: rr.RecordingStream, series: SkinSeries, prefix: str) -> None:
    """Log one skin modality: a scalar series per channel, one entity per cell."""
    names = series_names(series.modality, series.data.shape[2])
    for column, cell in enumerate(series.cell_ids):
        entity = f"{prefix}/skin/{series.modality}/cell_{int(cell)}"
        _series(stream, entity, series.stamps_ns, series.data[:, column, :], names)


def log_joints(stream: rr.RecordingStream, joints: JointStates, prefix: str) -> None:
    """Log the joint positions, velocities and efforts, one series per joint."""
    for quantity in ("position", "velocity", "effort"):
        values = getattr(joints, quantity)
        entity = f"{prefix}/robot/joints/{quantity}"
        _series(stream, entity, joints.stamps_ns, values, joints.names)


def log_tcp(stream: rr.RecordingStream, tcp: TcpPoses, prefix: str) -> None:
    """Log the TCP pose as a transform over time and its whole path as a static line."""
    stream.log(f"{prefix}/robot", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    entity = f"{prefix}/robot/tcp"
    stream.log(entity, rr.TransformAxes3D(TCP_AXIS_LENGTH), static=True)
    stream.send_columns(
        entity,
        indexes=_times(tcp.stamps_ns),
        columns=rr.Transform3D.columns(translation=tcp.position, quaternion=tcp.orientation),
    )
    stream.log(f"{prefix}/robot/trajectory", rr.LineStrips3D([tcp.position]), static=True)


def log_phases(stream: rr.RecordingStream, recording: ActionRecording, prefix: str) -> None:
    """Log the start of every phase as a text event."""
    if not recording.phases:
        return
    stamps = np.array([mark.start_ns for mark in recording.phases], dtype=np.int64)
    texts = [mark.phase for mark in recording.phases]
    stream.send_columns(
        f"{prefix}/action/phases",
        indexes=_times(stamps),
        columns=rr.TextLog.columns(text=texts, level=[rr.TextLogLevel.INFO] * len(texts)),
    )


def log_recording(stream: rr.RecordingStream, recording: ActionRecording, key: str) -> None:
    """Log one recording's signals under ``key`` (its properties: :func:`send_properties`)."""
    for series in recording.signals.values():
        log_skin(stream, series, key)
    if recording.joints is not None:
        log_joints(stream, recording.joints, key)
    if recording.tcp is not None:
        log_tcp(stream, recording.tcp, key)
    log_phases(stream, recording, key)


@dataclass(frozen=True, slots=True)
class ViewedRecording:
    """A logged recording: the entity path it is under, its file and metadata."""

    key: str
    path: Path
    metadata: RecordingMetadata


def send_properties(stream: rr.RecordingStream, viewed: Sequence[ViewedRecording]) -> None:
    """Send the ``object``, ``action`` and ``recording`` properties, one value per recording."""
    metas = [item.metadata for item in viewed]
    parameters = {
        name: [float(m.action_parameters.get(name, 0.0)) for m in metas]
        for name in ("depth_m", "force_n", "speed_m_s", "duration_s")
    }
    stream.send_property(
        "object",
        rr.AnyValues(
            id=[m.object_id for m in metas],
            name=[m.object_name for m in metas],
            description=[m.object_description for m in metas],
        ),
    )
    stream.send_property(
        "action",
        rr.AnyValues(
            id=[m.action_id for m in metas],
            kind=[m.action_kind for m in metas],
            trial=[m.trial for m in metas],
            depth_m=parameters["depth_m"],
            force_n=parameters["force_n"],
            speed_m_s=parameters["speed_m_s"],
            duration_s=parameters["duration_s"],
        ),
    )
    stream.send_property(
        "recording",
        rr.AnyValues(
            key=[item.key for item in viewed],
            path=[str(item.path) for item in viewed],
            rig=[m.rig.get("kind", "") for m in metas],
            seed=[m.seed for m in metas],
            software_version=[m.software_version for m in metas],
            schema_version=[m.schema_version for m in metas],
        ),
    )


def unique_key(recording: ActionRecording, taken: Container[str]) -> str:
    """Return the recording's key, with a suffix ``-2``, ``-3``, ... if ``taken`` has it."""
    key, number = recording_key(recording), 1
    while (candidate := key if number == 1 else f"{key}-{number}") in taken:
        number += 1
    return candidate


def log_recordings(
    stream: rr.RecordingStream, recordings: Iterable[ActionRecording]
) -> list[ViewedRecording]:
    """Log recordings one after the other, each under its own key, then their properties.

    ``recordings`` may be a generator: only one recording is held at a time.

    Returns:
        What was logged, in order.
    """
    viewed: list[ViewedRecording] = []
    keys: set[str] = set()
    for recording in recordings:
        key = unique_key(recording, keys)
        keys.add(key)
        log_recording(stream, recording, key)
        viewed.append(ViewedRecording(key, recording.path, recording.metadata))
    if viewed:
        send_properties(stream, viewed)
    return viewed


# ------------------------------------------------------------------------------ learning runs


def _steps(steps: Sequence[int]) -> list[rr.TimeColumn]:
    """Return the ``step`` index column."""
    return [rr.TimeColumn(STEP_TIMELINE, sequence=np.asarray(steps, dtype=np.int64))]


def _scalars(
    stream: rr.RecordingStream, entity: str, steps: Sequence[int], values: Sequence[float]
) -> None:
    """Send one scalar per step."""
    if not steps:
        return
    stream.send_columns(
        entity,
        indexes=_steps(steps),
        columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)),
    )


def decision_text(row: dict[str, Any]) -> str:
    """Return the one-line description of a decision (a history row with step > 0)."""
    how = "explore" if row["explored"] else "exploit"
    prior = f"prior {row['prior']} (rho {float(row['rho'] or 0.0):.2f})" if row["prior"] else ""
    return f"{row['object']} {row['action']} ({how}) {prior}".rstrip()


def _log_accuracy(stream: rr.RecordingStream, run: LearnRun, prefix: str) -> None:
    """Log the accuracy of all actions together and of each action, per step."""
    frame = run.frame.filter(pl.col("accuracy").is_not_null())
    steps = frame["step"].to_list()
    stream.log(f"{prefix}/accuracy/all", rr.SeriesLines(names=["all actions"]), static=True)
    _scalars(stream, f"{prefix}/accuracy/all", steps, frame["accuracy"].to_list())
    for action in run.actions:
        column = frame[f"accuracy_{action}"]
        entity = f"{prefix}/accuracy/{rr.escape_entity_path_part(action)}"
        stream.log(entity, rr.SeriesLines(names=[action]), static=True)
        _scalars(stream, entity, steps, column.fill_null(float("nan")).to_list())


def _log_decisions(stream: rr.RecordingStream, run: LearnRun, prefix: str) -> None:
    """Log every decision as text and its transfer coefficient and uncertainty as scalars."""
    rows = list(run.decisions.iter_rows(named=True))
    if not rows:
        return
    steps = [int(row["step"]) for row in rows]
    stream.send_columns(
        f"{prefix}/decisions",
        indexes=_steps(steps),
        columns=rr.TextLog.columns(
            text=[decision_text(row) for row in rows],
            level=[rr.TextLogLevel.INFO] * len(rows),
        ),
    )
    _scalars(stream, f"{prefix}/rho", steps, [float(row["rho"] or 0.0) for row in rows])
    for column in ("uncertainty", "mean_entropy"):
        if column in run.frame.columns:
            values = [float("nan") if row[column] is None else row[column] for row in rows]
            _scalars(stream, f"{prefix}/{column}", steps, values)


def _log_weights(stream: rr.RecordingStream, run: LearnRun, prefix: str) -> None:
    """Log the explored classifier's modality weights, one series per modality."""
    if "weights" not in run.frame.columns or "modalities" not in run.frame.columns:
        return
    series: dict[str, tuple[list[int], list[float]]] = {}
    for row in run.decisions.iter_rows(named=True):
        for modality, weight in zip(row["modalities"] or [], row["weights"] or [], strict=False):
            steps, values = series.setdefault(modality, ([], []))
            steps.append(int(row["step"]))
            values.append(float(weight))
    for modality, (steps, values) in series.items():
        entity = f"{prefix}/weights/{rr.escape_entity_path_part(modality)}"
        stream.log(entity, rr.SeriesLines(names=[modality]), static=True)
        _scalars(stream, entity, steps, values)


def _log_entropy(stream: rr.RecordingStream, run: LearnRun, prefix: str) -> None:
    """Log the entropy map (actions x objects) before every decision: a tensor and series."""
    if "entropies" not in run.frame.columns:
        return
    rows = [row for row in run.decisions.iter_rows(named=True) if row["entropies"]]
    if not rows:
        return
    steps = [int(row["step"]) for row in rows]
    maps = np.array([row["entropies"] for row in rows], dtype=np.float64)
    for step, matrix in zip(steps, maps, strict=True):
        stream.set_time(STEP_TIMELINE, sequence=step)
        stream.log(f"{prefix}/entropy/map", rr.Tensor(matrix, dim_names=("action", "object")))
    stream.reset_time()
    for a, action in enumerate(run.actions[: maps.shape[1]]):
        for o, obj in enumerate(run.objects[: maps.shape[2]]):
            part = "/".join(rr.escape_entity_path_part(p) for p in (action, obj))
            entity = f"{prefix}/entropy/{part}"
            stream.log(entity, rr.SeriesLines(names=[f"{obj} {action}"]), static=True)
            _scalars(stream, entity, steps, maps[:, a, o].tolist())


def log_run(stream: rr.RecordingStream, run: LearnRun, prefix: str = "run") -> None:
    """Log a learning run on the ``step`` timeline.

    Entities under ``prefix``: ``decisions`` (text: object, action, explore/exploit, chosen
    prior and rho), ``rho``, ``uncertainty``, ``mean_entropy``, ``weights/<modality>``,
    ``entropy/map`` (tensor, actions x objects, before each decision),
    ``entropy/<action>/<object>`` and ``accuracy/all``, ``accuracy/<action>``. The property
    ``run`` names the actions and objects (the map's axes) and the final accuracy.
    """
    _log_accuracy(stream, run, prefix)
    _log_decisions(stream, run, prefix)
    _log_weights(stream, run, prefix)
    _log_entropy(stream, run, prefix)
    final = run.frame["accuracy"].drop_nulls()
    stream.send_property(
        prefix,
        rr.AnyValues(
            path=str(run.path),
            actions=list(run.actions),
            objects=list(run.objects),
            steps=int(run.frame.height),
            final_accuracy=float(final[-1]) if final.len() else float("nan"),
        ),
    )
