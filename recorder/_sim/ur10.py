"""UR10 (CB3) kinematics and static joint torques from the published DH parameters.

Standard Denavit-Hartenberg convention with the parameters Universal Robots publishes for the
UR10 ("DH parameters for calculations of kinematics and dynamics"): link lengths ``a``,
offsets ``d``, twists ``alpha``, link masses and centres of mass (in each link's DH frame).
Every function is vectorised over a leading sample axis.
"""

from __future__ import annotations

from typing import Final

import numpy as np
from numpy.typing import NDArray

F64 = NDArray[np.float64]

D: Final = np.array([0.1273, 0.0, 0.0, 0.163941, 0.1157, 0.0922])
"""DH offsets d_i, m."""
A: Final = np.array([0.0, -0.612, -0.5723, 0.0, 0.0, 0.0])
"""DH link lengths a_i, m."""
ALPHA: Final = np.array([np.pi / 2, 0.0, 0.0, np.pi / 2, -np.pi / 2, 0.0])
"""DH twists alpha_i, rad."""
MASS: Final = np.array([7.1, 12.7, 4.27, 2.0, 2.0, 0.365])
"""Link masses, kg."""
CENTRE_OF_MASS: Final = np.array(
    [
        [0.021, 0.0, 0.027],
        [0.38, 0.0, 0.158],
        [0.24, 0.0, 0.068],
        [0.0, 0.007, 0.018],
        [0.0, 0.007, 0.018],
        [0.0, 0.0, -0.026],
    ]
)
"""Centre of mass of each link in its own DH frame, m."""
GRAVITY: Final = np.array([0.0, 0.0, -9.81])
"""Gravity in the base frame, m/s^2."""


def _dh_transforms(q: F64) -> F64:
    """Return the six DH link transforms, shape (n, 6, 4, 4), for joint angles (n, 6)."""
    ct, st = np.cos(q), np.sin(q)
    ca, sa = np.cos(ALPHA), np.sin(ALPHA)
    t = np.zeros((*q.shape, 4, 4))
    t[..., 0, 0], t[..., 0, 1], t[..., 0, 2], t[..., 0, 3] = ct, -st * ca, st * sa, A * ct
    t[..., 1, 0], t[..., 1, 1], t[..., 1, 2], t[..., 1, 3] = st, ct * ca, -ct * sa, A * st
    t[..., 2, 1], t[..., 2, 2], t[..., 2, 3] = sa, ca, D
    t[..., 3, 3] = 1.0
    return t


def link_frames(q: F64) -> F64:
    """Return the base-frame pose of DH frames 0..6 for joint angles ``q``.

    Args:
        q: Joint angles, shape (n, 6), rad.

    Returns:
        Shape (n, 7, 4, 4): frame 0 is the base, frame 6 the tool flange.
    """
    q = np.atleast_2d(q)
    links = _dh_transforms(q)
    frames = np.empty((q.shape[0], 7, 4, 4))
    frames[:, 0] = np.eye(4)
    for i in range(6):
        frames[:, i + 1] = frames[:, i] @ links[:, i]
    return frames


def forward(q: F64, tool: F64 | None = None) -> F64:
    """Return the flange (or tool) pose in the base frame.

    Args:
        q: Joint angles, shape (n, 6), rad.
        tool: Optional tool transform in the flange frame, shape (4, 4).

    Returns:
        Homogeneous transforms, shape (n, 4, 4).
    """
    pose = link_frames(q)[:, 6]
    return pose if tool is None else pose @ tool


def jacobian(q: F64, tool: F64 | None = None) -> F64:
    """Return the geometric Jacobian of the flange (or tool) point in the base frame.

    Args:
        q: Joint angles, shape (n, 6), rad.
        tool: Optional tool transform in the flange frame, shape (4, 4).

    Returns:
        Shape (n, 6, 6): rows are linear then angular velocity, columns the joints.
    """
    return frame_jacobian(link_frames(q), np.eye(4) if tool is None else tool)


def frame_jacobian(frames: F64, tool: F64) -> F64:
    """Return the geometric Jacobian of the tool point from the DH frames.

    Args:
        frames: DH frames, shape (n, 7, 4, 4) (:func:`link_frames`).
        tool: Tool transform in the flange frame, shape (4, 4).

    Returns:
        Shape (n, 6, 6): rows are linear then angular velocity, columns the joints.
    """
    end = frames[:, 6] @ tool
    axes = frames[:, :6, :3, 2]
    origins = frames[:, :6, :3, 3]
    jac = np.empty((frames.shape[0], 6, 6))
    jac[:, :3] = np.cross(axes, end[:, None, :3, 3] - origins).transpose(0, 2, 1)
    jac[:, 3:] = axes.transpose(0, 2, 1)
    return jac


