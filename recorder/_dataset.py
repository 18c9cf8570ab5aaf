"""Dataset generation: many recordings in parallel, laid out for people, with a parquet index.

Layout: ``<root>/<object id>/<action id>/<trial>.mcap`` with the trial number 1-based and
zero-padded to three digits (``001.mcap``), so a directory listing sorts by trial. Beside the
recordings, ``<root>/index.parquet`` has one row per recording; it is derived data and
:func:`write_index` rebuilds it from the files at any time.

Every recording is an independent task (object, action, trial) performed by a fresh rig made
from the dataset seed; its bytes depend on nothing else, so the dataset is byte-identical
whatever the number of worker processes or the order the tasks finish in. Existing
recordings are skipped (an interrupted run resumes) and never overwritten.
"""

from __future__ import annotations

import contextlib
import enum
import errno
import functools
import hashlib
import io
import itertools
import os
import struct
import sys
import threading
import time
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import tomli_w
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import MCAP0_MAGIC

from recorder._claim import claim_dataset, differing_settings
from recorder._rigconfig import ConfiguredRig, is_exclusive, register_rig, rig_factory, rig_names
from recorder.errors import OutputExistsError, RecorderError
from recorder.runner._record import record_action
from recorder.writing._writer import FACT_PREFIX, METADATA_NAME
from schemas import (
    CHANNELS,
    MAX_TRIAL,
    PART_SUFFIX,
    SET_ASIDE_DIR,
    VOCABULARY,
    ContractError,
    RecordingMetadata,
    atomic_write,
    check_id,
    check_rig,
    cli,
    dataset_recordings,
    loads_toml,
    parse_metadata,
    part_writer,
    process_running,
    recording_into,
    unreadable,
)
from schemas import recording_path as schemas_recording_path

if TYPE_CHECKING:
    from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence

    import polars as pl
    from threadpoolctl import ThreadpoolController

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder._rigconfig import RigFactory

#: polars, joblib, cloudpickle and threadpoolctl are imported where they are used, not with this
#: module: every ``atikt-record`` command imports it, and most (``serve-sim``, ``session``
#: until it indexes, ``--help``, a refusal) never need them (about 0.25 s of each start).
_LAZY = ("polars", "joblib", "cloudpickle", "threadpoolctl")
#: File name of a dataset's index, beside the object directories.
INDEX_NAME = "index.parquet"
#: The rig registry lives in recorder._rigconfig; these names stay importable from here.
__all__ = ["INDEX_NAME", "register_rig", "rig_factory", "rig_names"]


def recording_path(root: Path, object_id: str, action_id: str, trial: int) -> Path:
    """Return where a dataset keeps trial ``trial`` of ``action_id`` on ``object_id``.

    Raises:
        RecorderError: An id breaks the id rule or the path would lie outside ``root``.
    """
    try:
        return schemas_recording_path(root, object_id, action_id, trial)
    except ContractError as err:
        msg = f"{root}: {err}"
        raise RecorderError(msg) from err


@dataclass(frozen=True, slots=True)
class RecordingTask:
    """One recording of a dataset: trial ``trial`` (1-based) of ``action`` on ``obj``."""

    obj: ObjectSpec
    action: ActionSpec
    trial: int

    def path(self, root: Path) -> Path:
        """Return the recording's path in the dataset at ``root``."""
        return recording_path(root, self.obj.id, self.action.id, self.trial)


def _select(catalog: Mapping[str, Any], wanted: Sequence[str] | None, what: str) -> list[Any]:
    """Return the catalog entries named in ``wanted`` (all when None), in catalog order.

    Raises:
        RecorderError: A name is not in the catalog.
    """
    if wanted is None:
        return list(catalog.values())
    if unknown := [name for name in wanted if name not in catalog]:
        msg = (
            f"--{what} {','.join(unknown)}: not in the {what} catalog; known: {', '.join(catalog)}"
        )
        raise RecorderError(msg)
    return [entry for name, entry in catalog.items() if name in set(wanted)]


