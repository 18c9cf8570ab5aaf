"""Synthetic raw skin signals of objects, for the atikt tests and benchmark.

Each object has a stiffness, a texture (period and roughness) and a thermal response; each
action turns them into force (250 Hz), acceleration (1 kHz) and temperature (20 Hz) arrays of
the execute phase, with sensor noise, then into raw features. Every draw is seeded.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from atikt import RawFeatures, extract_features

N_CELLS = 7


@dataclass(frozen=True)
class SyntheticObject:
    """Physical parameters of one object."""

    stiffness: float  # N per mm of press depth
    roughness: float  # vibration amplitude while sliding, m/s^2
    period_mm: float  # texture period
    cooling: float  # steady temperature drop of the heated skin in contact, C
    tau_s: float  # thermal time constant, s


@dataclass(frozen=True)
class SyntheticAction:
    """One exploratory action (thesis parameters)."""

    kind: str
    duration_s: float
    depth_mm: float = 0.0
    force_n: float = 0.0
    speed_m_s: float = 0.0


ACTIONS: dict[str, SyntheticAction] = {
    "P1": SyntheticAction("press", 3.0, depth_mm=1.0),
    "P2": SyntheticAction("press", 3.0, depth_mm=2.0),
    "S1": SyntheticAction("slide", 1.0, force_n=0.1, speed_m_s=0.01),
    "S2": SyntheticAction("slide", 1.0, force_n=0.1, speed_m_s=0.05),
    "S3": SyntheticAction("slide", 1.0, force_n=0.2, speed_m_s=0.01),
    "S4": SyntheticAction("slide", 1.0, force_n=0.2, speed_m_s=0.05),
    "C1": SyntheticAction("static", 15.0, depth_mm=2.0),
}

# Five new objects and three old ones; every new object resembles an old one in some property.
NEW_OBJECTS = (
    SyntheticObject(stiffness=0.3, roughness=2.0, period_mm=2.0, cooling=0.3, tau_s=4.0),
    SyntheticObject(stiffness=2.0, roughness=0.5, period_mm=0.5, cooling=2.4, tau_s=1.5),
    SyntheticObject(stiffness=1.5, roughness=1.2, period_mm=1.0, cooling=0.6, tau_s=3.0),
    SyntheticObject(stiffness=0.6, roughness=3.0, period_mm=3.0, cooling=0.2, tau_s=5.0),
    SyntheticObject(stiffness=1.9, roughness=0.4, period_mm=0.4, cooling=1.2, tau_s=2.0),
)
OLD_OBJECTS = (
    SyntheticObject(stiffness=0.32, roughness=2.1, period_mm=2.1, cooling=0.32, tau_s=4.0),
    SyntheticObject(stiffness=2.1, roughness=0.5, period_mm=0.5, cooling=2.3, tau_s=1.5),
    SyntheticObject(stiffness=1.0, roughness=5.0, period_mm=5.0, cooling=1.8, tau_s=2.5),
)


def signals(
    obj: SyntheticObject, action: SyntheticAction, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Force (n, 7, 3), acceleration (n, 7, 3) and temperature (n, 7) of one execution."""
    duration = action.duration_s
    n_force, n_acc, n_temp = int(250 * duration), int(1000 * duration), int(20 * duration)
    load = obj.stiffness * action.depth_mm + action.force_n
    cell_gain = 1.0 + 0.1 * rng.standard_normal((1, N_CELLS, 1))
    force = load * cell_gain / 3.0 + 0.02 * rng.standard_normal((n_force, N_CELLS, 3))
    t = np.arange(n_acc) / 1000.0
    acceleration = 0.05 * rng.standard_normal((n_acc, N_CELLS, 3))
    if action.speed_m_s > 0:
        freq = action.speed_m_s * 1000.0 / obj.period_mm
        phase = rng.uniform(0, 2 * np.pi, size=(1, N_CELLS, 1))
        gains = np.array([1.0, 0.6, 0.3]) * obj.roughness * (0.5 + action.force_n * 5)
        wave = np.sin(2 * np.pi * freq * t[:, None, None] + phase) * gains
        acceleration += wave * (1.0 + 0.1 * rng.standard_normal())
        acceleration += 0.2 * obj.roughness * rng.standard_normal((n_acc, N_CELLS, 3))
    tt = np.arange(n_temp) / 20.0
    start = 29.5 + 0.1 * rng.standard_normal()
    drop = obj.cooling * (1.0 + 0.05 * rng.standard_normal()) * (1 - np.exp(-tt / obj.tau_s))
    temperature = start - drop[:, None] + 0.03 * rng.standard_normal((n_temp, N_CELLS))
    return force, acceleration, temperature


#: The thesis's feature blocks per action kind (the contract's assignment, for synthetic data).
THESIS_BLOCKS = {"press": ("force", "thermal"), "slide": ("texture", "thermal")}
THESIS_BLOCKS["static"] = THESIS_BLOCKS["press"]


def thesis_features(
    kind: str,
    force: np.ndarray | None,
    acceleration: np.ndarray | None,
    temperature: np.ndarray,
    **options: Any,
) -> RawFeatures:
    """Extract the thesis's blocks of ``kind`` from force, acceleration and temperature."""
    given = {"force": (force, 250.0), "texture": (acceleration, 1000.0)}
    given["thermal"] = (temperature, options.pop("temperature_rate_hz", 20.0))
    signals = {b: given[b] for b in THESIS_BLOCKS.get(kind, ()) if given[b][0] is not None}
    return extract_features(kind, signals, **options)  # type: ignore[arg-type]


def observation(obj: SyntheticObject, action_id: str, rng: np.random.Generator) -> RawFeatures:
    """Raw features of one execution of ``action_id`` on ``obj``."""
    action = ACTIONS[action_id]
    force, acceleration, temperature = signals(obj, action, rng)
    return thesis_features(action.kind, force, acceleration, temperature)


def pool(
    objects: tuple[SyntheticObject, ...],
    actions: list[str],
    n_trials: int,
    seed: int,
) -> dict[str, dict[int, list[RawFeatures]]]:
    """``pool[action][object] = n_trials`` observations, seeded."""
    rng = np.random.default_rng(seed)
    return {
        a: {i: [observation(o, a, rng) for _ in range(n_trials)] for i, o in enumerate(objects)}
        for a in actions
    }


class PoolObserver:
    """``observe(object, action)`` that hands out a pool's observations in order."""

    def __init__(self, data: dict[str, dict[int, list[RawFeatures]]]) -> None:
        self.data = data
        self.used: dict[tuple[str, int], int] = {}
        self.calls: list[tuple[int, str]] = []

    def __call__(self, obj: int, action: str) -> RawFeatures:
        key = (action, obj)
        index = self.used.get(key, 0)
        self.used[key] = index + 1
        self.calls.append((obj, action))
        observations = self.data[action][obj]
        return observations[index % len(observations)]
