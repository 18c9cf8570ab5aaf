"""The virtual lab's objects and skin: surfaces under the arm, the skin driven by the real motion.

Objects are surfaces. The top face of an object lies :data:`SURFACE_GAP_M` below its pose
along the tool's z axis: below ``[objects.X] pose`` of the rig configuration (``serve-sim
--rig-config``), where the rig presents it; an object without a pose is placed by a person
under the arm, so its face lies that gap below the TCP where its first action is announced.
A face stays where it was placed for the rest of the run (the arm may sink into it; it never
moves). The object touched is the one the running program announced
(``textmsg("atikt: object=..")``).

The skin is the simulator's (:mod:`recorder._sim`), driven by the arm's actual motion:

- force: each force sensor's depth into the face (the patch centre's depth plus the sensor's
  offset from tilt, curvature and flatness, plus the texture's ridges under it) through the
  simulator's contact law (cover and object in series) and its relaxation; then the sensor's
  gain, offset, drift, noise and 1 mN steps. The conditions of the spot touched (its
  stiffness, location on the face, tilt, the skin's gains) are drawn per announced execution
  from (seed, object, action, trial), as the simulator draws them;
- temperature: the simulator's thermal model (interface temperature from the effusivities,
  conductance from each cell's force, the cover's and sensor's lags), stepped cycle by cycle;
- vibration: while the patch moves along the face in contact, the texture's ridges and the
  friction noise (:mod:`recorder._sim.texture`) at 1 kHz through the cell's resonance (the
  offline simulator's random relief and stick-slip are not modelled live); gravity; the
  accelerometer's bias, noise and 10-bit steps;
- proximity: each cell's distance to the face, through the proximity sensor's model.

Samples are taken on a 1 ms grid of controller time inside each controller cycle, so at
``time_scale`` S < 1 each sample is 1/S ms of world time apart.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Final

import numpy as np
from numpy.typing import NDArray

from recorder._sim import contact, skin, texture, thermal
from recorder._sim.motion import RATE_HZ
from recorder._sim.rig import Conditions, sensor_offsets

if TYPE_CHECKING:
    from recorder._catalog import ActionSpec, ObjectPhysics, ObjectSpec
    from recorder._sim import SimulatedRig
    from recorder._sim.skin import SkinHardware

F64 = NDArray[np.float64]

SURFACE_GAP_M: Final = 0.02
"""Gap between the TCP at an object's pose and the object's top face, m (the simulator's
``start_gap_m``: its approach starts this far above the face)."""
SUB_NS: Final = 1_000_000
"""Controller time between two skin samples, ns (1 kHz, the fastest sensor's rate)."""
_HISTORY: Final = 64
"""Samples of the resonance's input kept between cycles (its response decays within them)."""


@dataclass(frozen=True, slots=True)
class Surface:
    """An object's top face: a plane, and its axes for the texture.

    Attributes:
        point: A point of the face (under the pose), base frame, m.
        normal: The face's outward normal (towards the arm), base frame.
        along: The tool's x axis at placement (the slide direction), base frame.
    """

    point: F64
    normal: F64
    along: F64

    @classmethod
    def below(cls, tcp: F64) -> Surface:
        """Return the face :data:`SURFACE_GAP_M` below a TCP transform (4x4) along its z."""
        down = tcp[:3, 2]
        return cls(tcp[:3, 3] + SURFACE_GAP_M * down, -down, tcp[:3, 0].copy())

    def depth(self, position: F64) -> F64:
        """Return how far points (..., 3) lie below the face, m (negative: above it)."""
        depth: F64 = (self.point - position) @ self.normal
        return depth

    def slid(self, position: F64) -> F64:
        """Return points' (..., 3) coordinate along the slide direction, m."""
        along: F64 = (position - self.point) @ self.along
        return along


@dataclass(frozen=True, slots=True)
class Touch:
    """What an announced execution touches: the object as it is at that spot.

    Attributes:
        object_id: The object.
        obj: Its physics at the spot (the execution's draw).
        conditions: The execution's conditions (location, tilt, gains, ridges).
        law: One force sensor's contact law.
        offsets: Each force sensor's depth over the patch centre's, (c, 3), m; NaN: off.
        depths: Patch-centre depths of the force curve, m.
        totals: Total elastic force at those depths, N (non-decreasing).
        temp_offset: Each temperature sensor's offset (aged by the trial), C.
    """

    object_id: str
    obj: ObjectPhysics
    conditions: Conditions
    law: contact.ContactLaw
    offsets: F64
    depths: F64
    totals: F64
    temp_offset: F64

    def depth_for(self, force_n: float) -> float:
        """Return the patch-centre depth at which the total elastic force is ``force_n``."""
        return float(np.interp(force_n, self.totals, self.depths))


def _stable(text: str) -> int:
    return zlib.crc32(text.encode("utf-8"))


@dataclass
class SkinModel:
    """The skin's sensors and the touched object, stepped one controller cycle at a time."""

    sim: SimulatedRig
    seed: int = 0
    rng: np.random.Generator = field(init=False)
    hardware: SkinHardware = field(init=False)
    touch: Touch | None = field(default=None, init=False)
    _memory: F64 = field(init=False)
    _force_offset: F64 = field(init=False)
    _drift_rate: F64 = field(init=False)
    _drift_since_s: float = field(default=0.0, init=False)
    _cover: F64 = field(init=False)
    _sensor: F64 = field(init=False)
    _touching_since: F64 = field(init=False)
    _source: F64 = field(init=False)
    _last_force: F64 = field(init=False)
    _points: F64 = field(init=False)

    def __post_init__(self) -> None:
        """Draw the skin's offsets and start it in free air at its heater's set point."""
        self.rng = np.random.default_rng(np.random.SeedSequence([self.seed, _stable("vlab")]))
        self.hardware = self.sim._hardware  # noqa: SLF001 (the simulator's skin, read only)
        cells = self.hardware.n_cells
        shape = (cells, skin.FORCE_SENSORS)
        self._memory = np.zeros(shape)
        self._force_offset = skin.FORCE_OFFSET_N * self.rng.standard_normal(shape)
        self._drift_rate = skin.FORCE_DRIFT_N_S * self.rng.standard_normal(shape)
        set_point = self.sim.config.skin_c
        self._cover = np.full(cells, set_point)
        self._sensor = np.full(cells, set_point)
        self._touching_since = np.full(cells, np.nan)
        self._source = np.zeros((_HISTORY, cells, 3))
        self._last_force = np.zeros(shape)
        self._points = self.hardware.force_sensor_positions()

    @property
    def cells(self) -> int:
        """Return the number of cells."""
        return self.hardware.n_cells

    def begin(self, obj: ObjectSpec, action: ActionSpec, trial: int, world_s: float) -> Touch:
        """Draw the conditions of an announced execution (the spot touched, the skin's gains).

        The force offsets carry on (a real skin's do); their drift takes a new rate.

        Raises:
            ValueError: The object has no physics, or the skin cannot land on its face.
        """
        if obj.physics is None:
            msg = f"object {obj.id!r} has no physical parameters; the virtual lab cannot touch it"
            raise ValueError(msg)
        sequence = np.random.SeedSequence(
            [self.seed, _stable(obj.id), _stable(action.id), trial, _stable("vlab")]
        )
        rng = np.random.default_rng(sequence)
        conditions = Conditions.draw(obj.physics, self.sim.config, self.hardware, rng, trial)
        offsets = sensor_offsets(conditions.obj, conditions, self.hardware)
        if np.isnan(offsets).all():
            msg = f"object {obj.id!r}: its top face is too small for the skin to land on"
            raise ValueError(msg)
        law = contact.contact_law(conditions.obj)
        gain = conditions.force_gain
        first = -float(np.nanmax(offsets))
        depths = first + np.linspace(0.0, 0.015, 1500)
        totals = np.maximum.accumulate(contact.total_force_curve(law, offsets, gain, depths))
        temp_offset, _ = self.hardware.aged(trial)
        self._force_offset += self._drift_rate * (world_s - self._drift_since_s)
        self._drift_rate = skin.FORCE_DRIFT_N_S * self.rng.standard_normal(self._drift_rate.shape)
        self._drift_since_s = world_s
        self.touch = Touch(
            obj.id, conditions.obj, conditions, law, offsets, depths, totals, temp_offset
        )
        return self.touch

    def total_force(self) -> float:
        """Return the true total normal force of the last sample, N."""
        return float(self._last_force.sum())

    def sample(
        self, surface: Surface | None, positions: F64, world_s: F64, dt_s: float
    ) -> dict[str, F64]:
        """Return the skin's readings at a cycle's sample times.

        Args:
            surface: The touched object's face (None: nothing under the arm).
            positions: The TCP position at each sample, shape (m, 3), m.
            world_s: World time of each sample, shape (m,), s.
            dt_s: World time the cycle covers, s.

        Returns:
            Modality -> readings: force and acceleration (m, c, 3), temperature and proximity
            (c, 1) (the cycle's last).
        """
        touch = self.touch if surface is not None else None
        m, cells = positions.shape[0], self.cells
        if touch is None or surface is None:
            true = np.zeros((m, cells, skin.FORCE_SENSORS))
            distance = np.full(cells, skin.PROXIMITY_RANGE_M)
            vibration = self._vibrate(np.zeros((0, cells, 3)), m)
            reflectance = skin.NOMINAL_REFLECTANCE
        else:
            depth, slid = surface.depth(positions), surface.slid(positions)
            true = self._forces(touch, depth, slid, dt_s / m)
            cell_offset = np.nan_to_num(np.nanmean(touch.offsets, axis=1), nan=0.0)
            distance = np.maximum(-(depth[-1] + cell_offset), 0.0)
            source = self._sliding(touch, slid, true.sum(axis=2), dt_s)
            vibration = self._vibrate(source, m)
            reflectance = touch.obj.reflectance
        self._last_force = true[-1]
        self._heat(touch, true[-1].sum(axis=1), world_s[-1], dt_s)
        return {
            "force": self._read_force(true, world_s, touch),
            "acceleration": self._read_acceleration(vibration),
            "temperature": self._read_temperature(touch)[:, None],
            "proximity": skin.measure_proximity(
                distance[None], reflectance, self.hardware, self.rng
            )[0][:, None],
        }

    def _forces(self, touch: Touch, depth: F64, slid: F64, dt_s: float) -> F64:
        """Return every force sensor's true force at the samples, (m, c, 3), N."""
        from scipy.signal import lfilter  # noqa: PLC0415 (scipy.signal: ~0.8 s to import, on use)

        decay = float(np.exp(-dt_s / touch.law.relaxation_s))
        shape = (depth.shape[0], *touch.offsets.shape)
        if float(depth.max()) < float(touch.depths[0]) - touch.obj.texture_amplitude_m:
            self._memory = self._memory * decay ** depth.shape[0]  # out of contact
            return np.zeros(shape)
        relief = texture.ridge_relief(touch.obj, slid, self._points, touch.conditions.slide)
        local = depth[:, None, None] + np.nan_to_num(touch.offsets, nan=-1.0) + relief
        elastic = touch.law.elastic(local)
        # the relaxation's low-pass, continued from the last cycle (its state: the memory)
        memory, _ = lfilter(
            [1.0 - decay], [1.0, -decay], elastic, axis=0, zi=(decay * self._memory)[None]
        )
        self._memory = memory[-1]
        force: F64 = np.maximum(elastic - touch.law.relaxation * memory, 0.0)
        return force

    def _sliding(self, touch: Touch, slid: F64, cell_force: F64, dt_s: float) -> F64:
        """Return the vibration source at 1 kHz of world time while sliding, (n, c, 3)."""
        count = max(2, round(dt_s * RATE_HZ))
        start = float(slid[0]) - (float(slid[-1]) - float(slid[0])) / max(slid.shape[0], 1)
        path = np.linspace(start, float(slid[-1]), count + 1)[1:]
        force = np.repeat(cell_force[-1:], count, axis=0)
        speed = abs(float(path[-1] - start)) / dt_s
        cells = self.hardware.n_cells
        if speed < texture.MOVING_SPEED_M_S or float(force.sum()) <= 0:
            return np.zeros((count, cells, 3))
        obj = touch.obj
        ridges = texture._ridge_acceleration(  # noqa: SLF001 (the simulator's texture model)
            obj, path, self.hardware.centres, touch.conditions.slide
        )
        scale = (
            texture.FRICTION_NOISE_GAIN
            * obj.friction_kinetic
            * obj.fine_roughness_m
            * np.sqrt(speed / 0.01)
            * np.sqrt(np.maximum(force, 0.0) / 0.03)
        )
        noise = self.rng.standard_normal((count, cells, 3)) * scale[..., None]
        angle = touch.conditions.slide.ridge_angle
        source = np.empty((count, cells, 3))
        source[..., 0] = texture.RIDGE_PUSH * np.cos(angle) * ridges + obj.friction_kinetic * ridges
        source[..., 0] += noise[..., 0]
        source[..., 1] = texture.RIDGE_PUSH * np.sin(angle) * ridges + 0.5 * noise[..., 1]
        source[..., 2] = ridges + 0.4 * (0.5 * noise[..., 0] + 0.87 * noise[..., 2])
        contact_share = force / (force + texture.CONTACT_SCALE_N)
        source *= contact_share[..., None]
        return source

    def _vibrate(self, source: F64, m: int) -> F64:
        """Return the cells' vibration at the cycle's m samples (the resonance, continued).

        The resonance is filtered over the last inputs and the new ones: its response decays
        within :data:`_HISTORY` samples, so the filter's state need not be kept.
        """
        if source.shape[0] == 0:
            source = np.zeros((m, self.cells, 3))
        joined = np.concatenate([self._source, source])
        self._source = joined[-_HISTORY:]
        touch = self.touch
        if touch is None or not np.any(joined):
            return np.zeros((m, self.cells, 3))
        resonance = texture.Resonance.on(touch.obj, touch.law)
        out = resonance.filter(joined)[-source.shape[0] :]
        picks = np.round(np.arange(1, m + 1) * source.shape[0] / m).astype(np.int64) - 1
        vibration: F64 = out[picks]
        return vibration

    def _heat(self, touch: Touch | None, cell_force: F64, world_s: float, dt_s: float) -> None:
        """Step the thermal model one cycle (the simulator's, made causal)."""
        set_point = self.sim.config.skin_c
        surface = np.full(self.cells, set_point)
        touching = cell_force > thermal.CONTACT_FORCE_N
        began = np.where(np.isnan(self._touching_since), world_s, self._touching_since)
        self._touching_since = np.where(touching, began, np.nan)
        if touch is not None and touching.any():
            since = np.nan_to_num(world_s - self._touching_since, nan=0.0)
            effusivity = thermal.effusivity_over_time(touch.obj, since)
            room = self.sim.config.room_c
            interface = (thermal.SKIN_EFFUSIVITY * set_point + effusivity * room) / (
                thermal.SKIN_EFFUSIVITY + effusivity
            )
            force = np.maximum(cell_force, 0.0)
            conductance = np.where(
                touching, force / (force + thermal.HALF_CONDUCTANCE_FORCE_N), 0.0
            )
            surface = set_point - np.minimum(conductance, 1.0) * (set_point - interface)
        self._cover += -np.expm1(-dt_s / thermal.COVER_LAG_S) * (surface - self._cover)
        self._sensor += -np.expm1(-dt_s / thermal.SENSOR_LAG_S) * (self._cover - self._sensor)

    def _read_force(self, true: F64, world_s: F64, touch: Touch | None) -> F64:
        gain = touch.conditions.force_gain if touch is not None else self.hardware.force_gain
        since = (world_s - self._drift_since_s)[:, None, None]
        offset = self._force_offset + self._drift_rate * since
        noise = skin.FORCE_NOISE_N * self.rng.standard_normal(true.shape)
        return skin.quantize(gain * true + offset + noise, skin.FORCE_LSB_N)

    def _read_acceleration(self, vibration: F64) -> F64:
        specific = vibration.copy()
        specific[..., 2] -= skin.GRAVITY_M_S2
        reading: Any = skin.measure_acceleration(specific, self.hardware, self.rng)
        return np.asarray(reading, dtype=np.float64)

    def _read_temperature(self, touch: Touch | None) -> F64:
        offset = touch.temp_offset if touch is not None else self.hardware.temp_offset
        noise = skin.TEMP_NOISE_C * self.rng.standard_normal(self.cells)
        return skin.quantize(self._sensor + offset + noise, skin.TEMP_LSB_C)
