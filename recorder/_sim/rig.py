"""The simulated rig: a UR10 with a skin (7 cells by default) exploring catalog objects.

Time: every execution starts at 0 ns (the start of the approach); stamps and receive times
are relative to it, and the recording covers ``[0, end)`` with ``end`` on a 0.1 s boundary.
No clock is read anywhere.

Determinism: the skin's hardware (mounting angles, gains, offsets and how fast they age) is
drawn from the rig's seed alone; everything that varies between executions is drawn from
``SeedSequence([seed, crc32(object id), crc32(action id), trial])``, so an execution's data
depend on nothing else (not on the order of executions, nor on the process). What a real
session carries from one action to the next (residual heat, the skin's ageing) is therefore
drawn per execution, or is a function of the trial (the session's round), never simulated
history. The spread of every source and the fact it is calibrated to: CALIBRATION.md.

Array shapes name the skin's cells ``c``: 7 for the thesis's patch, else ``SimConfig.cells``.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Final, Self

import numpy as np
from numpy.typing import NDArray

from recorder._catalog import check_object
from recorder._sim import contact, motion, skin, thermal, ur10
from recorder._sim.config import SimConfig
from recorder._sim.texture import SlideConditions, ridge_relief, sliding_vibration
from recorder.errors import RigError
from recorder.writing._stream import JointSample, Modality, PhaseEvent, PoseSample, SkinBlock
from schemas import VOCABULARY

if TYPE_CHECKING:
    from collections.abc import Iterator, Mapping
    from types import TracebackType

    from recorder._catalog import ActionSpec, ObjectPhysics, ObjectSpec
    from recorder.writing._stream import StreamItem

F64 = NDArray[np.float64]

SIMULATOR_VERSION: Final = "2"
"""Version of the physical model; recordings from different versions differ."""
SIMULATED_KINDS: Final = ("press", "slide", "static")
"""Action kinds the simulator has a model of (its motion and contact for each)."""
ROBOT_DECIMATION: Final = 8
"""RTDE publishes every 8 ms (125 Hz)."""
FORCE_DT_S: Final = motion.DT_S * motion.FORCE_DECIMATION
"""Forces and the thermal model run at the force sensors' 250 Hz."""
TEMPERATURE_DECIMATION: Final = 50
"""The temperature sensors sample at 20 Hz."""
TEMPERATURE_STEP: Final = TEMPERATURE_DECIMATION / motion.FORCE_DECIMATION
"""20 Hz samples fall every 12.5 samples of the 250 Hz thermal model."""
ROBOT_LATENCY_NS: Final = (1_000_000, 500_000)
"""RTDE transport latency: fixed part and uniform jitter, ns."""
SKIN_LATENCY_NS: Final = (2_000_000, 1_000_000)
"""Skin bus transport latency of a block: fixed part and uniform jitter, ns."""
EFFORT_DECIMATION: Final = 5
"""Gravity torques and the Jacobian are evaluated every 5 RTDE samples and interpolated."""
EFFORT_NOISE_N_M: Final = 0.1
"""Noise of the joint torques the controller estimates from motor currents."""
ORIENTATION_SPREAD_DEG: Final = 10.0
"""Objects are placed again by hand between trials: their yaw varies uniformly within +- this
(the thesis's lab rotated objects between rounds; no magnitude is reported, CALIBRATION.md)."""
FRICTION_SPREAD: Final = 0.08
"""Relative spread of friction between executions (humidity, dust, wear of the cover)."""
CONDUCTANCE_SPREAD: Final = 0.03
"""Relative spread of the thermal contact conductance between executions: what the real
probe's aluminium drop (2.40 +- 0.16 C, 6.5 %) leaves after the ambient drift (4 %) and the
residual heat (4 %) (CALIBRATION.md)."""
CONDUCTANCE_MEDIAN: Final = 0.985
"""Median factor on the contact conductance. The factor is capped at full conductance; the
former 10 % spread lowered the mean through that cap, and this median keeps the mean drops
where they were calibrated (wood 0.48 C, aluminium 2.40 C after 5 s)."""
RESIDUAL_HEAT_C: Final = 0.1
"""Mean deficit of the skin below its set point when an action starts, C: the 30 s pause
between actions is too short for the heater to recover fully."""
RESIDUAL_HEAT_SHAPE: Final = 3.0
"""Shape of the gamma distribution of that deficit (sd 0.058 C): with the other sources the
skin's temperature at the 1 N onset varies by 0.07 C, the real probe's by 0.08 C."""
RECOVERY_SPREAD_C_S: Final = 0.025
"""Spread (sd) of the rate at which the skin is still recovering from earlier touches when an
action starts, C/s (signed: the heater overshoots while it recovers; zero mean, so the mean
drops stay as calibrated). It sets the spread of the 5 s drop on wood to the real probe's
0.10 C; the real probe still changes by 0.086 +- 0.047 C/s in the second before contact
(CALIBRATION.md)."""
WORKSPACE_XY_M: Final = (-0.70, -0.20)
"""Where objects lie on the table, in the robot's base frame."""
Q_REFERENCE: Final = np.array([0.05, -1.27, 2.04, -2.34, -np.pi / 2, 0.05])
"""Arm configuration above the workspace (elbow up, tool pointing down)."""
TOOL: Final = np.array([[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0.045], [0, 0, 0, 1.0]])
"""Skin patch surface centre (the TCP) in the flange frame: mount plus skin, 45 mm."""
TCP_ROTATION: Final = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])
"""TCP axes in the base frame: x (sliding) along base y, z pointing down into the object."""


