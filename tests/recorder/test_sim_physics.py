from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from recorder import (
    ActionSpec,
    Modality,
    ObjectSpec,
    Phase,
    SimulatedRig,
    SkinBlock,
    StreamItem,
    load_actions,
    load_objects,
)
from recorder._catalog import ObjectPhysics
from recorder._sim import contact, skin, texture, thermal
from recorder._sim.motion import DT_S

OBJECTS = load_objects()
ACTIONS = load_actions()


def _series(
    items: list[StreamItem], modality: Modality
) -> tuple[np.ndarray, np.ndarray, dict[Phase, int]]:
    blocks = [item for item in items if isinstance(item, SkinBlock) and item.modality is modality]
    data = np.concatenate([block.data for block in blocks]).astype(np.float64)
    times = np.concatenate([b.stamp_ns + b.period_ns * np.arange(b.data.shape[0]) for b in blocks])
    events = {item.phase: item.stamp_ns for item in items if hasattr(item, "phase")}
    return times, data, events


def _run(obj: ObjectSpec, action: ActionSpec, trial: int) -> list[StreamItem]:
    with SimulatedRig(0) as rig:
        return list(rig.perform(obj, action, trial))


def _hold_force(object_id: str, action_id: str, trial: int) -> np.ndarray:
    """Total force over the hold (after the press-in), 250 Hz."""
    t, force, events = _series(_run(OBJECTS[object_id], ACTIONS[action_id], trial), "force")
    hold = (t >= events["execute"] + 400_000_000) & (t < events["retract"])
    total: np.ndarray = force[hold].sum(axis=(1, 2))
    return total


def _mean_hold(object_id: str, action_id: str) -> float:
    return float(np.mean([_hold_force(object_id, action_id, trial).mean() for trial in range(3)]))


def _physics(object_id: str) -> ObjectPhysics:
    physics = OBJECTS[object_id].physics
    assert physics is not None
    return physics


def test_on_a_hard_object_the_skin_cover_takes_the_deflection() -> None:
    expected = contact.SKIN_STIFFNESS_N_M * ACTIONS["P2"].depth_m
    assert _mean_hold("wood", "P2") == pytest.approx(expected, rel=0.12)
    assert _mean_hold("aluminium_plate", "P1") == pytest.approx(expected / 2, rel=0.12)


def test_foam_softens_and_a_thin_layer_on_marble_stiffens() -> None:
    ratio = {
        name: _mean_hold(name, "P2") / _mean_hold(name, "P1")
        for name in ("wood", "soft_sponge", "marble_sponge")
    }
    assert ratio["wood"] == pytest.approx(2.0, abs=0.15)  # linear
    assert ratio["soft_sponge"] < 1.85  # elastic range ends: plateau
    assert ratio["marble_sponge"] > 2.2  # the 8 mm layer densifies on the marble


def test_foam_relaxes_during_a_hold_and_wood_hardly() -> None:
    for name, low, high in (("soft_sponge", 0.6, 0.92), ("wood", 0.93, 1.02)):
        force = _hold_force(name, "P2", trial=0)
        start, end = force[:25].mean(), force[-25:].mean()
        assert low < end / start < high, name


def test_contact_law_is_the_series_of_cover_and_object() -> None:
    rigid = contact.contact_law(_physics("wood"))
    depth = np.array([0.5e-3, 1e-3, 2e-3])
    per_sensor = contact.SKIN_STIFFNESS_N_M / contact.SENSORS
    np.testing.assert_allclose(rigid.elastic(depth), per_sensor * depth, rtol=0.01)
    assert rigid.elastic(np.array([-1e-3]))[0] == 0.0
    foam = contact.contact_law(_physics("soft_sponge"))
    assert np.all(np.diff(foam.force_n) > 0)
    assert foam.elastic(np.array([2e-3]))[0] < 0.1 * rigid.elastic(np.array([2e-3]))[0]
    assert foam.object_share > 0.9
    assert rigid.object_share < 0.05