def plan_dataset(
    objects: Mapping[str, ObjectSpec],
    actions: Mapping[str, ActionSpec],
    *,
    object_ids: Sequence[str] | None = None,
    action_ids: Sequence[str] | None = None,
    trials: int | None = None,
) -> list[RecordingTask]:
    """Return the recordings of a dataset, object by object, action by action, trial by trial.

    Args:
        objects: Object catalog.
        actions: Action catalog.
        object_ids: Objects to record (all when None).
        action_ids: Actions to record (all when None).
        trials: Trials per (object, action), numbered from 1; each action's catalog
            default (``trials``) when None.

    Raises:
        RecorderError: An id is not in its catalog or ``trials`` is below 1.
    """
    if trials is not None and trials < 1:
        msg = f"--trials {trials}: need at least one trial"
        raise RecorderError(msg)
    if trials is not None and trials > MAX_TRIAL:
        msg = f"--trials {trials}: trials are numbered 1..{MAX_TRIAL}; give at most {MAX_TRIAL}"
        raise RecorderError(msg)
    return [
        RecordingTask(obj, action, trial)
        for obj in _select(objects, object_ids, "objects")
        for action in _select(actions, action_ids, "actions")
        for trial in range(1, (trials or action.trials) + 1)
    ]


class TaskStatus(enum.StrEnum):
    """What happened to one task."""

    WRITTEN = "written"
    SKIPPED = "skipped"
    FAILED = "failed"


@dataclass(frozen=True, slots=True)
class TaskResult:
    """The outcome of one task: status, size of the file on disk, and why it failed."""

    task: RecordingTask
    status: TaskStatus
    size_bytes: int
    error: str = ""


#: Seconds between a worker's checks that the process that started it is still alive.
WATCH_INTERVAL_S = 0.5
_watched: set[int] = set()


def watch_parent(parent: int, interval_s: float = WATCH_INTERVAL_S) -> None:
    """In a worker process started by ``parent``: exit as soon as ``parent`` has died.

    A daemon thread compares the worker's parent process id with the one it had when the
    watch began (an orphan is adopted by another process); it works wherever
    ``os.getppid`` does. Nothing happens in ``parent`` itself (one worker runs in-process)
    or when the watch is already running. A worker killed this way leaves its unfinished
    recording as ``*.mcap.part``, as any killed recorder does.
    """
    if os.getpid() == parent or parent in _watched:
        return
    _watched.add(parent)
    adopter = os.getppid()

    def watch() -> None:
        while os.getppid() == adopter:
            threading.Event().wait(interval_s)
        os._exit(1)  # the parent is gone: nobody reads this worker's results

    threading.Thread(target=watch, name="atikt-parent-watch", daemon=True).start()


@functools.cache
def _blas() -> ThreadpoolController:
    """Return this process's BLAS and OpenMP libraries, found once.

    ``threadpool_limits`` looks for them among every loaded library on each call (a few ms, as
    much as the writer spends on a recording's messages); the libraries a worker has do not
    change between its recordings.
    """
    from threadpoolctl import ThreadpoolController  # noqa: PLC0415 (see _LAZY)

    return ThreadpoolController()


def run_task(
    task: RecordingTask,
    root: Path,
    factory: RigFactory,
    seed: int,
    parent: int | None = None,
    *,
    durable: bool = True,
) -> TaskResult:
    """Record one task with a fresh rig (one BLAS thread: results independent of workers).

    Args:
        task: The recording to make.
        root: Dataset directory.
        factory: Makes the rig.
        seed: Dataset seed.
        parent: Process id of the dataset run; a worker exits when it dies.
        durable: Sync the file before it counts as written (see :func:`generate_dataset`).

    Returns:
        WRITTEN; SKIPPED when the file existed (possibly written meanwhile by another run);
        FAILED with the error's message when the recorder refused (its temporary file is
        removed then), so that the other workers finish their recordings cleanly.
    """
    if parent is not None:
        watch_parent(parent)
    path = task.path(root)
    try:
        with _blas().limit(limits=1), factory(seed) as rig:
            written = record_action(
                rig, task.obj, task.action, task.trial, path, seed=seed, durable=durable
            )
    except OutputExistsError:
        return TaskResult(task, TaskStatus.SKIPPED, path.stat().st_size)
    except RecorderError as err:
        return TaskResult(task, TaskStatus.FAILED, 0, str(err))
    return TaskResult(task, TaskStatus.WRITTEN, written.size_bytes)


