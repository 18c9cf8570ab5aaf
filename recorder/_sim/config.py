"""Configuration of the simulated rig: the session's conditions and the controller's settings."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Final

from recorder._sim.skin import CELL_PITCH_M, N_CELLS, SkinLayout
from recorder.errors import RigError

SKIN_FIELDS: Final = ("cells", "layout", "cell_pitch_m")
"""The skin's shape; in a recording's metadata only when it is not the thesis's patch, so
that recordings of the thesis's patch keep the metadata (and bytes) they always had."""


@dataclass(frozen=True, slots=True)
class SimConfig:
    """Settings of a simulated session; the defaults reproduce the thesis set-up.

    Attributes:
        room_c: Mean room temperature, which the objects share, C.
        room_spread_c: Width of the uniform trial-to-trial variation of the room temperature, C.
        skin_c: Set point of the skin's heater, C.
        start_gap_m: Gap between skin and object surface when the approach starts, m.
        approach_speed_m_s: Cruise speed of the approach, m/s.
        creep_speed_m_s: Slowest approach speed, reached near the surface, m/s.
        slowdown_s: The approach speed is the proximity reading over this time, s.
        guard_gap_m: Within this gap of where the robot believes the surface is, it moves at
            most at the guard speed, m.
        guard_speed_m_s: Speed limit near the believed surface, m/s.
        height_spread_m: Objects' heights are known within +- this: the true surface is that
            much higher or lower than the robot believes, m.
        contact_force_n: Total force that counts as light contact, N.
        settle_s: Pause in light contact before the action starts, s.
        press_speed_m_s: Peak speed when pressing in or setting the sliding force, m/s.
        retract_speed_m_s: Peak speed of the retract, m/s.
        retract_gap_m: Gap above the surface at the end of the retract, m.
        location_spread_m: Contact location varies uniformly within +- this on each axis, m.
        tilt_deg: RMS tilt between the object's top face and the skin, degrees.
        force_control_error: Relative RMS error of the sliding force controller.
        cells: Number of skin cells: 7 is the thesis's patch; fewer (e.g. 3, a fingertip)
            keep its first cells (``hex``) or lie in a row (``row``).
        layout: Arrangement of the cells, ``hex`` or ``row`` (see ``skin.LAYOUTS``).
        cell_pitch_m: Centre-to-centre distance of neighbouring cells, m.
    """

    room_c: float = 22.5
    room_spread_c: float = 1.0
    skin_c: float = 29.5
    start_gap_m: float = 0.02
    approach_speed_m_s: float = 0.03
    creep_speed_m_s: float = 0.003
    slowdown_s: float = 0.25
    guard_gap_m: float = 0.003
    guard_speed_m_s: float = 0.008
    height_spread_m: float = 0.002
    contact_force_n: float = 0.05
    settle_s: float = 0.2
    press_speed_m_s: float = 0.01
    retract_speed_m_s: float = 0.04
    retract_gap_m: float = 0.015
    location_spread_m: float = 0.01
    tilt_deg: float = 0.3
    force_control_error: float = 0.08
    cells: int = N_CELLS
    layout: str = "hex"
    cell_pitch_m: float = CELL_PITCH_M

    def __post_init__(self) -> None:
        """Refuse settings the controller cannot run with.

        Raises:
            RigError: A setting is out of range; the message names it and the fix.
        """
        problem = self.skin.problem()
        if problem is not None:
            msg = f"SimConfig: {problem}"
            raise RigError(msg)
        for field in fields(self):
            value = getattr(self, field.name)
            if field.name in {"room_c", "layout"}:
                continue
            if not value >= 0:
                msg = f"SimConfig.{field.name} = {value!r} must be >= 0"
                raise RigError(msg)
        if not 0 < self.creep_speed_m_s <= self.approach_speed_m_s:
            msg = (
                f"SimConfig: creep_speed_m_s = {self.creep_speed_m_s} must lie in "
                f"(0, approach_speed_m_s = {self.approach_speed_m_s}]"
            )
            raise RigError(msg)
        if not self.creep_speed_m_s <= self.guard_speed_m_s:
            msg = (
                f"SimConfig: guard_speed_m_s = {self.guard_speed_m_s} must be >= "
                f"creep_speed_m_s = {self.creep_speed_m_s}"
            )
            raise RigError(msg)
        nearest = self.guard_gap_m + self.height_spread_m
        if self.start_gap_m <= nearest or self.slowdown_s <= 0:
            msg = (
                f"SimConfig: start_gap_m = {self.start_gap_m} must exceed guard_gap_m + "
                f"height_spread_m = {nearest:.4g} (and slowdown_s > 0); raise the start gap"
            )
            raise RigError(msg)
        if self.contact_force_n <= 0 or self.press_speed_m_s <= 0 or self.retract_speed_m_s <= 0:
            msg = "SimConfig: contact_force_n, press_speed_m_s and retract_speed_m_s must be > 0"
            raise RigError(msg)

    @property
    def skin(self) -> SkinLayout:
        """The skin's shape."""
        return SkinLayout(self.cells, self.layout, self.cell_pitch_m)

    def describe(self) -> dict[str, str]:
        """Return every setting as text, for the recording's metadata.

        The skin's shape is left out for the thesis's patch (``SKIN_FIELDS``).
        """
        thesis = self.skin == SkinLayout()
        return {
            field.name: repr(getattr(self, field.name))
            for field in fields(self)
            if not (thesis and field.name in SKIN_FIELDS)
        }
