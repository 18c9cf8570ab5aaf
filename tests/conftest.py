"""Shared fixtures: a fake rig that streams synthetic signals, and small recordings.

The fake rig stands in for hardware (and for the simulator) in tests of the writer, the
dataset generation and the reader: its signals are seeded noise shaped like the contract's
channels, with a short last block per channel so uneven blocks are exercised.
"""

from __future__ import annotations

import contextlib
import fcntl
import gc
import itertools
import os
import shutil
import signal
import tempfile
import threading
import zlib
from pathlib import Path
from typing import TYPE_CHECKING, Self

import forked
import numpy as np
import ports  # noqa: F401 (claims this worker's own ports before a test starts a process)
import pytest
from threadpoolctl import threadpool_limits

from recorder import (
    ActionSpec,
    JointSample,
    Modality,
    Phase,
    PhaseEvent,
    PoseSample,
    SkinBlock,
    StreamItem,
    generate_dataset,
    load_actions,
    load_objects,
    plan_dataset,
    rig_factory,
)
from recorder._catalog import ObjectSpec
from recorder.runner._record import record_action
from schemas import CHANNELS, VOCABULARY, cli

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator, Mapping
    from types import TracebackType

#: Cyclone DDS restricted to the loopback interface, no multicast, one peer: 127.0.0.1. Set
#: when pytest loads this file, before any test imports ``cyclonedds`` (which reads it when
#: the first participant is created); ``dds_domain`` checks it is still in force.
LOOPBACK_URI = (
    '<CycloneDDS><Domain><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
    "<AllowMulticast>false</AllowMulticast></General><Discovery><Peers>"
    '<Peer address="127.0.0.1"/></Peers><ParticipantIndex>auto</ParticipantIndex>'
    "</Discovery></Domain></CycloneDDS>"
)
os.environ["CYCLONEDDS_URI"] = LOOPBACK_URI
#: A shell starts a command run in the background (``pytest &``, ``nohup``) with Ctrl-C ignored,
#: and an ignored signal stays ignored in Python and in every process it starts: the tests that
#: press Ctrl-C (on this process or on a command they run) would see nothing happen. The tests
#: run as at a terminal.
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)
#: rich wraps what the commands print at the console width, 80 columns when the output is not
#: a terminal; the temporary paths of pytest-xdist's workers (``.../popen-gw0/...``) are long
#: enough to wrap a line a test looks for, so the tests' consoles (and their subprocesses') are
#: wide.
os.environ["COLUMNS"] = "400"
#: The tests start a few hundred Python processes (every command as a lab types it, the virtual
#: lab, the benchmarks' quick modes); where the environment says PYTHONDONTWRITEBYTECODE, each
#: would compile this project's modules from source again (about 0.2 s of a core per start).
#: Their bytecode goes to a cache of the tests' own outside the checkout and site-packages
#: (PYTHONPYCACHEPREFIX), checked against each source's size and time as usual; the xdist
#: workers, started after this file is read, and every subprocess inherit it.
PYCACHE = Path(tempfile.gettempdir()) / f"atikt-tests-pycache-{os.getuid()}"
os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
os.environ.setdefault("PYTHONPYCACHEPREFIX", str(PYCACHE))
#: OpenBLAS runs a process's matrix products on a thread per core, and its threads spin on
#: between products; with two xdist workers per core (below) the spinning threads of one
#: worker took the cores the other workers' tests needed: tests/atikt and test_studies.py used
#: 62-72 s of CPU under -n auto with the default threads, 30 s with one. The learner's
#: matrices are small, and the replay tool already computes them on one thread (see
#: replay.learning._session): the tests, their workers and the commands they start do too.
#: This process loaded numpy before this line: its BLAS is limited through threadpoolctl.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
threadpool_limits(limits=int(os.environ["OPENBLAS_NUM_THREADS"]), user_api="blas")

NS = 1_000_000_000
_CHANNELS_PER_CELL = {
    "force": 3,
    "temperature": 1,
    "acceleration": 3,
    "proximity": 1,
}
_TOPICS = {
    "force": "/skin/force",
    "temperature": "/skin/temperature",
    "acceleration": "/skin/acceleration",
    "proximity": "/skin/proximity",
}
CELLS = 7