def check_sendable(factory: RigFactory) -> None:
    """Refuse, before any worker starts, a rig factory that cannot be sent to workers.

    joblib's process pool (loky) sends tasks with cloudpickle, so the check uses it too.

    Raises:
        RecorderError: The factory does not pickle; the message names it and the fix.
    """
    import cloudpickle  # noqa: PLC0415 (see _LAZY)

    try:
        cloudpickle.dumps(factory)
    except Exception as err:  # pickling a user's object may raise anything
        name = factory.config.name if isinstance(factory, ConfiguredRig) else repr(factory)
        msg = (
            f"rig {name}: its builder cannot be sent to worker processes "
            f"({type(err).__name__}: {err}); define the rig's builder at the top level of an "
            "importable module, or record with --workers 1"
        )
        raise RecorderError(msg) from err


@dataclass(frozen=True, slots=True)
class DatasetReport:
    """Summary of a dataset run.

    Attributes:
        root: Dataset directory.
        written: Recordings written by this run.
        skipped: Recordings that existed already.
        index: Path of the rebuilt index.
        size_bytes: Size of all recordings of the index.
        incomplete: Temporary files of recorders still running (``*.mcap.part``).
        set_aside: Unfinished recordings of dead recorders, moved to :data:`SET_ASIDE_DIR`.
    """

    root: Path
    written: int
    skipped: int
    index: Path
    size_bytes: int
    incomplete: tuple[Path, ...]
    set_aside: tuple[Path, ...] = ()


def generate_dataset(
    tasks: Sequence[RecordingTask],
    root: Path,
    factory: RigFactory,
    *,
    seed: int,
    workers: int | None = None,
    on_result: Callable[[TaskResult], None] | None = None,
    durable: bool = True,
) -> DatasetReport:
    """Record ``tasks`` under ``root`` in parallel, skipping existing files, then index.

    Args:
        tasks: The recordings to make (see :func:`plan_dataset`).
        root: Dataset directory (created if needed).
        factory: Makes a rig from the seed; called once per task, in the worker.
        seed: Dataset seed, given to every rig and written to every file.
        workers: Worker processes; all cores when None. An exclusive rig (see
            :func:`recorder.is_exclusive`) records one action at a time in this process,
            whatever ``workers`` says.
        on_result: Called in the parent for every finished task (progress display).
        durable: Sync each recording to the disk before it counts as written (the default).
            False for a dataset that can be recorded again from its seed (the default
            simulated dataset in the cache): the recordings are synced all at once before
            the index is written (a sync per file is most of a small recording's time), and
            a run first sets aside any recording cut short, which a power loss during an
            earlier run can leave under its final name.

    Returns:
        What was written and skipped, and the index.

    Raises:
        RecorderError: ``root`` holds recordings of another seed or rig configuration, the
            rig cannot be sent to worker processes, or a task failed: no new task starts,
            those running finish, and every recording finished is kept.
    """
    root = Path(root).absolute()  # reused workers keep the directory they started in
    check_configuration(root, seed, factory)
    claim_dataset(root, seed, check_rig(factory(seed).describe()))  # atomic: one seed a dir
    with recording_into(root):  # a check meanwhile sees a recorder at work
        set_aside = set_aside_stale_parts(root)
        if not durable:
            set_aside += set_aside_cut_short(root)
        before = set(incomplete_files(root))
        n_jobs = 1 if is_exclusive(factory) else workers or os.cpu_count() or 1
        notify = on_result or (lambda _result: None)
        pending = []
        for task in tasks:
            path = task.path(root)
            if path.exists():
                notify(TaskResult(task, TaskStatus.SKIPPED, path.stat().st_size))
            else:
                pending.append(task)
        skipped = len(tasks) - len(pending)
        failed: list[TaskResult] = []
        parent = os.getpid()
        if n_jobs > 1 and pending:
            check_sendable(factory)
        import joblib  # noqa: PLC0415 (see _LAZY)
        import polars as pl  # noqa: PLC0415

        with cli.workers_ignore_interrupts():  # the call starts the workers; Ctrl-C is ours
            # tasks are handed out lazily: after a failure, none starts
            results = joblib.Parallel(n_jobs=n_jobs, return_as="generator_unordered")(
                joblib.delayed(run_task)(task, root, factory, seed, parent, durable=durable)
                for task in pending
                if not failed
            )
        try:
            for result in results:
                skipped += result.status == TaskStatus.SKIPPED
                if result.status == TaskStatus.FAILED:
                    failed.append(result)
                notify(result)
        except KeyboardInterrupt:  # joblib has killed the workers: their recordings are cut off
            _remove_own_parts(root, before)
            raise
        if failed:
            more = f" ({len(failed) - 1} more recordings failed)" if len(failed) > 1 else ""
            raise RecorderError(failed[0].error + more)
        if not durable and hasattr(os, "sync"):
            os.sync()  # every recording on the disk before the index says the dataset is whole
        declare_objects(root, [task.obj for task in tasks])
        index = write_index(root)
        frame = pl.read_parquet(index, glob=False)  # a path, never a pattern
        return DatasetReport(
            root=root,
            written=len(tasks) - skipped,
            skipped=skipped,
            index=index,
            size_bytes=int(frame["size_bytes"].sum()),
            incomplete=incomplete_files(root),
            set_aside=set_aside,
        )