def _link(i: int, theta: F64) -> F64:
    """Return the DH transform of joint ``i`` (0-based) at angles ``theta`` (n,), (n, 4, 4)."""
    ct, st = np.cos(theta), np.sin(theta)
    ca, sa = np.cos(ALPHA[i]), np.sin(ALPHA[i])
    t = np.zeros((theta.shape[0], 4, 4))
    t[:, 0, 0], t[:, 0, 1], t[:, 0, 2], t[:, 0, 3] = ct, -st * ca, st * sa, A[i] * ct
    t[:, 1, 0], t[:, 1, 1], t[:, 1, 2], t[:, 1, 3] = st, ct * ca, -ct * sa, A[i] * st
    t[:, 2, 1], t[:, 2, 2], t[:, 2, 3] = sa, ca, D[i]
    t[:, 3, 3] = 1.0
    return t


def _rigid_inverse(t: F64) -> F64:
    """Return the inverses of rigid transforms, shape (..., 4, 4)."""
    inv = np.zeros_like(t)
    rot_t = np.swapaxes(t[..., :3, :3], -1, -2)
    inv[..., :3, :3] = rot_t
    inv[..., :3, 3] = -(rot_t @ t[..., :3, 3, None])[..., 0]
    inv[..., 3, 3] = 1.0
    return inv


def _solve_branch(flange: F64, branch: F64) -> F64:
    """Closed-form inverse kinematics on given branches.

    Standard UR solution (Hawkins 2013, "Analytic inverse kinematics for the Universal Robots
    UR-5/UR-10 arms"): joint 1 from the wrist centre, joint 5 from the offset along joint 1's
    axis, joint 6 from the orientation, then the planar 2R problem of joints 2 and 3.

    Args:
        flange: Flange poses, shape (n, 4, 4).
        branch: Signs (shoulder, wrist, elbow) per pose, shape (n, 3) or (3,), each +-1.

    Returns:
        Joint angles, shape (n, 6), rad.
    """
    shoulder, wrist, elbow = np.broadcast_to(branch, (flange.shape[0], 3)).T
    p06 = flange[:, :3, 3]
    x6, y6, z6 = flange[:, :3, 0], flange[:, :3, 1], flange[:, :3, 2]
    p05 = p06 - D[5] * z6
    radius = np.hypot(p05[:, 0], p05[:, 1])
    offset = np.arcsin(np.clip(D[3] / radius, -1.0, 1.0))
    q1 = np.arctan2(p05[:, 1], p05[:, 0]) + np.where(shoulder > 0, offset, np.pi - offset)
    s1, c1 = np.sin(q1), np.cos(q1)
    c5 = np.clip((p06[:, 0] * s1 - p06[:, 1] * c1 - D[3]) / D[5], -1.0, 1.0)
    q5 = wrist * np.arccos(c5)
    s5 = np.where(np.abs(np.sin(q5)) < 1e-12, 1e-12, np.sin(q5))  # noqa: PLR2004 - singular
    q6 = np.arctan2(-(y6[:, 0] * s1 - y6[:, 1] * c1) / s5, (x6[:, 0] * s1 - x6[:, 1] * c1) / s5)
    t14 = (
        _rigid_inverse(_link(0, q1))
        @ flange
        @ _rigid_inverse(_link(5, q6))
        @ _rigid_inverse(_link(4, q5))
    )
    px, py = t14[:, 0, 3], t14[:, 1, 3]
    c3 = np.clip((px**2 + py**2 - A[1] ** 2 - A[2] ** 2) / (2 * A[1] * A[2]), -1.0, 1.0)
    q3 = elbow * np.arccos(c3)
    q2 = np.arctan2(py, px) - np.arctan2(A[2] * np.sin(q3), A[1] + A[2] * c3)
    q4 = np.arctan2(t14[:, 1, 0], t14[:, 0, 0]) - q2 - q3
    return np.stack([q1, q2, q3, q4, q5, q6], axis=1)


BRANCHES: Final = np.array(
    [[s, w, e] for s in (1.0, -1.0) for w in (1.0, -1.0) for e in (1.0, -1.0)]
)
"""The eight (shoulder, wrist, elbow) branches of the UR inverse kinematics."""


def _wrap_near(q: F64, reference: F64) -> F64:
    """Return ``q`` shifted by multiples of 2 pi to lie within pi of ``reference``."""
    return reference + (q - reference + np.pi) % (2 * np.pi) - np.pi


def select_branch(target: F64, reference: F64, tool: F64 | None = None) -> F64:
    """Return the branch (shoulder, wrist, elbow signs) whose solution is nearest ``reference``.

    Args:
        target: One flange (or tool) pose, shape (4, 4).
        reference: A configuration near the wanted solution, shape (6,), rad.
        tool: Optional tool transform in the flange frame, shape (4, 4).

    Returns:
        The branch, shape (3,).
    """
    flange = target if tool is None else target @ _rigid_inverse(tool)
    solutions = _wrap_near(_solve_branch(np.repeat(flange[None], 8, axis=0), BRANCHES), reference)
    branch: F64 = BRANCHES[int(np.argmin(np.abs(solutions - reference).sum(axis=1)))]
    return branch