def _channel(topic: str) -> tuple[int, int]:
    """Return (period_ns, block_samples) of a contract topic."""
    channel = next(c for c in CHANNELS if c.topic == topic)
    return round(NS / channel.rate_hz), channel.block_samples


class FakeRig:
    """A rig streaming seeded synthetic signals; ``fail_after`` raises after that many items."""

    def __init__(self, seed: int = 0, time_scale: float = 0.1, fail_after: int | None = None):
        self.seed = seed
        self.time_scale = time_scale
        self.fail_after = fail_after
        self.connected = False

    def __enter__(self) -> Self:
        self.connected = True
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.connected = False

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(f"joint_{i}" for i in range(6))

    def describe(self) -> Mapping[str, str]:
        return {"kind": "fake", "seed": str(self.seed), "time_scale": str(self.time_scale)}

    def phases(self, action: ActionSpec) -> list[tuple[Phase, int]]:
        durations = [0.5, 0.2, action.duration_s * self.time_scale, 0.3]
        starts, t = [], 2 * NS
        for phase, duration in zip(
            ("approach", "contact", "execute", "retract"), durations, strict=True
        ):
            starts.append((phase, t))
            t += round(duration * NS)
        starts.append(("end", t))
        return starts

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        key = [self.seed, trial, zlib.crc32(obj.id.encode()), zlib.crc32(action.id.encode())]
        rng = np.random.default_rng(key)
        phases = self.phases(action)
        start, stop = phases[0][1], phases[-1][1]
        items: list[StreamItem] = [PhaseEvent(t, t, phase) for phase, t in phases]
        for modality in VOCABULARY.modalities:
            items += self._skin(rng, modality, start, stop)
        items += self._robot(rng, start, stop)
        items.sort(key=lambda item: item.receive_ns)
        for count, item in enumerate(items):
            if self.fail_after is not None and count >= self.fail_after:
                msg = "fake rig failure"
                raise RuntimeError(msg)
            yield item

    def _skin(
        self, rng: np.random.Generator, modality: Modality, start: int, stop: int
    ) -> list[StreamItem]:
        period, block = _channel(_TOPICS[modality])
        n = (stop - start) // period
        shape = (n, CELLS, _CHANNELS_PER_CELL[modality])
        data = (rng.normal(1.0, 0.5, shape) + np.arange(CELLS)[None, :, None]).astype(np.float32)
        blocks: list[StreamItem] = []
        for first in range(0, n, block):
            chunk = data[first : first + block]
            stamp = start + first * period
            receive = stamp + (len(chunk) - 1) * period + 1_000_000
            blocks.append(SkinBlock(modality, stamp, period, receive, chunk))
        return blocks

    def _robot(self, rng: np.random.Generator, start: int, stop: int) -> list[StreamItem]:
        period, _ = _channel(VOCABULARY.robot["joint_states"].topic)
        items: list[StreamItem] = []
        for stamp in range(start, stop, period):
            q = rng.normal(0.0, 1.0, 18)
            items.append(JointSample(stamp, stamp + 500_000, q[:6], q[6:12], q[12:]))
            orientation = rng.normal(0.0, 1.0, 4)
            orientation /= np.linalg.norm(orientation)
            items.append(PoseSample(stamp, stamp + 600_000, rng.normal(0, 1, 3), orientation))
        return items


def fake_objects() -> dict[str, ObjectSpec]:
    """Return a tiny object catalog: one old and one new object."""
    return {
        "wood": ObjectSpec("wood", "Wooden board", "a board of beech", novel=False),
        "sponge": ObjectSpec("sponge", "Soft sponge", "a soft yellow sponge", novel=True),
    }


@pytest.fixture(scope="session")
def actions() -> dict[str, ActionSpec]:
    return load_actions()


@pytest.fixture(scope="session")
def objects() -> dict[str, ObjectSpec]:
    return fake_objects()


@pytest.fixture(scope="session")
def fake_recording(
    tmp_path_factory: pytest.TempPathFactory,
    actions: dict[str, ActionSpec],
    objects: dict[str, ObjectSpec],
) -> Path:
    """One recording of the fake rig (S2 on the sponge, trial 3), shared by the tests."""
    path = tmp_path_factory.mktemp("recording") / "sponge" / "S2" / "003.mcap"
    with FakeRig(seed=7) as rig:
        record_action(rig, objects["sponge"], actions["S2"], 3, path, seed=7)
    return path