def _metadata_of(path: Path) -> RecordingMetadata:
    """Return the metadata record of a finished recording (nothing else is read).

    Raises:
        RecorderError: The file cannot be read or has no valid metadata record.
    """
    try:
        with path.open("rb") as stream:
            records = {r.name: r.metadata for r in make_reader(stream).iter_metadata()}
        return parse_metadata(records[METADATA_NAME])
    except OSError as err:
        raise RecorderError(unreadable(path, err)) from err
    except (McapError, ContractError, KeyError, ValueError, EOFError, struct.error) as err:
        msg = f"{path}: not a readable recording ({err}); check it with 'atikt-replay check'"
        raise RecorderError(msg) from err


def first_metadata(root: Path) -> tuple[Path, RecordingMetadata] | None:
    """Return the first recording under ``root`` whose metadata reads, and its metadata."""
    for path in dataset_recordings(root) if Path(root).is_dir() else []:
        with contextlib.suppress(RecorderError):
            return path, _metadata_of(path)
    return None


def _configuration(rig: Mapping[str, object]) -> dict[str, object]:
    """Return a rig description without what the rig learned on connecting (``fact:...``).

    The rig's identity in a dataset is its configuration; a controller's version is recorded
    in every file but is not known before connecting, so it is never compared.
    """
    return {k: v for k, v in check_rig(rig).items() if not k.startswith(FACT_PREFIX)}


def check_configuration(root: Path, seed: int, factory: RigFactory) -> None:
    """Refuse to record into a dataset whose recordings have another seed or rig configuration.

    One dataset holds one seed and one rig configuration; the first readable recording stands
    for the dataset (an unreadable one is left to the index, which names it).

    Raises:
        RecorderError: The seeds or rig descriptions differ; the message names both and the fix.
    """
    rig = _configuration(factory(seed).describe())  # a bad rig option fails before any worker
    found = first_metadata(root)
    if found is None:
        return
    existing, meta = found
    if meta.seed != seed:
        msg = (
            f"{root}: holds recordings of seed {meta.seed} (e.g. {existing}), this run has "
            f"--seed {seed}; a dataset holds one seed: give another --out, or --seed "
            f"{meta.seed} to resume it"
        )
        raise RecorderError(msg)
    theirs_rig = _configuration(meta.rig)
    if differ := differing_settings(theirs_rig, rig):
        if "kind" in differ:  # another rig altogether: its kind says it, not every setting
            differ = ["kind"]
        theirs = ", ".join(f"{k}={theirs_rig.get(k)!r}" for k in differ)
        wanted = ", ".join(f"{k}={rig.get(k)!r}" for k in differ)
        msg = (
            f"{root}: holds recordings of another rig configuration ({theirs}; this run: "
            f"{wanted}, e.g. {existing}); give another --out"
        )
        raise RecorderError(msg)


