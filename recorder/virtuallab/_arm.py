"""The virtual lab's arm: a kinematic UR10 moved by resolved rate, one controller cycle a step.

The controller keeps a commanded TCP twist (linear m/s, angular rad/s, base frame), changed
each cycle towards what the running URScript call asks for, never faster than the call's
acceleration ``a`` allows. The commanded twist is integrated into a target TCP pose; the
joints follow by resolved rate: ``dq = J(q)^-1 (target - FK(q))`` (one Newton step of the
tool-point error, as a twist), with the UR10's DH Jacobian (:mod:`recorder._sim.ur10`). The
TCP the controller reports is always the forward kinematics of the joints, with the
simulator's tool transform, so joints and pose agree in every package; the actual TCP speed
is the pose's change over the cycle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Final

import numpy as np
from numpy.typing import NDArray

from recorder._sim import ur10
from recorder._sim.rig import Q_REFERENCE, TOOL

F64 = NDArray[np.float64]

#: Default TCP acceleration of a call without ``a`` (URScript's default for movel), m/s^2.
DEFAULT_ACCELERATION: Final = 1.2
#: Angular acceleration and speed bounds of a Cartesian move, rad/s^2 and rad/s.
ANGULAR_ACCELERATION: Final = 1.4
ANGULAR_SPEED: Final = 0.5
#: Speeds below this count as zero, m/s (and rad/s).
STILL: Final = 1e-9


# Rotations are converted by hand: scipy's Rotation objects cost more than the whole rest of
# a controller cycle, which runs 125 to 500 times a second.


def rotation_matrix(rotvec: F64) -> F64:
    """Return the rotation matrix of a rotation vector (Rodrigues' formula)."""
    angle = float(np.sqrt(rotvec @ rotvec))
    if angle < 1e-12:  # noqa: PLR2004 (no rotation)
        return np.eye(3)
    x, y, z = rotvec / angle
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    matrix: F64 = np.eye(3) + np.sin(angle) * k + (1.0 - np.cos(angle)) * (k @ k)
    return matrix


def rotation_vector(matrix: F64) -> F64:
    """Return the rotation vector of a rotation matrix (exact near a half turn too).

    The axis comes from the antisymmetric part, or near a half turn (the tool pointing down
    is one) from the symmetric part ``cos(t) I + (1 - cos(t)) n n^T``.
    """
    m = matrix
    skew = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])
    cosine = min(1.0, max(-1.0, 0.5 * (m[0, 0] + m[1, 1] + m[2, 2] - 1.0)))
    angle = math.acos(cosine)
    if angle < 1e-6:  # noqa: PLR2004 (sin(t) ~ t)
        return 0.5 * skew
    if angle < math.pi - 1e-3:
        return skew * (angle / (2.0 * math.sin(angle)))
    outer = (0.5 * (m + m.T) - cosine * np.eye(3)) / (1.0 - cosine)
    pivot = int(np.argmax(np.diag(outer)))
    axis = outer[:, pivot] / math.sqrt(outer[pivot, pivot])
    if float(axis @ skew) < 0:
        axis = -axis
    vector: F64 = axis * angle
    return vector


def pose_matrix(pose: F64) -> F64:
    """Return the 4x4 transform of a pose (x, y, z, rx, ry, rz)."""
    matrix = np.eye(4)
    matrix[:3, :3] = rotation_matrix(np.asarray(pose[3:6], dtype=np.float64))
    matrix[:3, 3] = pose[:3]
    return matrix


def matrix_pose(matrix: F64) -> F64:
    """Return the pose (x, y, z, rx, ry, rz) of a 4x4 transform."""
    return np.concatenate([matrix[:3, 3], rotation_vector(matrix[:3, :3])])


def twist_between(start: F64, end: F64) -> F64:
    """Return the twist (translation, rotation vector, base frame) taking ``start`` to ``end``."""
    rotation = rotation_vector(end[:3, :3] @ start[:3, :3].T)
    return np.concatenate([end[:3, 3] - start[:3, 3], rotation])


def apply_twist(pose: F64, twist: F64) -> F64:
    """Return ``pose`` moved by a twist (translation, rotation vector, base frame)."""
    moved = pose.copy()
    moved[:3, 3] += twist[:3]
    moved[:3, :3] = rotation_matrix(twist[3:]) @ pose[:3, :3]
    return moved


def approach_rate(
    current: float, wanted: float, limit: float, acceleration: float, dt: float
) -> float:
    """Return the next speed towards ``wanted`` (<= ``limit``), changed by at most ``a dt``."""
    target = min(wanted, limit)
    step = acceleration * dt
    return min(current + step, target) if target > current else max(current - step, target)


def ramp(current: F64, wanted: F64, acceleration: float, dt: float) -> F64:
    """Return a vector moved towards ``wanted`` by at most ``acceleration * dt`` (its norm)."""
    change = wanted - current
    size = float(np.linalg.norm(change))
    step = acceleration * dt
    if size <= step:
        return wanted.copy()
    return current + change * (step / size)