#: A small simulated dataset for the replay engine's tests: old objects (priors), new objects,
#: actions and trials per (object, action).
OLD = ("metal_toolbox", "soft_sponge", "wood")
NEW = ("aluminium_plate", "foam_block", "pine_board")
ACTIONS = ("P1", "S2")
TRIALS = 5


def shared_directory(
    tmp_path_factory: pytest.TempPathFactory, name: str, build: Callable[[Path], object]
) -> Path:
    """Return directory ``name``, built once per test run by ``build`` and shared read-only.

    Under pytest-xdist every worker has its own session fixtures; the directory lies in the
    run's temporary root, which the workers share, and the first worker to take its lock builds
    it (into a scratch name, renamed when complete), so that the others wait and reuse it.
    """
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    done = root / name
    with (root / f"{name}.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not done.exists():
            scratch = Path(tempfile.mkdtemp(prefix=f"{name}-", dir=root))
            build(scratch)
            scratch.rename(done)
    return done


def _record_small_dataset(directory: Path) -> None:
    """Record :data:`OLD` + :data:`NEW` x :data:`ACTIONS` x :data:`TRIALS` (sim rig, seed 0)."""
    tasks = plan_dataset(
        load_objects(), load_actions(), object_ids=[*OLD, *NEW], action_ids=ACTIONS, trials=TRIALS
    )
    generate_dataset(tasks, directory / "dataset", rig_factory("sim"), seed=0, workers=1)


def copy_dataset(shared: Path, copy: Path) -> Path:
    """Copy a shared dataset to ``copy`` for a test that changes it; return ``copy``.

    Another worker may be writing the dataset's feature cache meanwhile (a temporary file,
    renamed when complete): a copy leaves such temporary files out rather than fail on one
    that was renamed between the listing and its copy.
    """
    shutil.copytree(shared, copy, ignore=shutil.ignore_patterns("*.tmp"))
    return copy


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Record 6 objects x 2 actions x 5 trials with the simulated rig (seed 0), once per run.

    Shared by every test (and xdist worker): tests must not change it (copy it first).
    """
    return shared_directory(tmp_path_factory, "small", _record_small_dataset) / "dataset"


#: DDS domain ids a test may take (Cyclone's default port mapping reaches 232).
_DOMAINS = 230
_domains_taken = itertools.count()


def _take_dds_domain() -> int:
    """Return a DDS domain id no other test of this run has taken (until the ids run out).

    A domain shared with another test would let a publisher that is still shutting down (the
    virtual lab of the test before) put its samples into this test's topics. The run (the
    pytest process that started the workers) picks a base; each worker has its own slice of
    the ids and hands them out in turn.
    """
    assert os.environ["CYCLONEDDS_URI"] == LOOPBACK_URI
    worker = os.environ.get("PYTEST_XDIST_WORKER", "gw0")
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    run = os.getppid() if "PYTEST_XDIST_WORKER" in os.environ else os.getpid()
    size = _DOMAINS // max(workers, 1)
    index = int(worker.removeprefix("gw") or 0) * size + next(_domains_taken) % size
    return 1 + (run + index) % _DOMAINS


@pytest.fixture
def dds_domain() -> int:
    """Return a DDS domain id of this test's own."""
    return _take_dds_domain()


@pytest.fixture(scope="module")
def module_dds_domain() -> int:
    """Return a DDS domain id of this module's own (for its module-scoped fixtures)."""
    return _take_dds_domain()


@pytest.fixture(autouse=True)
def _no_virtual_lab_left_ticking() -> Iterator[None]:
    """Fail a test that leaves a virtual lab's world ticking (``with world:`` ends it).

    A world left ticking computes 125-500 controller cycles a second for the rest of the run
    and starves the real-time tests that come after it.
    """
    yield
    ticking = [t for t in threading.enumerate() if t.name == "atikt-vlab"]
    if not ticking:
        return
    gc.collect()  # a world only in a reference cycle: its thread ends at its next tick
    for thread in ticking:
        thread.join(1.0)
    left = [t for t in ticking if t.is_alive()]
    assert not left, f"{len(left)} virtual lab world(s) left ticking: use `with world:`"