def _topic_column(topic: str) -> str:
    """Return the index column counting a topic's messages, e.g. ``n_force``."""
    return "n_" + topic.rsplit("/", 1)[-1]


#: The index's columns and their types (polars' type names; see :func:`_index_schema`).
_INDEX_COLUMNS: dict[str, str] = {
    "path": "String",
    "object_id": "String",
    "object_name": "String",
    "action_id": "String",
    "action_kind": "String",
    "trial": "Int64",
    "seed": "Int64",
    "rig": "String",
    "source": "String",
    "software_version": "String",
    "schema_version": "Int64",
    "size_bytes": "Int64",
    "sha256": "String",
    "start_ns": "Int64",
    "end_ns": "Int64",
    "duration_ns": "Int64",
    "messages": "Int64",
} | {_topic_column(channel.topic): "Int64" for channel in CHANNELS}


def _index_schema() -> dict[str, Any]:
    """Return the index's polars schema (polars is imported here, see :data:`_LAZY`)."""
    import polars as pl  # noqa: PLC0415

    return {name: getattr(pl, kind) for name, kind in _INDEX_COLUMNS.items()}


def _summary_row(path: Path, data: bytes) -> dict[str, Any]:
    """Return the index fields found in a recording's metadata record and statistics."""
    reader = make_reader(io.BytesIO(data))
    summary = reader.get_summary()
    records = {record.name: record.metadata for record in reader.iter_metadata()}
    if summary is None or summary.statistics is None or METADATA_NAME not in records:
        msg = f"{path}: no summary or no {METADATA_NAME!r} record; not a finished recording"
        raise RecorderError(msg)
    try:
        meta = parse_metadata(records[METADATA_NAME])
    except ContractError as err:
        msg = f"{path}: metadata record: {err}; check the file with 'atikt-replay check'"
        raise RecorderError(msg) from err
    stats = summary.statistics
    counts = {
        channel.topic: stats.channel_message_counts.get(channel.id, 0)
        for channel in summary.channels.values()
    }
    legacy = VOCABULARY.legacy.get(meta.schema_version)
    renamed = legacy.topics if legacy is not None else {}
    counts = {renamed.get(topic, topic): count for topic, count in counts.items()}
    return {
        "object_id": meta.object_id,
        "object_name": meta.object_name,
        "action_id": meta.action_id,
        "action_kind": meta.action_kind,
        "trial": meta.trial,
        "seed": meta.seed,
        "rig": str(meta.rig.get("kind", "")),
        _IDENTITY: rig_identity(meta.rig),
        "source": meta.source,
        "software_version": meta.software_version,
        "schema_version": meta.schema_version,
        "start_ns": stats.message_start_time,
        "end_ns": stats.message_end_time,
        "duration_ns": stats.message_end_time - stats.message_start_time,
        "messages": stats.message_count,
    } | {_topic_column(c.topic): counts.get(c.topic, 0) for c in CHANNELS}


#: A row's key (not an index column) for :func:`rig_identity`.
_IDENTITY = "rig_identity"
#: What identifies an imported rig within a dataset: its skin's cells and channel widths. The
#: bags, the map's file name and its stamps differ between imports of one rig.
IMPORTED_IDENTITY = ("cells", "widths")


def rig_identity(rig: Mapping[str, object]) -> str:
    """Return what one dataset's recordings share of their rig description, one line.

    A recorded dataset's whole configuration is compared before it records
    (:func:`check_configuration`); bags of several rigs imported into one directory are
    compared here: two skins of other cells or widths make one dataset of nothing.
    """
    kind = str(rig.get("kind", ""))
    if kind != "imported":
        return kind
    return ", ".join([kind, *(f"{key}={rig.get(key, '')}" for key in IMPORTED_IDENTITY)])