def stable_hash(text: str) -> int:
    """Return a hash of ``text`` that is the same in every process (CRC-32)."""
    return zlib.crc32(text.encode("utf-8"))


@dataclass(frozen=True, slots=True)
class Conditions:
    """What varies from trial to trial.

    Attributes:
        obj: The object as it is at the touched spot (stiffness, texture depth, roughness and
            friction vary from spot to spot and day to day).
        room_c: Room (object) temperature, C.
        skin_state: The skin's thermal state at the start.
        location: Where the patch centre lands on the top face, object frame, shape (2,), m.
        yaw: The object's orientation about the vertical relative to the patch, rad.
        tilt: Slope of the top face relative to the patch along its x and y, shape (2,).
        irregularity: Height of the surface under each cell, shape (c,), m.
        height_error: How much higher the top face is than the robot believes, m.
        force_error: Relative error of the sliding force controller.
        force_gain: Gain of each force sensor during this execution, shape (c, 3).
        temp_offset: Offset of each temperature sensor during this execution, shape (c,), C.
        slide: Ridge angle and phases of the slide.
    """

    obj: ObjectPhysics
    room_c: float
    skin_state: thermal.SkinState
    location: F64
    yaw: float
    tilt: F64
    irregularity: F64
    height_error: float
    force_error: float
    force_gain: F64
    temp_offset: F64
    slide: SlideConditions

    @classmethod
    def draw(
        cls,
        obj: ObjectPhysics,
        config: SimConfig,
        hardware: skin.SkinHardware,
        rng: np.random.Generator,
        trial: int = 0,
    ) -> Conditions:
        """Draw the conditions of one execution.

        Args:
            obj: The object as the catalog describes it.
            config: The session's settings.
            hardware: The skin patch.
            rng: Random generator of this execution.
            trial: The trial, which is the round of the session: the skin has aged that long.

        Returns:
            The conditions.
        """
        temp_offset, aged_gain = hardware.aged(trial)
        yaw = float(np.deg2rad(ORIENTATION_SPREAD_DEG) * rng.uniform(-1.0, 1.0))
        spread = rng.standard_normal(5)
        friction = float(np.exp(FRICTION_SPREAD * spread[3]))
        spot = replace(
            obj,
            stiffness_n_m=obj.stiffness_n_m * float(np.exp(obj.variability * spread[0])),
            texture_amplitude_m=obj.texture_amplitude_m
            * float(np.exp(obj.variability * spread[1])),
            fine_roughness_m=obj.fine_roughness_m * float(np.exp(obj.variability * spread[2])),
            friction_static=obj.friction_static * friction,
            friction_kinetic=obj.friction_kinetic * friction,
        )
        skin_state = thermal.SkinState(
            set_point_c=config.skin_c,
            deficit_c=RESIDUAL_HEAT_C * float(rng.gamma(RESIDUAL_HEAT_SHAPE)) / RESIDUAL_HEAT_SHAPE,
            conductance=CONDUCTANCE_MEDIAN * float(np.exp(CONDUCTANCE_SPREAD * spread[4])),
            recovery_c_s=RECOVERY_SPREAD_C_S * float(rng.standard_normal()),
        )
        return cls(
            obj=spot,
            room_c=config.room_c + config.room_spread_c * float(rng.uniform(-0.5, 0.5)),
            skin_state=skin_state,
            location=config.location_spread_m * rng.uniform(-1.0, 1.0, 2),
            yaw=yaw,
            tilt=np.tan(np.deg2rad(config.tilt_deg)) * rng.standard_normal(2),
            irregularity=obj.flatness_m * rng.standard_normal(hardware.n_cells),
            height_error=config.height_spread_m * float(rng.uniform(-1.0, 1.0)),
            force_error=config.force_control_error * float(rng.standard_normal()),
            force_gain=aged_gain * (1.0 + skin.FORCE_GAIN_DRIFT * float(rng.standard_normal())),
            temp_offset=temp_offset,
            slide=SlideConditions(
                ridge_angle=float(np.deg2rad(obj.grain_angle_deg)) + yaw,
                phases=rng.uniform(0.0, 2.0 * np.pi, 3),
            ),
        )