def test_depth_for_force_inverts_the_total_force() -> None:
    law = contact.contact_law(_physics("paper_box"))
    rng = np.random.default_rng(0)
    offsets = 1e-4 * rng.standard_normal((7, 3))
    offsets[6] = np.nan  # a cell off the object
    gain = 1.0 + 0.03 * rng.standard_normal((7, 3))
    for target in (0.05, 0.2, 1.0):
        depth = contact.depth_for_force(law, offsets, gain, target)
        total = contact.total_force_curve(law, offsets, gain, np.array([depth]))[0]
        assert total == pytest.approx(target, rel=0.01)


def _drop_after(object_id: str, seconds: float, trials: int) -> tuple[float, float]:
    """Mean drop of the skin temperature ``seconds`` after light contact, and mean force."""
    drops, forces = [], []
    for trial in range(trials):
        items = _run(OBJECTS[object_id], ACTIONS["C1"], trial)
        t, temp, events = _series(items, "temperature")
        mean = temp[..., 0].mean(axis=1)
        contact_ns = events["contact"]
        before = mean[(t <= contact_ns) & (t > contact_ns - 500_000_000)].mean()
        drops.append(before - mean[np.searchsorted(t, contact_ns + seconds * 1e9)])
        tf, force, _ = _series(items, "force")
        forces.append(force[(tf > contact_ns + 1e9) & (tf < contact_ns + 5e9)].sum(axis=(1, 2)))
    return float(np.mean(drops)), float(np.mean(np.concatenate(forces)))


def test_static_contact_reproduces_the_measured_thermal_drops() -> None:
    """Calibration (recorder/_sim/CALIBRATION.md): 4.5 N on room-temperature wood drops a
    29.5 C skin by 0.48 +- 0.10 C after 5 s, on aluminium by 2.40 +- 0.16 C, with about 1 s
    lag."""
    wood, wood_force = _drop_after("wood", 5.0, trials=5)
    aluminium, aluminium_force = _drop_after("aluminium_plate", 5.0, trials=5)
    assert wood_force == pytest.approx(4.5, rel=0.1)
    assert aluminium_force == pytest.approx(4.5, rel=0.1)
    assert wood == pytest.approx(0.48, rel=0.3)
    assert aluminium == pytest.approx(2.40, rel=0.3)
    early, _ = _drop_after("aluminium_plate", 1.0, trials=2)
    assert early < 0.15 * aluminium  # the sensor lags about a second


def test_thermal_drop_grows_with_effusivity() -> None:
    order = ["soft_sponge", "wood", "glass_plate", "aluminium_plate"]
    # 6 trials: one trial's drop varies by about 0.1 C (the real probe's spread on wood)
    drops = [_drop_after(name, 5.0, trials=6)[0] for name in order]
    assert drops == sorted(drops)
    assert abs(drops[0]) < 0.1  # foam insulates


def test_interface_model_and_layers() -> None:
    cell_force = np.zeros((2500, 7))
    cell_force[250:] = 0.6
    state = thermal.SkinState(set_point_c=29.5)
    steady = {}
    for effusivity in (35.0, 450.0, 23400.0):
        obj = ObjectPhysics(effusivity=effusivity)
        temp = thermal.sensor_temperature(cell_force, 0.004, obj, 22.5, state)
        assert temp[:250].max() == pytest.approx(29.5)
        steady[effusivity] = 29.5 - temp[-1, 0]
    assert steady[35.0] < steady[450.0] < steady[23400.0] < 7.0
    layered = ObjectPhysics(effusivity=40.0, base_effusivity=2600.0, thermal_layer_s=4.0)
    felt = thermal.effusivity_over_time(layered, np.array([0.0, 0.1, 4.0, 400.0, 1e6]))
    assert felt[0] == pytest.approx(40.0)
    assert felt[1] < 45.0
    assert np.all(np.diff(felt) > 0)
    assert felt[-1] == pytest.approx(2600.0, rel=0.01)