def index_row(root: Path, path: Path) -> dict[str, Any]:
    """Return the index row of one recording.

    Raises:
        RecorderError: The file cannot be read or is not a finished recording.
    """
    try:
        data = path.read_bytes()
        row = _summary_row(path, data)
    except OSError as err:
        raise RecorderError(unreadable(path, err)) from err
    except (McapError, ValueError, KeyError, EOFError, struct.error) as err:
        msg = f"{path}: not a readable recording ({err}); delete it and record it again"
        raise RecorderError(msg) from err
    location = {"path": path.relative_to(root).as_posix()}
    content = {"size_bytes": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    return location | row | content


#: A dataset's object declarations: id, name, description and the default role (``novel``).
OBJECTS_FILE = "objects.toml"


_OBJECTS_HEADER = b"# Objects of this dataset; novel = true: new by default.\n"


def objects_toml(objects: Iterable[ObjectSpec]) -> bytes:
    """Return the ``objects.toml`` declarations of ``objects`` (sorted by id).

    Written by a TOML writer (tomli-w: keys quoted where TOML needs it, so ids such as
    ``oak+1`` or ``oak.v2`` stay one key), never by string formatting.

    Raises:
        ContractError: An id breaks the id rule.
    """
    table = {
        check_id("object", o.id): {"name": o.name, "description": o.description, "novel": o.novel}
        for o in sorted(objects, key=lambda o: o.id)
    }
    return _OBJECTS_HEADER + tomli_w.dumps(table).encode("utf-8")


def declare_objects(root: Path, objects: Iterable[ObjectSpec]) -> Path:
    """Add objects to ``<root>/objects.toml`` (existing declarations are kept as they are).

    The file says which objects are new by default (``novel``); runs choose roles with
    ``--new``/``--priors``. Written by dataset generation and bag import, read by the replay.

    Raises:
        RecorderError: The file cannot be read or written.
    """
    path = Path(root) / OBJECTS_FILE
    try:
        text = path.read_text("utf-8") if path.exists() else ""
        declared = loads_toml(text)
        objects = list(objects)
        _say_kept(path, declared, objects)
        new = {o.id: o for o in objects if o.id not in declared}
        if not new:
            return path
        body = objects_toml(new.values())
        if text:  # appended below the existing declarations, which stay as they are
            body = text.rstrip("\n").encode("utf-8") + b"\n\n" + body[len(_OBJECTS_HEADER) :]
        atomic_write(path, lambda stream: stream.write(body))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError, ContractError) as err:
        msg = f"{path}: cannot update the object declarations ({err}); fix or delete the file"
        raise RecorderError(msg) from err
    return path


def _say_kept(path: Path, declared: Mapping[str, Any], objects: Sequence[ObjectSpec]) -> None:
    """Say, one line each, where a run names a declared object otherwise (it is kept).

    A declaration is the dataset's: a later map or catalog that renames an object does not
    rename it silently, nor silently fail to.
    """
    for obj in objects:
        table = declared.get(obj.id)
        if not isinstance(table, dict):
            continue
        for key, ours in (("name", obj.name), ("description", obj.description)):
            theirs = table.get(key)
            if isinstance(theirs, str) and theirs != ours:
                print(  # noqa: T201 (a note for the person: nothing fails)
                    f"{path}: [{obj.id}] {key} = {theirs!r} is kept (this run says {ours!r}); "
                    f"edit {path.name} to change it",
                    file=sys.stderr,
                )


def recordings(root: Path) -> list[Path]:
    """Return the finished recordings under ``root``, sorted by path."""
    return dataset_recordings(root)


def incomplete_files(root: Path) -> tuple[Path, ...]:
    """Return temporary files of unfinished recordings under ``root`` (not those set aside)."""
    aside = Path(root) / SET_ASIDE_DIR
    return tuple(
        sorted(p for p in Path(root).rglob(f"*{PART_SUFFIX}") if not p.is_relative_to(aside))
    )


#: How long to wait for killed workers to be gone before their files are removed.
_WORKER_EXIT_S = 5.0