def _on_object(obj: ObjectPhysics, conditions: Conditions, points: F64) -> NDArray[np.bool_]:
    """Return which patch points (..., 2) lie over the object's top face."""
    c, s = np.cos(conditions.yaw), np.sin(conditions.yaw)
    rotation = np.array([[c, -s], [s, c]])
    local = points @ rotation.T + conditions.location
    inside: NDArray[np.bool_] = (np.abs(local[..., 0]) <= obj.length_m / 2) & (
        np.abs(local[..., 1]) <= obj.width_m / 2
    )
    return inside


def sensor_offsets(obj: ObjectPhysics, conditions: Conditions, hardware: skin.SkinHardware) -> F64:
    """Return each force sensor's depth over the patch centre's, shape (c, 3), m.

    Tilt, the top face's curvature around its centre and its irregularity under each cell put
    some sensors deeper than others; sensors off the object are NaN.
    """
    points = hardware.force_sensor_positions()
    c, s = np.cos(conditions.yaw), np.sin(conditions.yaw)
    local = points @ np.array([[c, -s], [s, c]]).T + conditions.location
    dome = (
        -0.5 * obj.curvature_1_m * ((local**2).sum(axis=-1) - float((conditions.location**2).sum()))
    )
    offsets = points @ conditions.tilt + dome + conditions.irregularity[:, None]
    cells_on = _on_object(obj, conditions, hardware.centres)
    return np.where(cells_on[:, None], offsets, np.nan)


@dataclass(frozen=True, slots=True)
class Signals:
    """True (noise-free) signals of one execution.

    Attributes:
        plan: The motion.
        force: Normal force of every force sensor at 250 Hz, shape (n / 4, c, 3), N.
        specific_force: Accelerometer input in the patch frame, shape (n, c, 3), m/s^2.
        temperature: Sensor temperatures at 20 Hz, shape (n / 50, c), C.
        distance: Distance from each cell to the surface below, shape (n, c), m.
    """

    plan: motion.Plan
    force: F64
    specific_force: F64
    temperature: F64
    distance: F64