def _proc_file(path: str, *, whole: bool = False) -> bytes:
    """Return a /proc file's bytes (its first read, or all of it when ``whole``)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        data = os.read(fd, 4096)
        while whole and (more := os.read(fd, 65536)):
            data += more
        return data
    finally:
        os.close(fd)


def _labs_started_here() -> list[int]:
    """Return the live ``serve-sim`` processes this process started (its children, forks too).

    It runs after every test and reads two files of every process of the machine: with plain
    reads, half the CPU of pathlib's (0.6 ms instead of 1.2 ms a test among 80 processes).
    """
    found = []
    me = os.getpid()
    for entry in Path("/proc").iterdir():
        name = entry.name
        if not name.isdigit():
            continue
        try:
            stat = _proc_file(f"/proc/{name}/stat").rsplit(b")", 1)[1].split()
            if stat[0] == b"Z" or int(stat[1]) != me:
                continue
            # a fork's cmdline is the fork server's: its command is in forked.STARTED
            command = " ".join(forked.STARTED.get(int(name), ())).encode()
            if b"serve-sim" in (command or _proc_file(f"/proc/{name}/cmdline", whole=True)):
                found.append(int(name))
        except OSError:  # ended meanwhile
            continue
    return found


@pytest.fixture(autouse=True)
def _no_lab_process_left_running() -> Iterator[None]:
    """Fail a test that leaves a ``serve-sim`` it started running (it is killed).

    A lab left running ticks its world for the rest of the run (5000 cycles a second at 500 Hz
    and time scale 0.1) and slows every test after it.
    """
    yield
    left = _labs_started_here()
    for pid in left:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    assert not left, f"serve-sim process(es) {left} left running (killed): stop them"


@pytest.fixture(autouse=True)
def _signal_handlers_restored() -> Iterator[None]:
    """Fail a test that leaves SIGINT, SIGTERM, SIGHUP, SIGTSTP or SIGCONT handled otherwise.

    A Ctrl-C handler left ignored (or deferred) makes a later test's interrupt vanish: the
    test that sends it fails, far from the test that caused it. The handlers are put back.
    """
    numbers = (*cli.ENDING_SIGNALS, signal.SIGTSTP, signal.SIGCONT)  # an arm's too
    before = {number: signal.getsignal(number) for number in numbers}
    yield
    changed = {n: h for n in numbers if (h := signal.getsignal(n)) is not before[n]}
    for number in changed:
        signal.signal(number, before[number])
    assert not changed, f"handlers left changed: {changed} (were {before})"


@pytest.fixture
def suspend_caught() -> Iterator[None]:
    """SIGTSTP (Ctrl-Z) handled by a no-op for the test, never the default (suspend).

    A test sending Ctrl-Z to its own process sees it taken by the code under test; if that
    code does not take it, the no-op does, and the test fails instead of stopping the tests.
    """
    previous = signal.signal(signal.SIGTSTP, lambda *_: None)
    try:
        yield
    finally:
        signal.signal(signal.SIGTSTP, previous)


@pytest.fixture
def hangup_not_ignored() -> Iterator[None]:
    """SIGHUP at its default for the test (``nohup`` starts the tests with it ignored).

    A command handles SIGHUP only where it is not ignored (under ``nohup`` a run outlives its
    terminal); a test that sends SIGHUP to see it handled needs it not ignored.
    """
    previous = signal.signal(signal.SIGHUP, signal.SIG_DFL)
    try:
        yield
    finally:
        signal.signal(signal.SIGHUP, previous)


#: pytest-xdist workers per core under ``-n auto`` (addopts), and one more.
WORKERS_PER_CORE = 2


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int:  # noqa: ARG001 (the hook's)
    """Run two workers per core and one more: much of the suite's time is spent waiting.

    The live tests run the virtual lab and the recorder at the controller's pace (sessions,
    listen, the manual's walk-throughs); with one worker per core the 2-core machine was busy
    at 103 % of one core in a 300 s run, and with two per core the same run took 195-200 s at
    183 %. With the slow tests dealt to two of them (:func:`deal_slow_tests`), two workers
    waiting on real time left the cores idle a fifth of the run (1.6 cores busy); a fifth
    worker fills it (docs/performance.md has the runs). The live tests' configurations allow
    for a loaded machine; ``-n 2`` gives one worker per core again.
    """
    return WORKERS_PER_CORE * (os.cpu_count() or 1) + 1


#: Seconds a test marked ``slow`` without a figure is taken to last.
SLOW_S = 5.0
#: Workers the slow tests are dealt to (the others start on the rest of the suite).
SLOW_CHAINS = 2


def _slow_seconds(item: pytest.Item) -> float:
    mark = item.get_closest_marker("slow")
    if mark is None:
        return 0.0
    return float(mark.args[0]) if mark.args else SLOW_S


def first_shares(total: int, workers: int) -> list[int]:
    """How many tests pytest-xdist's worksteal scheduler first hands each worker, in order.

    Its first schedule cuts the collection into contiguous shares, ``remaining // workers
    left`` each (``xdist/scheduler/worksteal.py``, ``check_schedule``); an idle worker later
    steals the second half of the longest queue.
    """
    shares = []
    for left in range(workers, 0, -1):
        shares.append(total // left)
        total -= shares[-1]
    return shares


def deal_slow_tests(items: list[pytest.Item], workers: int) -> list[pytest.Item]:
    """Order the tests so that the slow ones run first, dealt to :data:`SLOW_CHAINS` workers.

    Worksteal hands each worker a contiguous share and steals only from a queue's end, so the
    tests at the front of a share stay with its worker. Sorted longest first, every slow test
    had fallen into the first share: one worker ran them one after another (190 s of the
    suite's 198 s, measured with a timeline of each worker) while the others had finished.
    Dealt longest first to the chain with the fewest seconds so far, at the front of the first
    :data:`SLOW_CHAINS` shares, two chains of about half that run beside the rest of the suite.
    Not to every worker: four real-time walk-throughs at once starve each other's controller
    loops on two cores (a robot section stopped on arm silence at load 7). The figures are a
    test's seconds alone on the 2-core machine (``--durations``); they only order the run. The
    order is the same in every worker, as xdist requires.
    """
    slow = sorted(
        (item for item in items if _slow_seconds(item)), key=lambda item: -_slow_seconds(item)
    )
    rest = [item for item in items if not _slow_seconds(item)]
    chains = min(SLOW_CHAINS, workers)
    if chains < 2:
        return slow + rest
    dealt: list[list[pytest.Item]] = [[] for _ in range(chains)]
    load = [0.0] * chains
    for item in slow:
        chain = load.index(min(load))
        dealt[chain].append(item)
        load[chain] += _slow_seconds(item)
    shares = first_shares(len(items), workers)
    if any(len(chain) > share for chain, share in zip(dealt, shares, strict=False)):
        return slow + rest
    ordered: list[pytest.Item] = []
    others = iter(rest)
    for index, share in enumerate(shares):
        front = dealt[index] if index < chains else []
        ordered.extend(front)
        ordered.extend(itertools.islice(others, share - len(front)))
    ordered.extend(others)
    return ordered


@pytest.hookimpl(trylast=True)  # after -k and -m have deselected: the shares of what runs
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Run the slow tests first, in two chains beside the rest (:func:`deal_slow_tests`)."""
    workerinput = getattr(config, "workerinput", None)
    workers = int(workerinput["workercount"]) if workerinput else 1
    items[:] = deal_slow_tests(items, workers)


def pytest_collection_finish(session: pytest.Session) -> None:  # noqa: ARG001 (the hook's)
    """Freeze what the collection made (modules, their data, the items) out of the collector.

    Every full collection of the garbage collector walks every object the process holds, and
    a worker holds the imported libraries and 1,700 collected tests for the whole run: its
    full collections during the tests, and the five pytest runs at its end, walked them each
    time (tests/replay, schemas and atikt in one process: 2.1 s of its 60 s of CPU in full
    collections, 1.4 s frozen). They stay alive to the end anyway; what the tests and
    fixtures make afterwards is collected as usual (``gc.freeze``).
    """
    gc.collect()
    gc.freeze()