def stale_parts(root: Path) -> tuple[Path, ...]:
    """Return the unfinished recordings under ``root`` whose recorder is not running."""
    return tuple(part for part in incomplete_files(root) if not process_running(part_writer(part)))


def set_aside_stale_parts(root: Path) -> tuple[Path, ...]:
    """Move unfinished recordings whose recorder died to ``<root>/.incomplete/`` (kept).

    A ``.part`` of a recorder that is still running (its process id in the name is alive)
    stays; one of a dead recorder would otherwise be counted as unfinished forever. The
    trial is recorded again by the next dataset run.

    Returns:
        The new paths of the files set aside.

    Raises:
        RecorderError: A file cannot be moved.
    """
    root = Path(root)
    moved = []
    for part in stale_parts(root):
        target = _move_aside(root, part)
        if target is not None:  # None: its recorder finished or removed it meanwhile
            moved.append(target)
    return tuple(moved)


#: errno of a file system that has no hard links.
_NO_LINKS = frozenset({errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.EMLINK})


def _move_aside(root: Path, path: Path) -> Path | None:
    """Move ``path`` to the same place under ``<root>/.incomplete/``, never over a file there.

    A name taken by an earlier file set aside gets ``.1``, ``.2``, ... appended.

    Returns:
        The new path; None if ``path`` was gone.

    Raises:
        RecorderError: The file cannot be moved.
    """
    base = root / SET_ASIDE_DIR / path.relative_to(root)
    try:
        base.parent.mkdir(parents=True, exist_ok=True)
        for attempt in itertools.count():
            target = base.with_name(f"{base.name}.{attempt}") if attempt else base
            try:
                os.link(path, target)
            except FileExistsError:
                continue
            except OSError as err:  # a file system without hard links: a rename to a free name
                if err.errno not in _NO_LINKS:
                    raise
                if target.exists():
                    continue
                path.rename(target)
                return target
            path.unlink(missing_ok=True)
            return target
    except FileNotFoundError:
        return None
    except OSError as err:
        msg = f"{path}: cannot move it to {base.parent} ({err.strerror}); move it by hand"
        raise RecorderError(msg) from err
    return None  # pragma: no cover (the loop returns)


def _cut_short(path: Path) -> bool:
    """Return whether a recording lacks the MCAP magic that ends every finished file."""
    try:
        with path.open("rb") as stream:
            size = stream.seek(0, os.SEEK_END)
            if size < 2 * len(MCAP0_MAGIC):
                return True
            stream.seek(size - len(MCAP0_MAGIC))
            return stream.read(len(MCAP0_MAGIC)) != MCAP0_MAGIC
    except OSError:
        return False  # unreadable: the index names it


def set_aside_cut_short(root: Path) -> tuple[Path, ...]:
    """Move recordings cut short (no closing MCAP magic) to ``<root>/.incomplete/`` (kept).

    Only a dataset written without a sync per file (``generate_dataset(durable=False)``)
    can hold one: a power loss may leave a finished name whose data never reached the disk.
    The trial is recorded again.

    Returns:
        The new paths of the files set aside.

    Raises:
        RecorderError: A file cannot be moved.
    """
    root = Path(root)
    moved = []
    for path in recordings(root):
        if not _cut_short(path):
            continue
        target = _move_aside(root, path)
        if target is not None:
            moved.append(target)
    return tuple(moved)


def _remove_own_parts(root: Path, before: set[Path]) -> None:
    """Remove the cut-off recordings of this run's killed workers (new since ``before``).

    A worker that gets the interrupt removes its temporary file itself; workers killed by
    joblib cannot, so their files (trials recorded again by the next run) are removed here
    once their processes are gone.
    """
    deadline = time.monotonic() + _WORKER_EXIT_S
    for part in set(incomplete_files(root)) - before:
        pid = part_writer(part)
        while process_running(pid) and pid != os.getpid() and time.monotonic() < deadline:
            time.sleep(0.05)
        if not process_running(pid):
            part.unlink(missing_ok=True)


