"""Executors: where the learner's requested observations come from.

Both executors serve ``executor(object_index, action) -> RawFeatures`` and both go through the
one path MCAP file -> reader -> features. The :class:`PoolExecutor` serves recordings of a
dataset (through its feature cache, built by that same path); the live executor
(``replay.live.LiveExecutor``, the only one that uses the recorder) performs the action on a
rig, records it, and reads back the file it just wrote.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Protocol

import numpy as np
import polars as pl

from replay.errors import ReplayError
from replay.learning._features import raw_table

if TYPE_CHECKING:
    from collections.abc import Mapping, Sequence

    from atikt import RawFeatures

#: Manifest of a live session: every recording in the order it was made, with its role.
SESSION_NAME = "session.parquet"

Pair = tuple[str, str]  # (object id, action id)
TestSet = dict[str, tuple[list["RawFeatures"], list[int]]]


class Executor(Protocol):
    """Serves observations to the learner."""

    def __call__(self, obj: int, action: str) -> RawFeatures:
        """Return a new observation of ``action`` on new object number ``obj``."""
        ...

    @property
    def capacity(self) -> Mapping[tuple[int, str], int] | None:
        """Observations each (new object index, action) can give in all; None: unlimited."""
        ...


def _stable(text: str) -> int:
    """Return a hash of ``text`` that is the same in every process and Python version."""
    return zlib.crc32(text.encode())


@dataclass(frozen=True, slots=True)
class Split:
    """Per (object, action): the held-out test trials and the pool in serving order.

    Attributes:
        test: (object, action) -> trials kept for testing.
        pool: (object, action) -> trials the learner may draw, in the order they are served.
    """

    test: Mapping[Pair, tuple[int, ...]]
    pool: Mapping[Pair, tuple[int, ...]]

    @classmethod
    def random(
        cls,
        frame: pl.DataFrame,
        objects: Sequence[str],
        actions: Sequence[str],
        *,
        seed: int,
        test_fraction: float = 0.5,
    ) -> Split:
        """Split each (object, action)'s trials at random, by seed.

        The permutation of a pair depends only on (seed, object, action), not on which other
        objects or actions take part.

        Raises:
            ReplayError: A pair has fewer than two recordings.
        """
        test: dict[Pair, tuple[int, ...]] = {}
        pool: dict[Pair, tuple[int, ...]] = {}
        recorded = _recorded_trials(frame)
        for obj in objects:
            for action in actions:
                trials = _trials(recorded, obj, action)
                rng = np.random.default_rng([seed, _stable(obj), _stable(action)])
                order = [trials[i] for i in rng.permutation(len(trials))]
                n_test = min(max(1, round(test_fraction * len(trials))), len(trials) - 1)
                test[obj, action] = tuple(sorted(order[:n_test]))
                pool[obj, action] = tuple(order[n_test:])
        return cls(test, pool)

    @classmethod
    def from_session(cls, root: Path) -> Split:
        """Return the split a live session used, from its manifest.

        Raises:
            ReplayError: The directory has no readable session manifest.
        """
        target = Path(root) / SESSION_NAME
        try:
            frame = pl.read_parquet(target, glob=False)
        except (OSError, pl.exceptions.PolarsError) as err:
            msg = f"{target}: cannot read the session manifest ({err}); is {root} a live session?"
            raise ReplayError(msg) from err
        test: dict[Pair, list[int]] = {}
        pool: dict[Pair, list[int]] = {}
        for row in frame.sort("order").iter_rows(named=True):
            into = test if row["role"] == "test" else pool
            into.setdefault((row["object_id"], row["action_id"]), []).append(row["trial"])
        return cls(
            {k: tuple(sorted(v)) for k, v in test.items()},
            {k: tuple(v) for k, v in pool.items()},
        )


def _recorded_trials(frame: pl.DataFrame) -> dict[Pair, list[int]]:
    """Return the trials of every (object, action) of a feature table, in one pass."""
    recorded: dict[Pair, list[int]] = {}
    columns = (frame[c].to_list() for c in ("object_id", "action_id", "trial"))
    for obj, action, trial in zip(*columns, strict=True):
        recorded.setdefault((obj, action), []).append(trial)
    return recorded


def _trials(recorded: Mapping[Pair, list[int]], obj: str, action: str) -> list[int]:
    """Return the sorted trials of (obj, action) (``recorded``: :func:`_recorded_trials`).

    Raises:
        ReplayError: Fewer than two recordings.
    """
    trials = sorted(recorded.get((obj, action), []))
    if len(trials) < 2:  # noqa: PLR2004
        msg = (
            f"object {str(obj)!r}, action {str(action)!r}: {len(trials)} usable recording(s); "
            "a run needs >= 2 (one to learn, one to test); record more trials of it, or leave "
            f"it out (--actions without {str(action)!r}, or --new and --priors without "
            f"{str(obj)!r})"
        )
        raise ReplayError(msg)
    return trials


class FeatureLookup:
    """Raw features of a feature table by (object, action, trial).

    Every observation of an action has the same feature blocks: those the feature policy
    selects among the blocks every recording of the action has (see
    :func:`replay.learning._features.select_blocks`).
    """

    def __init__(self, frame: pl.DataFrame, policy: str = "thesis") -> None:
        """Convert the table's rows once and choose each action's feature blocks."""
        self._raw, self.kinds, self.blocks = raw_table(frame, policy)
        index: dict[tuple[str, str], list[int]] = {}
        for obj, action, trial in sorted(self._raw):
            index.setdefault((obj, action), []).append(trial)
        self._trials = index

    def get(self, obj: str, action: str, trial: int) -> RawFeatures:
        """Return the features of one recording.

        Raises:
            ReplayError: The table has no such recording.
        """
        raw = self._raw.get((obj, action, trial))
        if raw is None:
            msg = f"no recording of object {str(obj)!r}, action {str(action)!r}, trial {trial}"
            raise ReplayError(msg)
        return raw

    def groups(self, objects: Sequence[str], action: str) -> dict[int, list[RawFeatures]]:
        """Return every recording of each object of ``action``, trials in order, by index."""
        return {
            i: [self._raw[obj, action, t] for t in self._trials.get((obj, action), [])]
            for i, obj in enumerate(objects)
        }

    def trials(self, obj: str, action: str) -> list[int]:
        """Return the sorted trials of (obj, action)."""
        return list(self._trials.get((obj, action), []))

    def objects(self, action: str) -> list[str]:
        """Return the sorted objects with at least one recording of ``action``."""
        return sorted({o for (o, a) in self._trials if a == action})


@dataclass(slots=True)
class PoolExecutor:
    """Serves the next unused pool recording of the requested (object, action).

    Attributes:
        lookup: Features of the dataset.
        objects: New object ids, in the learner's index order.
        split: Test trials and pool order.
        like_rig: Report every pair as available, as the rig of a live session did, so that a
            replay of the session makes the same decisions (see ``Split.from_session``).
        served: (object, action, trial) of every served recording, in order.
    """

    lookup: FeatureLookup
    objects: Sequence[str]
    split: Split
    like_rig: bool = False
    served: list[tuple[str, str, int]] = field(default_factory=list)
    _next: dict[Pair, int] = field(default_factory=dict)

    @property
    def capacity(self) -> dict[tuple[int, str], int] | None:
        """Return the pool size of every (object index, action); None like a rig."""
        if self.like_rig:
            return None
        index = {obj: i for i, obj in enumerate(self.objects)}
        pools = self.split.pool.items()
        return {(index[obj], a): len(trials) for (obj, a), trials in pools if obj in index}

    def available(self, obj: int, action: str) -> bool:
        """Return whether the pool of (obj, action) still has an unused recording."""
        if self.like_rig:
            return True
        pair = (self.objects[obj], action)
        return self._next.get(pair, 0) < len(self.split.pool.get(pair, ()))

    def __call__(self, obj: int, action: str) -> RawFeatures:
        """Return the features of the next unused pool recording.

        Raises:
            ReplayError: The pool of (obj, action) is used up.
        """
        pair = (self.objects[obj], action)
        pool = self.split.pool.get(pair, ())
        position = self._next.get(pair, 0)
        if position >= len(pool):
            msg = (
                f"object {str(pair[0])!r}, action {str(action)!r}: all {len(pool)} pool recordings "
                "are used; record more trials or lower the budget"
                + (" (the replay left the recorded session's path)" if self.like_rig else "")
            )
            raise ReplayError(msg)
        self._next[pair] = position + 1
        self.served.append((*pair, pool[position]))
        return self.lookup.get(*pair, pool[position])

    def test_set(self, actions: Sequence[str]) -> TestSet:
        """Return the held-out observations of every action, labelled by object index."""
        test: TestSet = {}
        for action in actions:
            observations, labels = [], []
            for index, obj in enumerate(self.objects):
                for trial in self.split.test.get((obj, action), ()):
                    observations.append(self.lookup.get(obj, action, trial))
                    labels.append(index)
            test[action] = (observations, labels)
        return test