def _grating(period_m: float) -> ObjectSpec:
    physics = ObjectPhysics(
        texture_period_m=period_m,
        texture_amplitude_m=60e-6,
        anisotropy=1.0,
        fine_roughness_m=0.0,
        friction_static=0.3,
        friction_kinetic=0.3,
        variability=0.0,
    )
    return ObjectSpec("grating", "Grating", physics=physics)


def _steady_slide(items: list[StreamItem]) -> np.ndarray:
    t, acc, events = _series(items, "acceleration")
    steady = (t >= events["execute"] + 300_000_000) & (t < events["retract"] - 100_000_000)
    return acc[steady]


@pytest.mark.parametrize(("action_id", "expected_hz"), [("S1", 10.0), ("S2", 50.0)])
def test_vibration_frequency_is_speed_over_texture_period(
    action_id: str, expected_hz: float
) -> None:
    peaks = []
    for trial in range(3):  # one slide's strongest line may be the ridges' second harmonic
        acc = _steady_slide(_run(_grating(1e-3), ACTIONS[action_id], trial=trial))
        normal = acc[..., 2].mean(axis=1)
        spectrum = np.abs(np.fft.rfft(normal - normal.mean(), n=4096))
        frequency = np.fft.rfftfreq(4096, DT_S)
        peaks.append(frequency[np.argmax(spectrum * (frequency > 3.0))])
    assert np.median(peaks) == pytest.approx(expected_hz, rel=0.1)  # cos(yaw) >= 0.98


def test_sliding_on_hard_materials_has_a_realistic_spectral_centroid() -> None:
    probe = ActionSpec("probe", "slide", 1.0, force_n=0.5, speed_m_s=0.02)
    for name in ("wood", "hard_box", "glass_plate", "rubber_mat", "book"):
        acc = _steady_slide(_run(OBJECTS[name], probe, trial=0))
        power = np.abs(np.fft.rfft(acc - acc.mean(axis=0), axis=0)) ** 2
        frequency = np.fft.rfftfreq(acc.shape[0], DT_S)
        centroid = (frequency[:, None, None] * power).sum() / power.sum()
        assert 120.0 < centroid < 250.0, name  # BioTac on everyday materials: 140-230 Hz


def test_stick_slip_needs_high_friction_difference_and_low_speed() -> None:
    rng = np.random.default_rng(0)
    force = np.full(1100, 0.2)
    slow = np.cumsum(np.r_[np.zeros(50), np.full(1050, 0.01 * DT_S)])
    fast = np.cumsum(np.r_[np.zeros(50), np.full(1050, 0.05 * DT_S)])
    sticky = replace(_physics("wood"), friction_static=1.2, friction_kinetic=0.7)
    slips = texture._slip_train(sticky, slow, force, rng)
    interval = 0.5 * 0.2 / (texture.TANGENTIAL_STIFFNESS_N_M * 0.01)
    assert np.count_nonzero(slips) == pytest.approx(1.05 / interval, rel=0.2)
    assert np.count_nonzero(texture._slip_train(sticky, fast, force, rng)) == 1  # break-away
    smooth = replace(_physics("wood"), friction_static=0.4, friction_kinetic=0.35)
    assert np.count_nonzero(texture._slip_train(smooth, slow, force, rng)) == 1


def test_proximity_reading_falls_with_distance_and_saturates_at_range() -> None:
    hardware = skin.SkinHardware.draw(np.random.default_rng(0))
    distance = np.repeat(np.array([0.0, 0.005, 0.02, 0.08, 0.19, 0.25])[:, None], 7, axis=1)
    rng = np.random.default_rng(1)
    reading = np.mean(
        [skin.measure_proximity(distance, 0.6, hardware, rng) for _ in range(20)], axis=0
    )
    assert np.all(np.diff(reading.mean(axis=1)) > 0)
    np.testing.assert_allclose(reading[-1], skin.PROXIMITY_RANGE_M)
    dark = skin.measure_proximity(distance[2:3], 0.2, hardware, rng)
    bright = skin.measure_proximity(distance[2:3], 0.9, hardware, rng)
    assert dark.mean() > bright.mean()  # infrared sensors see dark surfaces farther