class SimulatedRig:
    """A physics-based simulation of the UR10 and skin rig; the embedded default rig.

    Use it as a context manager; ``perform`` streams one execution. The same seed, object,
    action and trial always give the same items.
    """

    def __init__(self, seed: int = 0, config: SimConfig | None = None) -> None:
        """Create a rig.

        Args:
            seed: Seed of the session; fixes the skin's hardware and every execution.
            config: Conditions and controller settings; the thesis set-up when None.

        Raises:
            RigError: The seed is negative.
        """
        # the thermal model's scipy.special, loaded with the rig and not in its first action:
        # importing it holds the interpreter (other threads: progress, readers) for 0.3 s
        import scipy.special  # noqa: PLC0415, F401

        if seed < 0:
            msg = f"SimulatedRig seed = {seed} must be >= 0"
            raise RigError(msg)
        self._seed = seed
        self._config = SimConfig() if config is None else config
        hardware_seed = np.random.SeedSequence([seed, stable_hash("skin hardware")])
        hardware_rng = np.random.default_rng(hardware_seed)
        self._hardware = skin.SkinHardware.draw(hardware_rng, self._config.skin)
        above = np.eye(4)
        above[:3, :3] = TCP_ROTATION
        above[:3, 3] = (*WORKSPACE_XY_M, 0.1)
        self._branch = ur10.select_branch(above, Q_REFERENCE, TOOL)
        self._connected = False

    def __enter__(self) -> Self:
        """Connect (nothing to open for a simulation)."""
        self._connected = True
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Disconnect."""
        self._connected = False

    @property
    def config(self) -> SimConfig:
        """The rig's settings."""
        return self._config

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Return the UR10's joint names, in the order of its joint-state arrays."""
        return ur10.JOINT_NAMES

    def describe(self) -> Mapping[str, str]:
        """Return the rig's kind and configuration (deterministic), for the metadata."""
        return {
            "kind": "simulated",
            "simulator_version": SIMULATOR_VERSION,
            "seed": str(self._seed),
            **self._config.describe(),
        }

    def perform(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> Iterator[StreamItem]:
        """Simulate ``action`` on ``obj`` as trial ``trial``; return its items by receive time.

        Raises:
            RigError: The rig is not connected, or the object, action or trial is invalid.
        """
        physics = self._check(obj, action, trial)
        sequence = np.random.SeedSequence(
            [self._seed, stable_hash(obj.id), stable_hash(action.id), trial]
        )
        rngs = [np.random.default_rng(child) for child in sequence.spawn(7)]
        conditions = Conditions.draw(physics, self._config, self._hardware, rngs[0], trial)
        signals = self._simulate(obj.id, action, conditions, rngs[1])
        items: list[StreamItem] = [
            *_phase_events(signals.plan),
            *self._skin_blocks(conditions, signals, rngs[2:6]),
            *self._robot_samples(action, conditions, signals, rngs[6]),
        ]
        items.sort(key=_receive_ns)  # stable: at equal times, events come first
        last = max(item.receive_ns for item in items)
        items.append(PhaseEvent(signals.plan.n * 1_000_000, last, "end"))
        return iter(items)

    def _check(self, obj: ObjectSpec, action: ActionSpec, trial: int) -> ObjectPhysics:
        """Refuse to perform outside a ``with`` block or with invalid inputs.

        Returns:
            The object's physical parameters.
        """
        if not self._connected:
            msg = "SimulatedRig.perform outside a with block; use `with SimulatedRig() as rig:`"
            raise RigError(msg)
        if obj.physics is None:
            msg = (
                f"object {obj.id!r} has no physical parameters (stiffness_n_m, effusivity, ...) "
                "in its catalog entry: the simulator cannot touch it; add them or use a real rig"
            )
            raise RigError(msg)
        problem = check_object(obj.physics)
        if problem is not None:
            msg = f"object {obj.id!r}: {problem}; fix its catalog entry"
            raise RigError(msg)
        if trial < 0:
            msg = f"trial = {trial} must be >= 0"
            raise RigError(msg)
        if action.kind not in SIMULATED_KINDS:
            msg = (
                f"action {action.id!r} is of kind {action.kind!r}, which the simulator cannot "
                f"perform (it simulates {', '.join(SIMULATED_KINDS)}); use a real rig"
            )
            raise RigError(msg)
        needed = {
            "press": action.depth_m,
            "static": action.depth_m,
            "slide": min(action.force_n, action.speed_m_s),
        }[action.kind]
        if not (needed > 0 and action.duration_s > 0):
            msg = (
                f"action {action.id!r}: duration_s and the {action.kind} parameters "
                "(depth_m, or force_n and speed_m_s) must be > 0; fix the action catalog"
            )
            raise RigError(msg)
        return obj.physics

    def _simulate(
        self, object_id: str, action: ActionSpec, conditions: Conditions, rng: np.random.Generator
    ) -> Signals:
        """Plan the motion and compute the true signals."""
        obj = conditions.obj
        law = contact.contact_law(obj)
        offsets = sensor_offsets(obj, conditions, self._hardware)
        if np.isnan(offsets).all():
            msg = (
                f"object {object_id!r}: its top face ({obj.length_m} x {obj.width_m} m) is too "
                "small for the skin to land on; enlarge it or reduce location_spread_m"
            )
            raise RigError(msg)
        gain = conditions.force_gain
        light = contact.depth_for_force(law, offsets, gain, self._config.contact_force_n)
        target = action.force_n * (1.0 + conditions.force_error)
        slide_depth = contact.depth_for_force(law, offsets, gain, target)
        bias = skin.reading_bias(obj.reflectance)
        approach = motion.plan_approach(self._config, bias, conditions.height_error, light)
        plan = motion.plan_execution(action, self._config, approach, slide_depth)
        force = self._forces(action, law, plan, offsets, conditions)
        cell_force = force.sum(axis=2)
        specific = _motion_specific_force(plan, self._hardware.n_cells)
        if action.kind == "slide":
            window = slice(plan.execute, plan.retract)
            held = np.repeat(cell_force, motion.FORCE_DECIMATION, axis=0)
            specific[window] += sliding_vibration(
                obj,
                law,
                plan.slide[window],
                cell_force=held[window],
                cells=self._hardware.centres,
                conditions=conditions.slide,
                rng=rng,
            )
        temperature = thermal.sensor_temperature(
            cell_force, FORCE_DT_S, obj, conditions.room_c, conditions.skin_state
        )
        distance = _cell_distances(obj, plan, offsets, conditions.height_error)
        return Signals(plan, force, specific, _resample(temperature, TEMPERATURE_STEP), distance)

    def _forces(
        self,
        action: ActionSpec,
        law: contact.ContactLaw,
        plan: motion.Plan,
        offsets: F64,
        conditions: Conditions,
    ) -> F64:
        """Return every force sensor's true force at 250 Hz, shape (n / 4, c, 3), N."""
        obj = conditions.obj
        samples = np.arange(0, plan.n, motion.FORCE_DECIMATION)
        relief = None
        if action.kind == "slide":
            relief = np.zeros((samples.shape[0], self._hardware.n_cells, skin.FORCE_SENSORS))
            inside = (samples >= plan.execute) & (samples < plan.retract)
            points = self._hardware.force_sensor_positions()
            slid = plan.slide[samples[inside]]
            relief[inside] = ridge_relief(obj, slid, points, conditions.slide)
        return contact.sensor_forces(law, plan.depth[samples], offsets, FORCE_DT_S, relief)

    def _skin_blocks(
        self, conditions: Conditions, signals: Signals, rngs: list[np.random.Generator]
    ) -> list[SkinBlock]:
        """Measure every skin modality and cut the readings into blocks."""
        hw, n, obj = self._hardware, signals.plan.n, conditions.obj
        t = (np.arange(n) * motion.DT_S).astype(np.float64)
        gain = conditions.force_gain
        force = skin.measure_force(signals.force, t[:: motion.FORCE_DECIMATION], gain, rngs[0])
        temperature = skin.measure_temperature(
            signals.temperature, t[::TEMPERATURE_DECIMATION], conditions.temp_offset, rngs[1]
        )
        acceleration = skin.measure_acceleration(signals.specific_force, hw, rngs[2])
        proximity = skin.measure_proximity(signals.distance[::20], obj.reflectance, hw, rngs[3])
        readings: dict[Modality, NDArray[np.floating[Any]]] = {
            "force": force,
            "temperature": temperature[..., None],
            "acceleration": acceleration,
            "proximity": proximity[..., None],
        }
        jitter = rngs[3].uniform(0.0, 1.0, 4 * (n // motion.BLOCK_SAMPLES))
        blocks: list[SkinBlock] = []
        for index, (modality, data) in enumerate(readings.items()):
            blocks.extend(_cut_blocks(modality, data, jitter[index::4]))
        return blocks

    def _robot_samples(
        self,
        action: ActionSpec,
        conditions: Conditions,
        signals: Signals,
        rng: np.random.Generator,
    ) -> list[JointSample | PoseSample]:
        """Compute the arm's joint states and TCP poses at 125 Hz."""
        plan, obj = signals.plan, conditions.obj
        index = np.arange(0, plan.n, ROBOT_DECIMATION)
        depth, slide = plan.depth[index], plan.slide[index]
        pose = np.tile(np.eye(4), (index.shape[0], 1, 1))
        pose[:, :3, :3] = TCP_ROTATION
        pose[:, 0, 3] = WORKSPACE_XY_M[0] + conditions.location[0]
        pose[:, 1, 3] = WORKSPACE_XY_M[1] + conditions.location[1] + slide
        surface = obj.height_m + conditions.height_error
        pose[:, 2, 3] = surface + conditions.tilt[0] * slide - depth
        q = ur10.inverse(pose, Q_REFERENCE, TOOL, self._branch)
        normal = signals.force[index // motion.FORCE_DECIMATION].sum(axis=(1, 2))
        wrench = np.zeros((index.shape[0], 3))
        wrench[:, 2] = normal
        moving = np.gradient(slide) > 0
        if action.kind == "slide":
            wrench[:, 1] = -obj.friction_kinetic * normal * moving
        effort = _static_efforts(q, wrench)
        effort += EFFORT_NOISE_N_M * rng.standard_normal(effort.shape)
        velocity = np.gradient(q, ROBOT_DECIMATION * motion.DT_S, axis=0)
        # The closed-form solution is exact: forward kinematics of q gives back ``pose``.
        quat = ur10.quaternions(pose)
        position = np.ascontiguousarray(pose[:, :3, 3])
        for array in (q, velocity, effort, quat, position):
            array.setflags(write=False)
        stamps = index * 1_000_000
        fixed, spread = ROBOT_LATENCY_NS
        receive = stamps + fixed + (spread * rng.uniform(0.0, 1.0, stamps.shape)).astype(np.int64)
        rows = zip(
            stamps.tolist(), receive.tolist(), q, velocity, effort, position, quat, strict=True
        )
        samples: list[JointSample | PoseSample] = []
        for stamp, rec, q_k, v_k, e_k, p_k, o_k in rows:
            samples.append(JointSample(stamp, rec, q_k, v_k, e_k))
            samples.append(PoseSample(stamp, rec, p_k, o_k))
        return samples


def _static_efforts(q: F64, wrench: F64) -> F64:
    """Return the joint torques against gravity and the contact force on the tool.

    Gravity torques and the Jacobian change slowly while the arm moves a few centimetres;
    they are computed every ``EFFORT_DECIMATION`` samples and interpolated linearly, while the
    force enters exactly: ``tau = g(q) - J_v(q)^T f``.
    """
    n = q.shape[0]
    coarse = np.unique(np.r_[np.arange(0, n, EFFORT_DECIMATION), n - 1])
    frames = ur10.link_frames(q[coarse])
    gravity = ur10.static_torques(frames, TOOL, np.zeros((coarse.shape[0], 3)))
    linear = ur10.frame_jacobian(frames, TOOL)[:, :3]
    table = np.concatenate([gravity, linear.reshape(coarse.shape[0], -1)], axis=1)
    samples = np.arange(n)
    right = np.clip(np.searchsorted(coarse, samples), 1, coarse.shape[0] - 1)
    left = right - 1
    weight = ((samples - coarse[left]) / (coarse[right] - coarse[left]))[:, None]
    smooth = (1.0 - weight) * table[left] + weight * table[right]
    jac = smooth[:, 6:].reshape(n, 3, 6)
    efforts: F64 = smooth[:, :6] - np.einsum("nij,ni->nj", jac, wrench)
    return efforts


def _resample(signal: F64, step: float) -> F64:
    """Sample ``signal`` (time on axis 0) every ``step`` samples, interpolating linearly."""
    position = np.arange(0.0, signal.shape[0], step)
    low = np.minimum(position.astype(np.int64), signal.shape[0] - 1)
    high = np.minimum(low + 1, signal.shape[0] - 1)
    weight = (position - low)[:, None]
    resampled: F64 = (1.0 - weight) * signal[low] + weight * signal[high]
    return resampled


def _receive_ns(item: StreamItem) -> int:
    """Sort key: receive time."""
    return item.receive_ns


def _phase_events(plan: motion.Plan) -> list[PhaseEvent]:
    """Return the phase events up to the retract (the end is added last)."""
    starts = [
        (0, "approach"),
        (plan.contact, "contact"),
        (plan.execute, "execute"),
        (plan.retract, "retract"),
    ]
    return [PhaseEvent(i * 1_000_000, i * 1_000_000, phase) for i, phase in starts]


def _motion_specific_force(plan: motion.Plan, cells: int) -> F64:
    """Return the accelerometers' input from the arm's motion and gravity, patch frame."""
    dt = motion.DT_S
    specific = np.zeros((plan.n, cells, 3))
    specific[..., 0] = np.gradient(np.gradient(plan.slide, dt), dt)[:, None]
    specific[..., 2] = np.gradient(np.gradient(plan.depth, dt), dt)[:, None] - skin.GRAVITY_M_S2
    return specific


def _cell_distances(
    obj: ObjectPhysics, plan: motion.Plan, offsets: F64, height_error: float
) -> F64:
    """Return each cell's distance to the surface below it over time, shape (n, c), m."""
    cell_offset = offsets.mean(axis=1)
    over_object = -(plan.depth[:, None] + np.nan_to_num(cell_offset, nan=0.0))
    over_table = -plan.depth[:, None] + obj.height_m + height_error
    distance: F64 = np.where(np.isnan(cell_offset), over_table, np.maximum(over_object, 0.0))
    return distance


def _cut_blocks(
    modality: Modality, data: NDArray[np.floating[Any]], jitter: F64
) -> list[SkinBlock]:
    """Cut one modality's readings (samples, c, channels) into the contract's blocks."""
    channel = VOCABULARY.modalities[modality]
    per_block = channel.block_samples
    period_ns = round(1e9 / channel.rate_hz)
    values = data.astype(np.float32)
    values.setflags(write=False)
    fixed, spread = SKIN_LATENCY_NS
    blocks = []
    for b in range(values.shape[0] // per_block):
        stamp = b * per_block * period_ns
        last = stamp + (per_block - 1) * period_ns
        receive = last + fixed + int(spread * jitter[b])
        chunk = values[b * per_block : (b + 1) * per_block]
        blocks.append(SkinBlock(modality, stamp, period_ns, receive, chunk))
    return blocks
