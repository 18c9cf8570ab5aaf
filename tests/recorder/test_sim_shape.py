"""The simulated skin's shape: number of cells and their layout (``cells``, ``layout``)."""

from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import pytest

from recorder import (
    RecorderError,
    SimConfig,
    SimulatedRig,
    SkinBlock,
    load_actions,
    load_objects,
    load_rig_config,
    rig_factory,
)
from recorder._sim import skin

if TYPE_CHECKING:
    from pathlib import Path

OBJECTS = load_objects()
ACTIONS = load_actions()


def _blocks(config: SimConfig, object_id: str, action_id: str) -> dict[str, np.ndarray]:
    """Return each modality's readings of one execution, concatenated over blocks."""
    with SimulatedRig(0, config) as rig:
        items = list(rig.perform(OBJECTS[object_id], ACTIONS[action_id], 1))
    blocks: dict[str, list[np.ndarray]] = {}
    for item in items:
        if isinstance(item, SkinBlock):
            blocks.setdefault(item.modality, []).append(item.data)
    return {modality: np.concatenate(data) for modality, data in blocks.items()}


def test_a_fingertip_of_three_cells_reports_three_cells_in_every_modality() -> None:
    readings = _blocks(SimConfig(cells=3), "wood", "S1")
    assert {data.shape[1] for data in readings.values()} == {3}
    assert np.isfinite(np.concatenate([d.ravel() for d in readings.values()])).all()


def test_the_thesis_patch_is_the_default_and_keeps_its_metadata() -> None:
    explicit = SimConfig(cells=7, layout="hex", cell_pitch_m=skin.CELL_PITCH_M)
    assert explicit == SimConfig()
    described = SimulatedRig(0, explicit).describe()
    assert not {"cells", "layout", "cell_pitch_m"} & set(described)
    fingertip = SimulatedRig(0, SimConfig(cells=3)).describe()
    assert (fingertip["cells"], fingertip["layout"]) == ("3", "'hex'")


def test_the_default_skin_draws_the_same_hardware_as_the_thesis_patch() -> None:
    default = skin.SkinHardware.draw(np.random.default_rng(4))
    seven = skin.SkinHardware.draw(np.random.default_rng(4), skin.SkinLayout(7, "hex"))
    np.testing.assert_array_equal(default.centres, skin.cell_centres())
    np.testing.assert_array_equal(default.force_gain, seven.force_gain)
    three = skin.SkinHardware.draw(np.random.default_rng(4), skin.SkinLayout(3, "hex"))
    assert three.n_cells == 3
    np.testing.assert_array_equal(three.cell_angle, default.cell_angle[:3])  # first draw


def test_a_hex_fingertip_is_a_compact_triangle_and_a_row_lies_across_the_slide() -> None:
    triangle = skin.SkinLayout(3, "hex").centres()
    distances = np.linalg.norm(triangle[:, None] - triangle[None], axis=-1)
    assert distances[np.triu_indices(3, 1)] == pytest.approx([skin.CELL_PITCH_M] * 3)
    row = skin.SkinLayout(4, "row", 0.02).centres()
    np.testing.assert_allclose(row[:, 0], 0.0)
    np.testing.assert_allclose(row[:, 1], [-0.03, -0.01, 0.01, 0.03])


def test_a_smaller_skin_presses_with_its_share_of_the_force() -> None:
    # The per-sensor laws stay those of the thesis's patch: at the same press depth, three
    # cells carry about 3/7 of the seven cells' force (tilt and irregularity aside).
    flat = SimConfig(tilt_deg=0.0, location_spread_m=0.0)
    seven = _blocks(flat, "foam_block", "P2")["force"].sum(axis=(1, 2))
    three = _blocks(replace(flat, cells=3), "foam_block", "P2")["force"].sum(axis=(1, 2))
    ratio = float(np.max(three) / np.max(seven))
    assert 0.3 < ratio < 0.6  # 3/7 = 0.43, within the spread of the cells' gains and surface


@pytest.mark.parametrize(
    ("option", "match"),
    [
        ("cells=9", "cells = 9 exceeds the 7 cells of layout 'hex'.*layout=row"),
        ("cells=0", "cells = 0 must be >= 1"),
        ("cells=2.5", r"cells=2.5: give a whole number \(e.g. cells=3\)"),
        ("layout=ring", "layout = 'ring' is not one of hex, row"),
        ("layout=3", "layout=3: give a word"),
        ("cell_pitch_m=0.005", "cell_pitch_m = 0.005 must exceed 0.009 m.*larger pitch"),
    ],
)
def test_a_bad_skin_shape_is_a_one_line_error_naming_the_value_and_the_fix(
    option: str, match: str
) -> None:
    with pytest.raises(RecorderError, match=match) as caught:
        rig_factory(load_rig_config(options=[option]))(0)
    assert "\n" not in str(caught.value)


def test_a_rig_file_gives_the_skin_shape(tmp_path: Path) -> None:
    path = tmp_path / "fingertip.toml"
    path.write_text('rig = "sim"\n[options]\ncells = 5\nlayout = "row"\ncell_pitch_m = 0.012\n')
    rig = rig_factory(load_rig_config(path))(2)
    assert isinstance(rig, SimulatedRig)
    assert rig.config.skin == skin.SkinLayout(5, "row", 0.012)
