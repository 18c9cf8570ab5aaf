"""A session refused before its first recording leaves no index behind."""

from __future__ import annotations

from typing import TYPE_CHECKING, Self

import pytest
from conftest import FakeRig

from recorder import load_actions, load_objects, plan_dataset
from recorder._session import run_session
from recorder.errors import RigError

if TYPE_CHECKING:
    from pathlib import Path


class _Held(FakeRig):
    """A rig whose arm another process holds: refused on connecting."""

    def __enter__(self) -> Self:
        msg = "the arm is held by another process"
        raise RigError(msg)


def test_a_session_refused_on_connecting_writes_no_index(tmp_path: Path) -> None:
    tasks = plan_dataset(
        load_objects(), load_actions(), object_ids=["wood"], action_ids=["P1"], trials=1
    )
    root = tmp_path / "lockD"
    with pytest.raises(RigError, match="held by another process"):
        run_session(tasks, root, _Held, seed=0)
    assert not (root / "index.parquet").exists()
    assert not (root / "objects.toml").exists()