@dataclass
class KinematicArm:
    """A UR10's joints, moved by resolved rate; its TCP is the forward kinematics of the joints.

    Attributes:
        q: Joint positions, rad.
        qd: Joint velocities over the last step, rad/s.
        target: The target TCP pose the joints follow, 4x4.
        twist: Commanded TCP twist (m/s, rad/s, base frame).
        tcp_speed: Actual TCP twist over the last step (m/s, rad/s, base frame).
    """

    q: F64
    qd: F64 = field(default_factory=lambda: np.zeros(6))
    target: F64 = field(default_factory=lambda: np.eye(4))
    twist: F64 = field(default_factory=lambda: np.zeros(6))
    tcp_speed: F64 = field(default_factory=lambda: np.zeros(6))
    _frames: F64 = field(default_factory=lambda: np.zeros((1, 7, 4, 4)))
    _gravity: F64 = field(default_factory=lambda: np.zeros(6))
    _gravity_q: F64 | None = None
    _settled: bool = False
    _jacobian: F64 | None = None

    @classmethod
    def at(cls, pose: F64) -> KinematicArm:
        """Return an arm at rest with its TCP at ``pose`` (the solution nearest the reference)."""
        matrix = pose_matrix(np.asarray(pose, dtype=np.float64))
        q = ur10.inverse(matrix[None], Q_REFERENCE, TOOL)[0]
        arm = cls(q)
        arm._refresh()
        arm.target = arm.tcp()
        return arm

    def _refresh(self) -> None:
        self._frames = ur10.link_frames(self.q[None])
        self._jacobian = None

    def tcp(self) -> F64:
        """Return the TCP transform: the forward kinematics of the joints (4x4)."""
        end: F64 = self._frames[0, 6] @ TOOL
        return end

    def pose(self) -> F64:
        """Return the TCP pose (x, y, z, rx, ry, rz)."""
        return matrix_pose(self.tcp())

    def frames(self) -> F64:
        """Return the DH frames of the joints, shape (1, 7, 4, 4)."""
        return self._frames

    def place(self, pose: F64) -> None:
        """Put the arm at ``pose`` at once, at rest (a seam for tests; no controller does)."""
        matrix = pose_matrix(np.asarray(pose, dtype=np.float64))
        self.q = ur10.inverse(matrix[None], self.q, TOOL)[0]
        self._refresh()
        self.target = self.tcp()
        self.twist, self.qd, self.tcp_speed = np.zeros(6), np.zeros(6), np.zeros(6)
        self._settled = False

    def step(self, twist: F64, dt: float) -> None:
        """Move for ``dt`` s with the commanded TCP twist ``twist``, by resolved rate."""
        before = self.tcp()
        self.twist = twist
        moving = bool(np.any(twist != 0))
        if moving:
            self.target = apply_twist(self.target, twist * dt)
        elif self._settled:
            self.qd, self.tcp_speed = np.zeros(6), np.zeros(6)
            return
        error = twist_between(before, self.target)
        self._settled = not moving and float(np.abs(error).max()) < 1e-12  # noqa: PLR2004
        if float(np.abs(error).max()) > 0:
            jac = ur10.frame_jacobian(self._frames, TOOL)[0]
            self._jacobian = jac
            dq = np.linalg.solve(jac, error)
            self.q = self.q + dq
            self.qd = dq / dt
            self._refresh()
            self._jacobian = jac
        else:
            self.qd = np.zeros(6)
        self.tcp_speed = twist_between(before, self.tcp()) / dt

    def aim(self, target: F64) -> None:
        """Make ``target`` the pose the joints follow (reached in the next step)."""
        self.target = target
        self._settled = False

    def halt(self) -> None:
        """Stop where the arm is (a protective stop): no twist, the target is the TCP."""
        self.target = self.tcp()
        self.twist = np.zeros(6)
        self._settled = False

    def torques(self, force: F64) -> F64:
        """Return the joint torques holding the arm against gravity and ``force`` on the TCP.

        ``tau = g(q) - J_v(q)^T f`` (the simulator's static model); the gravity part changes
        slowly and is computed again only after the joints moved by more than 1 mrad.
        """
        if self._gravity_q is None or float(np.abs(self.q - self._gravity_q).max()) > 1e-3:  # noqa: PLR2004
            zero = np.zeros((1, 3))
            self._gravity = ur10.static_torques(self._frames, TOOL, zero)[0]
            self._gravity_q = self.q.copy()
        if self._jacobian is None:
            self._jacobian = ur10.frame_jacobian(self._frames, TOOL)[0]
        linear = self._jacobian[:3]  # of the cycle's start: the joints moved < 1 mrad since
        torques: F64 = self._gravity - linear.T @ force
        return torques
