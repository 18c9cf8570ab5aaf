"""The live executor: performs each requested action on a rig, records it, reads it back.

Recordings go straight into the run's session directory (``<session>/<object>/<action>/
<trial>.mcap``) as they are made and are never deleted by the program, whatever happens: a run
that ends early (Ctrl-C, a stop, a lost connection) leaves them for the next run, which
resumes: the learner's decisions are a function of the seed and of the observations, so the
same command asks for the same recordings in the same order, and every one already on disk is
read instead of performed again. ``session.parquet`` lists the recordings in the order they
were used, with their role (``test`` or ``pool``), so that an offline run over the session
(``Split.from_session``) serves exactly the same files. Unfinished files a killed run left
(``.part``) are set aside into ``<session>/.incomplete/`` with a line, as ``atikt-record
session`` does, and their trials recorded again.

Objects are presented as ``atikt-record session`` presents them: a rig that can move to an
object's pose goes there before the first recording of that object after another one; a rig
that could not present a new object is refused before anything moves.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any, Self

import polars as pl

from recorder import Presenting, record_action, recording_path, set_aside_stale_parts
from replay.errors import ReplayError
from replay.learning._executors import SESSION_NAME, Pair, TestSet
from replay.learning._features import file_features
from schemas import atomic_write, lost_samples

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence
    from types import TracebackType

    from atikt import RawFeatures
    from recorder import ActionSpec, ObjectSpec, Rig, Viewer


class LiveExecutor:
    """Performs each requested action on a rig (or reuses its recording), and reads it back."""

    def __init__(
        self,
        rig: Rig,
        objects: Sequence[ObjectSpec],
        actions: Mapping[str, ActionSpec],
        session: Path,
        *,
        seed: int,
        viewers: Sequence[Viewer] = (),
    ) -> None:
        """Store the rig and where to record; nothing is performed before ``__enter__``.

        Args:
            rig: The rig, not yet connected.
            objects: The new objects, in the learner's index order.
            actions: The action catalog.
            session: Where the recordings and ``session.parquet`` go (resumed if it has some).
            seed: The rig's seed, written to every recording.
            viewers: Live views: every item as it arrives, each recording once written (none
                may block).
        """
        self.rig = rig
        self.objects = list(objects)
        self.actions = dict(actions)
        self.session = Path(session)
        self.seed = seed
        self.viewers = tuple(viewers)
        self.made: list[dict[str, Any]] = []
        self.reused = 0
        self._trials: dict[Pair, int] = {}
        self._presented: str | None = None

    def __enter__(self) -> Self:
        """Refuse objects the rig cannot present (before anything moves), then connect.

        Raises:
            ReplayError: The rig has no pose for a new object (one line naming them).
        """
        refuse_unpresented(self.rig, self.objects)
        self.session.mkdir(parents=True, exist_ok=True)
        for moved in set_aside_stale_parts(self.session):  # a killed run's: kept, recorded again
            print(  # noqa: T201 (a note beside the run's step lines)
                f"unfinished recording of a stopped recorder set aside: {moved}", file=sys.stderr
            )
        self.rig.__enter__()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Disconnect the rig and write the manifest of what was used."""
        try:
            self.rig.__exit__(exc_type, exc, tb)
        finally:
            self._write_manifest()

    @property
    def capacity(self) -> None:
        """A rig can always perform another trial: no limit."""
        return None

    def _perform(self, obj: ObjectSpec, action_id: str, role: str) -> Path:
        """Record one more trial of (obj, action), or reuse it from an earlier run; its file."""
        pair = (obj.id, action_id)
        trial = self._trials.get(pair, 0) + 1
        self._trials[pair] = trial
        path = recording_path(self.session, obj.id, action_id, trial)
        if path.exists():
            self.reused += 1
        else:
            self._present(obj)
            path.parent.mkdir(parents=True, exist_ok=True)
            action = self.actions[action_id]
            written = record_action(
                self.rig, obj, action, trial, path, seed=self.seed, viewers=self.viewers
            )
            if lost := lost_samples(written.sources):  # learned from all the same: said now
                print(  # noqa: T201 (a note beside the run's step lines)
                    f"{written.path}: live sources lost samples ({lost}); check fails on it",
                    file=sys.stderr,
                )
        self.made.append(
            {"order": len(self.made), "object_id": obj.id, "action_id": action_id}
            | {"trial": trial, "role": role, "path": path.relative_to(self.session).as_posix()}
        )
        return path

    def _present(self, obj: ObjectSpec) -> None:
        """Bring ``obj`` under the skin when another object was there (rigs that can)."""
        if self._presented == obj.id:
            return
        if isinstance(self.rig, Presenting) and not self.rig.present(obj):
            msg = f"the rig could not present {obj.id}; give it a pose in the rig configuration"
            raise ReplayError(msg)
        self._presented = obj.id

    def __call__(self, obj: int, action: str) -> RawFeatures:
        """Perform, record and read back one observation."""
        return file_features(self._perform(self.objects[obj], action, "pool"))

    def record_test_set(self, actions: Sequence[str], trials: int) -> TestSet:
        """Record ``trials`` held-out trials of every (new object, action) and return them."""
        test: TestSet = {}
        for action in actions:
            observations, labels = [], []
            for index, obj in enumerate(self.objects):
                for _ in range(trials):
                    observations.append(file_features(self._perform(obj, action, "test")))
                    labels.append(index)
            test[action] = (observations, labels)
        return test

    def _write_manifest(self) -> None:
        """Write ``session.parquet`` (the recordings used so far, in order)."""
        schema = {
            "order": pl.Int64,
            "object_id": pl.String,
            "action_id": pl.String,
            "trial": pl.Int64,
            "role": pl.String,
            "path": pl.String,
        }
        manifest = pl.DataFrame(self.made, schema=schema)
        atomic_write(self.session / SESSION_NAME, manifest.write_parquet)


def refuse_unpresented(rig: Rig, objects: Sequence[ObjectSpec], where: str = "") -> None:
    """Refuse new objects the rig cannot present: live learning places none by hand.

    Args:
        rig: The rig, not yet connected.
        objects: The new objects.
        where: The rig configuration file, to name in the message (empty: none given).

    Raises:
        ReplayError: The rig has no pose for a new object (one line naming them, the
            configuration file and the fix).
    """
    missing = (
        [o.id for o in objects if not rig.can_present(o)] if isinstance(rig, Presenting) else []
    )
    if missing:
        config = where or "the rig configuration"
        msg = (
            f"{config}: the rig has no pose for {', '.join(missing)}: live learning presents "
            f"every new object by itself; give each a pose ([objects.{missing[0]}] pose in "
            f"{config})"
        )
        raise ReplayError(msg)