def build_index(root: Path, paths: Iterable[Path] | None = None) -> pl.DataFrame:
    """Return the index of the recordings under ``root`` (one row each, sorted by path).

    Raises:
        RecorderError: A file is not a readable recording.
    """
    root = Path(root)

    rows = [index_row(root, path) for path in (recordings(root) if paths is None else paths)]
    return _frame(rows)


def _frame(rows: Sequence[Mapping[str, Any]]) -> pl.DataFrame:
    """Return the index frame of rows (without their rig identities)."""
    import polars as pl  # noqa: PLC0415 (see _LAZY)

    table = [{k: v for k, v in row.items() if k != _IDENTITY} for row in rows]
    return pl.DataFrame(table, schema=_index_schema())


def _check_one_rig(root: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    """Refuse an index of recordings of several rigs (see :func:`rig_identity`).

    Raises:
        RecorderError: Two identities, each named with a file.
    """
    firsts: dict[str, str] = {}
    for row in rows:
        firsts.setdefault(row[_IDENTITY], row["path"])
    if len(firsts) > 1:
        shown = "; ".join(f"{rig} (e.g. {path})" for rig, path in list(firsts.items())[:2])
        msg = (
            f"{root}: holds recordings of {len(firsts)} different rigs ({shown}); a dataset "
            "holds one rig: move the recordings of one to another directory, then run "
            f"'atikt-record index {root}'"
        )
        raise RecorderError(msg)


def write_index(root: Path) -> Path:
    """Rebuild ``<root>/index.parquet`` from the recordings (atomically replaced).

    Returns:
        The index path.

    Raises:
        RecorderError: A file is not a readable recording, or the index cannot be written.
    """
    import polars as pl  # noqa: PLC0415 (see _LAZY)

    root = Path(root)
    target = root / INDEX_NAME
    try:
        root.mkdir(parents=True, exist_ok=True)
        with _index_lock(root):  # the last writer lists every file linked before it
            rows = [index_row(root, path) for path in recordings(root)]
            _check_one_rig(root, rows)
            index = _frame(rows)
            _check_one_seed(root, index)
            atomic_write(target, index.write_parquet)
    except (OSError, pl.exceptions.PolarsError) as err:
        reason = err.strerror if isinstance(err, OSError) else " ".join(str(err).split())
        msg = (
            f"{target}: cannot write the index ({reason}); check free space and that "
            f"the directory is writable, then run 'atikt-record index {root}'"
        )
        raise RecorderError(msg) from err
    return target


def _check_one_seed(root: Path, frame: pl.DataFrame) -> None:
    """Refuse an index of recordings of several seeds or rig configurations.

    :func:`check_configuration` refuses a run into a dataset of another seed; two runs that
    start at once into an empty dataset both pass it, and are caught here, when they index.

    Raises:
        RecorderError: The recordings have more than one seed or rig description.
    """
    import polars as pl  # noqa: PLC0415 (see _LAZY)

    for column in ("seed", "rig"):
        firsts = frame.group_by(column, maintain_order=True).agg(pl.col("path").first())
        if firsts.height > 1:
            shown = "; ".join(f"{column} {v} (e.g. {p})" for v, p in firsts.head(2).iter_rows())
            msg = (
                f"{root}: holds recordings of {firsts.height} different {column}s ({shown}); "
                f"a dataset holds one: move the recordings of one {column} to another directory"
            )
            raise RecorderError(msg)


@contextlib.contextmanager
def _index_lock(root: Path) -> Iterator[None]:
    """Serialise index rebuilds of one dataset between processes (an advisory lock on ``root``).

    Two runs recording into one dataset both rebuild the index when they finish; under the
    lock the later rebuild lists every recording of both. Without ``fcntl`` (Windows) the
    atomic rename still keeps the index whole, and ``atikt-record index`` refreshes it.
    """
    try:
        import fcntl  # noqa: PLC0415 (POSIX only)
    except ImportError:  # pragma: no cover (Windows)
        yield
        return
    descriptor = os.open(root, os.O_RDONLY)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX)
        yield
    finally:
        os.close(descriptor)  # releases the lock
