"""The live executor: performs each requested action on a rig, records it, reads it back."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Self

import polars as pl

from recorder import record_action, recording_path
from replay.errors import ReplayError
from replay.learning._executors import SESSION_NAME, Pair, TestSet
from replay.learning._features import file_features
from schemas import atomic_write

if TYPE_CHECKING:
    from collections.abc import Callable, Mapping, Sequence
    from types import TracebackType

    from atikt import RawFeatures
    from recorder import ActionSpec, ObjectSpec, Rig


class LiveExecutor:
    """Performs each requested action on a rig, records it, and reads the file back.

    Recordings go to ``<session>/<object>/<action>/<trial>.mcap``; ``session.parquet`` lists
    them in the order they were made, with their role (``test`` or ``pool``), so that an
    offline run over the session (``Split.from_session``) serves exactly the same files.
    """

    def __init__(
        self,
        rig: Rig,
        objects: Sequence[ObjectSpec],
        actions: Mapping[str, ActionSpec],
        session: Path,
        *,
        seed: int,
        on_recorded: Callable[[Path], Any] | None = None,
    ) -> None:
        """Store the rig and where to record; nothing is performed before ``__enter__``.

        Args:
            rig: The rig, not yet connected.
            objects: The new objects, in the learner's index order.
            actions: The action catalog.
            session: Where the recordings and ``session.parquet`` go (must hold none).
            seed: The rig's seed, written to every recording.
            on_recorded: Called with each recording's path once it is written (a live view).
        """
        self.rig = rig
        self.objects = list(objects)
        self.actions = dict(actions)
        self.session = Path(session)
        self.seed = seed
        self.on_recorded = on_recorded
        self.made: list[dict[str, Any]] = []
        self._trials: dict[Pair, int] = {}

    def __enter__(self) -> Self:
        """Connect the rig; refuse a session directory that already holds recordings."""
        if (self.session / SESSION_NAME).exists() or any(self.session.rglob("*.mcap")):
            msg = f"{self.session}: already holds a session; choose a new --session directory"
            raise ReplayError(msg)
        self.session.mkdir(parents=True, exist_ok=True)
        self.rig.__enter__()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Disconnect the rig and write the manifest of what was recorded."""
        try:
            self.rig.__exit__(exc_type, exc, tb)
        finally:
            self._write_manifest()

    @property
    def capacity(self) -> None:
        """A rig can always perform another trial: no limit."""
        return None

    def _perform(self, obj: ObjectSpec, action_id: str, role: str) -> Path:
        """Record one more trial of (obj, action) and return its file."""
        pair = (obj.id, action_id)
        trial = self._trials.get(pair, 0) + 1
        self._trials[pair] = trial
        path = recording_path(self.session, obj.id, action_id, trial)
        path.parent.mkdir(parents=True, exist_ok=True)
        record_action(self.rig, obj, self.actions[action_id], trial, path, seed=self.seed)
        if self.on_recorded is not None:
            self.on_recorded(path)
        self.made.append(
            {"order": len(self.made), "object_id": obj.id, "action_id": action_id}
            | {"trial": trial, "role": role, "path": path.relative_to(self.session).as_posix()}
        )
        return path

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
        """Write ``session.parquet`` (the recordings made so far, in order)."""
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
