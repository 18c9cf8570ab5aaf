"""``atikt-record session``: record actions at a rig, object by object, resumable.

A session records every (action, trial) of one object, then of the next, into the dataset
layout ``<out>/<object>/<action>/<trial>.mcap`` with the dataset's index and object
declarations. Before an object's recordings the rig presents it: a rig that is
:class:`recorder.Presenting` moves the object under the skin when its configuration has a pose
for it (False: a person must place it, and the session asks on the terminal) and says before
anything moves whether it could (an unattended ``--yes`` run). Other rigs (the simulator) need
nobody.

An interrupted session -- Ctrl-C, SIGTERM, SIGKILL, a lost connection, a protective stop --
resumes: recordings on disk are kept and skipped, as ``dataset`` does, unfinished files of dead
recorders are set aside with a line, and a directory of another seed or rig configuration
(the rig's identity is its configuration, not what it learns on connecting) is refused.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from recorder._claim import check_claim, check_writable, claim_dataset
from recorder._dataset import (
    check_configuration,
    declare_objects,
    set_aside_stale_parts,
    stale_parts,
    write_index,
)
from recorder._rig import Presenting, facts, source_stats
from recorder.errors import RecorderError
from recorder.live import ReportingSkin, SensingSkin, SkinFinding
from recorder.runner._limits import check_action
from recorder.runner._record import check_room, record_action
from recorder.runner._runner import ArmRig
from schemas import VOCABULARY, check_rig, recording_into

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence

    from recorder._catalog import ActionSpec, ObjectSpec
    from recorder._dataset import RecordingTask
    from recorder._rig import Rig
    from recorder._rigconfig import RigFactory
    from recorder.runner._viewer import Viewer
    from recorder.writing._writer import WrittenRecording
    from schemas import SourceStats


@dataclass(frozen=True, slots=True)
class SessionReport:
    """What a session did.

    Attributes:
        root: The session's dataset directory.
        written: Recordings made by this run.
        kept: Recordings that were on disk already (an earlier, interrupted run).
        index: The rebuilt index.
    """

    root: Path
    written: int
    kept: int
    index: Path


def refuse_unpresentable(rig: Rig, objects: Sequence[ObjectSpec]) -> None:
    """Refuse an unattended run (``--yes``) with objects the rig cannot bring itself.

    Raises:
        RecorderError: Objects without a pose; one line naming them and the fix.
    """
    if not isinstance(rig, Presenting):
        return
    if missing := [obj.id for obj in objects if not rig.can_present(obj)]:
        msg = (
            f"--yes: the rig has no pose for {', '.join(missing)}; give them a pose in the rig "
            "configuration, or run without --yes to place them by hand"
        )
        raise RecorderError(msg)


def refuse_unrecordable(rig: Rig, actions: Sequence[ActionSpec]) -> None:
    """Refuse actions whose kind needs a skin modality the rig's skin does not deliver.

    The rule is the reader's (:meth:`schemas.KindSpec.missing`): a recording made anyway
    fails ``check``, after the arm did the work. A skin that does not say what it delivers
    (a plug-in) is not checked here.

    Raises:
        RecorderError: One line naming the actions, the modalities they need, the ``[skin]``
            of the configuration file and the fix.
    """
    if not isinstance(rig, ArmRig) or not isinstance(rig.skin, SensingSkin):
        return
    held = rig.skin.modalities
    lacking = [
        (action, missing)
        for action in actions
        if (missing := VOCABULARY.kind(action.kind).missing(held))
    ]
    if lacking:
        needs = "; ".join(
            f"a {action.kind!r} action ({action.id}) needs the skin modality {', '.join(missing)}"
            for action, missing in lacking
        )
        msg = (
            f"{rig.where}: [skin] delivers {', '.join(held) or 'no modality'} only, and {needs}: "
            f"leave {','.join(action.id for action, _ in lacking)} out of --actions, or describe "
            "what they need in [skin] if the skin has it"
        )
        raise RecorderError(msg)


def present(
    rig: Rig, obj: ObjectSpec, *, unattended: bool, ask: Callable[[str], str], root: Path
) -> None:
    """Bring ``obj`` under the skin: the rig moves there, or a person places it.

    Raises:
        RecorderError: Unattended and the rig cannot present it, or the prompt ended (EOF,
            Ctrl-C); the message says that recordings are kept and how to resume.
    """
    if not isinstance(rig, Presenting) or rig.present(obj):
        return
    if unattended:
        msg = f"--yes: the rig could not present {obj.id}; give it a pose or run without --yes"
        raise RecorderError(msg)
    try:
        ask(f"place {obj.name} ({obj.id}), then Enter ")
    except (EOFError, KeyboardInterrupt) as err:
        msg = (
            f"session stopped at the prompt for {obj.id}; the recordings made are kept in "
            f"{root}; run the same command again to resume"
        )
        raise RecorderError(msg) from err


def _finish(root: Path, tasks: Sequence[RecordingTask]) -> Path:
    """Declare the objects recorded so far and rebuild the index."""
    declare_objects(root, [task.obj for task in tasks if task.path(root).exists()])
    return write_index(root)


def _finish_stopped(root: Path, tasks: Sequence[RecordingTask], recorded: int) -> None:
    """Index a stopped session's recordings; one that recorded none leaves no index behind.

    A session refused at connecting (another process holds the arm) recorded nothing: the
    directory stays as it was.
    """
    if recorded:
        with contextlib.suppress(RecorderError):  # the first error is the one to report
            _finish(root, tasks)


def run_session(
    tasks: Sequence[RecordingTask],
    root: Path,
    factory: RigFactory,
    *,
    seed: int,
    unattended: bool = False,
    ask: Callable[[str], str] = input,
    on_recorded: Callable[[RecordingTask, WrittenRecording], Any] | None = None,
    on_set_aside: Callable[[Path], Any] | None = None,
    viewers: Sequence[Viewer] = (),
    on_start: Callable[[RecordingTask], Any] | None = None,
) -> SessionReport:
    """Record ``tasks`` object by object with one rig, skipping recordings on disk.

    Args:
        tasks: The recordings, grouped by object (see :func:`recorder.plan_dataset`).
        root: Dataset directory.
        factory: Makes the rig (one for the whole session, in this process).
        seed: Seed of the rig, written to every file; a directory of another seed is refused.
        unattended: Never ask a person: every object must be presentable by the rig.
        ask: Shows a prompt and waits for Enter (``input``).
        on_recorded: Called after every recording.
        on_set_aside: Called with each unfinished file of a dead recorder that was set aside.
        viewers: Live views of every action (they never block).
        on_start: Called before each recording begins (the object presented first).

    Returns:
        What was written and kept, and the index.

    Raises:
        RecorderError: Another seed or rig configuration in ``root``, an action the rig's skin
            cannot record or an object without a pose when unattended (before anything
            moves), a stopped prompt, or a failed recording; the recordings finished are kept
            and indexed.
    """
    root = Path(root)
    check_configuration(root, seed, factory)
    # before the claim: a run refused for its skin leaves the directory as it found it
    refuse_unrecordable(
        factory(seed), list({task.action.id: task.action for task in tasks}.values())
    )
    claim_dataset(root, seed, check_rig(factory(seed).describe()))  # atomic: one seed a dir
    with recording_into(root):  # a check meanwhile sees a recorder at work
        for moved in set_aside_stale_parts(root):
            if on_set_aside is not None:
                on_set_aside(moved)
        pending = [task for task in tasks if not task.path(root).exists()]
        by_object: dict[str, list[RecordingTask]] = {}
        for task in pending:
            by_object.setdefault(task.obj.id, []).append(task)
        rig = factory(seed)
        if unattended:
            refuse_unpresentable(rig, [group[0].obj for group in by_object.values()])
        recorded = 0
        try:
            with rig:
                for group in by_object.values():
                    present(rig, group[0].obj, unattended=unattended, ask=ask, root=root)
                    for task in group:
                        path = task.path(root)
                        if on_start is not None:
                            on_start(task)
                        written = record_action(
                            rig, task.obj, task.action, task.trial, path, seed=seed, viewers=viewers
                        )
                        recorded += 1
                        if on_recorded is not None:
                            on_recorded(task, written)
        except BaseException:
            _finish_stopped(root, tasks, recorded)
            raise
        return SessionReport(root, len(pending), len(tasks) - len(pending), _finish(root, tasks))


#: How long a dry run reads the arm and the skin, s (action time).
DRY_RUN_S = 1.0
#: A source that sent none of this many samples due in a dry run is not ready.
DUE_SAMPLES = 3


@dataclass(frozen=True, slots=True)
class RigCheck:
    """What a rig showed before anything moved (a dry run of ``session`` or ``learn``).

    Attributes:
        by_rig: Objects the rig would present (in the run's order).
        by_hand: Objects a person would place.
        facts: What the rig learned on connecting (e.g. the controller's version).
        sources: The accounting of the arm's and the skin's sources over the check.
        window_ns: How long the streams were watched, on the recorder's clock (0: unknown).
        findings: What the skin counted and left out over the check that needs a fix
            (another sender, a frame type off its ``rate_hz``, malformed frames); a blocking
            one makes the rig not ready.
        origins: Where each source's samples came from, by source name (the skin's sender).
    """

    by_rig: tuple[str, ...]
    by_hand: tuple[str, ...]
    facts: Mapping[str, str]
    sources: tuple[SourceStats, ...]
    window_ns: int = 0
    findings: tuple[SkinFinding, ...] = ()
    origins: Mapping[str, str] = field(default_factory=dict)

    @property
    def lossy(self) -> tuple[str, ...]:
        """The sources that lost samples during the check (their recordings would fail)."""
        return tuple(source.name for source in self.sources if source.lost)

    @property
    def silent(self) -> tuple[str, ...]:
        """The sources that sent nothing though their rate says they should have.

        At least :data:`DUE_SAMPLES` of their samples were due in the check (a frame type the
        skin does not send, a sensor unplugged).
        """
        due = DUE_SAMPLES
        return tuple(s.name for s in self.sources if not s.received and self._due(s) >= due)

    @property
    def ready(self) -> bool:
        """Whether the run's recordings could pass ``check`` and hold what the skin sent.

        No loss, no silent source, and no blocking finding (frames of two senders at the
        skin's port, a frame type off its ``rate_hz``): ``check`` cannot see those.
        """
        blocked = any(finding.blocking for finding in self.findings)
        return not self.lossy and not self.silent and not blocked

    def _due(self, source: SourceStats) -> float:
        """Samples of ``source`` due in the check by its nominal period (0: unknown)."""
        return self.window_ns / source.period_ns if source.period_ns > 0 else 0.0

    def lines(self) -> list[str]:
        """The check, said: who presents the objects, whether the rig is ready, each source.

        A source that sent nothing is refused when its rate says that the check should have
        seen some of its samples; otherwise it is said, not refused: one slower than the check
        (a thermal sensor at 0.5 Hz) sends nothing in it. Each source says where its samples
        came from when it is known (the skin's sender); the skin's findings follow, one line
        each.
        """
        learned = ", ".join(f"{key} {value}" for key, value in self.facts.items())
        wrong = [f"{', '.join(self.lossy)} lost samples"] if self.lossy else []
        malformed = {s.name for s in self.sources if not s.received and s.malformed}
        if nothing := [name for name in self.silent if name not in malformed]:
            wrong.append(f"{', '.join(nothing)} sent nothing")
        if garbled := [name for name in self.silent if name in malformed]:
            wrong.append(f"{', '.join(garbled)} sent only malformed frames")
        wrong += [finding.short for finding in self.findings if finding.blocking]
        state = f"not ready: {'; '.join(wrong)}" if wrong else "ready"
        objects = (
            f"objects presented by the rig: {', '.join(self.by_rig) or '-'}; placed by hand: "
            f"{', '.join(self.by_hand) or '-'}"
        )
        lines = [
            objects,
            f"rig: {state}{f' ({learned})' if learned else ''}",
        ]
        for source in self.sources:
            said = source.problems() or "complete"
            if not source.received and source.malformed:
                said = (
                    f"{source.problems()}: what arrives does not match the rig configuration's "
                    "[skin] layout (cells, frame sizes, byte order); check it against the skin"
                )
            elif not source.received:
                said = "nothing in the check's second (a source that slow is not checked here)"
                if (due := self._due(source)) >= DUE_SAMPLES:
                    said = f"nothing, {due:.0f} due at its rate: check it and its configuration"
            origin = self.origins.get(source.name)
            whence = f" from {origin}" if origin and source.received else ""
            lines.append(f"  {source.name}: {source.received} received{whence}, {said}")
        lines += [finding.line for finding in self.findings]
        return lines


@dataclass(frozen=True, slots=True)
class SessionCheck:
    """What a session would do and what the rig showed, found moving and writing nothing.

    Attributes:
        root: The session's dataset directory.
        to_record: Recordings the session would make.
        kept: Recordings on disk that it would keep and skip.
        stale: Unfinished files of dead recorders it would set aside.
        rig: What the rig showed.
    """

    root: Path
    to_record: int
    kept: int
    stale: tuple[Path, ...]
    rig: RigCheck


def check_rig_ready(
    factory: RigFactory,
    seed: int,
    objects: Sequence[ObjectSpec],
    actions: Sequence[ActionSpec],
    room: Path,
    *,
    unattended: bool = False,
    seconds: float = DRY_RUN_S,
) -> RigCheck:
    """Check a rig as a run would before its first action, moving nothing, writing nothing.

    Who presents each object (``unattended``: every object needs a pose), every action against
    the limits, the room on ``room``'s disk, then, connected, the arm's state before an action
    (:meth:`recorder.runner.ArmRig.check_ready`) and ``seconds`` of the arm's and the skin's
    streams under every check an action runs.

    Raises:
        RecorderError: What the run would refuse, or a check of the rig failed; one line.
    """
    rig = factory(seed)
    if unattended:
        refuse_unpresentable(rig, objects)
    refuse_unrecordable(rig, actions)
    # a rig that does not present (the simulator) needs nobody: every object is the rig's
    by_rig = [o.id for o in objects if not isinstance(rig, Presenting) or rig.can_present(o)]
    window_ns = 0
    findings: tuple[SkinFinding, ...] = ()
    origins: dict[str, str] = {}
    with rig:
        if isinstance(rig, ArmRig):
            for action in actions:
                check_action(action, rig.limits, rig.where)
                for obj in objects:  # a press or a slide the workspace has no room for
                    rig.check_plan(obj, action)
            check_room(room)
            rig.check_ready()
            rig.watch(seconds)
            window_ns = round(seconds * rig.options.time_scale * 1e9)  # as watch() counts it
            if isinstance(rig.skin, ReportingSkin):
                findings = tuple(rig.skin.findings())
                if origin := rig.skin.origin():
                    origins = {source.name: origin for source in rig.skin.stats()}
        learned = dict(facts(rig))
        sources = tuple(source_stats(rig))
    by_hand = tuple(o.id for o in objects if o.id not in by_rig)
    return RigCheck(tuple(by_rig), by_hand, learned, sources, window_ns, findings, origins)


def check_session(
    tasks: Sequence[RecordingTask],
    root: Path,
    factory: RigFactory,
    *,
    seed: int,
    unattended: bool = False,
    seconds: float = DRY_RUN_S,
) -> SessionCheck:
    """Check everything a session would, moving nothing and writing nothing (``--dry-run``).

    The directory's seed and rig configuration, then the rig as :func:`check_rig_ready`
    checks it for the objects and actions still to record.

    Raises:
        RecorderError: What the session would refuse, or a check of the rig failed; one line.
    """
    root = Path(root)
    check_configuration(root, seed, factory)
    check_claim(root, seed, check_rig(factory(seed).describe()))
    check_writable(root)  # the run's first write is its claim: refused there as it would be
    pending = [task for task in tasks if not task.path(root).exists()]
    objects = list({task.obj.id: task.obj for task in pending}.values())
    actions = list({task.action.id: task.action for task in pending}.values())
    found = check_rig_ready(
        factory, seed, objects, actions, root, unattended=unattended, seconds=seconds
    )
    return SessionCheck(
        root,
        len(pending),
        len(tasks) - len(pending),
        stale_parts(root) if root.exists() else (),
        found,
    )
