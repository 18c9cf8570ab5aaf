"""A small simulated dataset shared by the replay engine's tests (recorded once per session)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import pytest

from recorder import generate_dataset, load_actions, load_objects, plan_dataset, rig_factory

if TYPE_CHECKING:
    from pathlib import Path

#: Old objects (priors) and new objects of the small dataset.
OLD = ("metal_toolbox", "soft_sponge", "wood")
NEW = ("aluminium_plate", "foam_block", "pine_board")
ACTIONS = ("P1", "S2")
TRIALS = 5


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Record 6 objects x 2 actions x 5 trials with the simulated rig (seed 0)."""
    root = tmp_path_factory.mktemp("small") / "dataset"
    tasks = plan_dataset(
        load_objects(), load_actions(), object_ids=[*OLD, *NEW], action_ids=ACTIONS, trials=TRIALS
    )
    generate_dataset(tasks, root, rig_factory("sim"), seed=0, workers=1)
    return root
