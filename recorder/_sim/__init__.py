"""The physics-based simulated rig (UR10 + 7-cell multimodal skin)."""

from recorder._sim.config import SimConfig
from recorder._sim.rig import SimulatedRig

__all__ = ["SimConfig", "SimulatedRig"]