def inverse(target: F64, reference: F64, tool: F64 | None = None, branch: F64 | None = None) -> F64:
    """Solve the inverse kinematics in closed form, on one branch for every pose.

    The UR arm has eight solutions per pose; unless given, the branch (shoulder, wrist,
    elbow) is the one whose solution for the first pose is nearest to ``reference``, and it
    is kept for every pose (an action moves the arm a few centimetres, far from
    singularities).

    Args:
        target: Desired flange (or tool) poses, shape (n, 4, 4).
        reference: A configuration near the wanted solution, shape (6,), rad.
        tool: Optional tool transform in the flange frame, shape (4, 4).
        branch: The branch to use (:func:`select_branch`); chosen from the first pose if None.

    Returns:
        Joint angles, shape (n, 6), rad, each within pi of ``reference``.
    """
    if branch is None:
        branch = select_branch(target[0], reference, tool)
    flange = target if tool is None else target @ _rigid_inverse(tool)
    return _wrap_near(_solve_branch(flange, branch), reference)


def static_torques(frames: F64, tool: F64, force: F64) -> F64:
    """Return the joint torques that hold the arm against gravity and a force on the tool.

    Static equilibrium: the motors cancel the moment of every link's weight and of the
    external force about each joint axis, ``tau_j = -z_j . sum((r - o_j) x f)``.

    Args:
        frames: DH frames of the configurations, shape (n, 7, 4, 4) (:func:`link_frames`).
        tool: Tool transform in the flange frame, shape (4, 4); the force acts at its origin.
        force: External force on the tool in the base frame, shape (n, 3), N.

    Returns:
        Torques the motors apply, shape (n, 6), N m.
    """
    com = (frames[:, 1:, :3, :3] @ CENTRE_OF_MASS[:, :, None])[..., 0] + frames[:, 1:, :3, 3]
    # Weight of links j..5 about joint j: (sum m_i c_i - M_j o_j) x g.
    mass_moment = np.cumsum((MASS[:, None] * com)[:, ::-1], axis=1)[:, ::-1]
    mass_tail = np.cumsum(MASS[::-1])[::-1]
    origins = frames[:, :6, :3, 3]
    lever = mass_moment - mass_tail[:, None] * origins
    moment = np.cross(lever, GRAVITY)
    tool_point = (frames[:, 6] @ tool)[:, :3, 3]
    moment += np.cross(tool_point[:, None, :] - origins, force[:, None, :])
    torques: F64 = -(moment * frames[:, :6, :3, 2]).sum(axis=2)
    return torques


def quaternions(pose: F64) -> F64:
    """Return the orientation of poses as unit quaternions (x, y, z, w), sign made unique.

    Shepperd's method: of the four ways to read the quaternion off the rotation matrix, use
    the one with the largest pivot, for accuracy.

    Args:
        pose: Homogeneous transforms or rotations, shape (n, 4, 4) or (n, 3, 3).

    Returns:
        Quaternions, shape (n, 4).
    """
    m = pose[:, :3, :3]
    m00, m11, m22 = m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]
    pivots = np.stack([m00 + m11 + m22, m00 - m11 - m22, m11 - m00 - m22, m22 - m00 - m11], 1)
    choice = np.argmax(pivots, axis=1)
    root = np.sqrt(np.maximum(1.0 + pivots[np.arange(m.shape[0]), choice], 1e-300))
    a, b, c = m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]
    d, e, f = m[:, 0, 1] + m[:, 1, 0], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1]
    candidates = np.stack(
        [
            np.stack([a, b, c, root * root], 1),  # w largest
            np.stack([root * root, d, e, a], 1),  # x largest
            np.stack([d, root * root, f, b], 1),  # y largest
            np.stack([e, f, root * root, c], 1),  # z largest
        ],
        1,
    )
    quat = candidates[np.arange(m.shape[0]), choice] / (2.0 * root[:, None])
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    # q and -q are the same rotation: make the first clearly non-zero of w, x, y, z positive.
    ordered = quat[:, [3, 0, 1, 2]]
    first = np.argmax(np.abs(ordered) > 1e-9, axis=1)  # noqa: PLR2004 - numerical zero
    sign = np.sign(ordered[np.arange(m.shape[0]), first])
    canonical: F64 = quat * sign[:, None]
    return canonical


#: Joint names of the UR10, in the order of the joint-state arrays (ROS ur_robot_driver).
JOINT_NAMES = (
    "shoulder_pan_joint",
    "shoulder_lift_joint",
    "elbow_joint",
    "wrist_1_joint",
    "wrist_2_joint",
    "wrist_3_joint",
)
