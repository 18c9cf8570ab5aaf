from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from recorder._sim import ur10
from recorder._sim.rig import Q_REFERENCE, TOOL


def _random_configurations(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(-np.pi, np.pi, (n, 6))


def test_zero_configuration_matches_the_published_geometry() -> None:
    pose = ur10.forward(np.zeros((1, 6)))[0]
    # Stretched arm: x = a2 + a3, y = -(d4 + d6), z = d1 - d5.
    expected = [-0.612 - 0.5723, -(0.163941 + 0.0922), 0.1273 - 0.1157]
    np.testing.assert_allclose(pose[:3, 3], expected, atol=1e-12)
    np.testing.assert_allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-12)


def test_inverse_recovers_random_configurations_on_their_branch() -> None:
    q = _random_configurations(200, seed=1)
    poses = ur10.forward(q)
    for k in range(q.shape[0]):
        solved = ur10.inverse(poses[k : k + 1], q[k])
        np.testing.assert_allclose(ur10.forward(solved), poses[k : k + 1], atol=1e-9)


def test_inverse_follows_a_path_with_the_tool() -> None:
    start = ur10.forward(Q_REFERENCE[None], TOOL)[0]
    path = np.repeat(start[None], 50, axis=0)
    path[:, 1, 3] += np.linspace(0.0, 0.05, 50)
    path[:, 2, 3] -= np.linspace(0.0, 0.03, 50)
    q = ur10.inverse(path, Q_REFERENCE, TOOL)
    np.testing.assert_allclose(ur10.forward(q, TOOL), path, atol=1e-10)
    assert np.abs(np.diff(q, axis=0)).max() < 0.01  # one branch, no jumps


def test_jacobian_matches_finite_differences() -> None:
    q = _random_configurations(5, seed=2)
    jac = ur10.jacobian(q, TOOL)
    step = 1e-7
    for joint in range(6):
        dq = np.zeros(6)
        dq[joint] = step
        plus, minus = ur10.forward(q + dq, TOOL), ur10.forward(q - dq, TOOL)
        linear = (plus[:, :3, 3] - minus[:, :3, 3]) / (2 * step)
        relative = plus[:, :3, :3] @ minus[:, :3, :3].transpose(0, 2, 1)
        angular = Rotation.from_matrix(relative).as_rotvec() / (2 * step)
        np.testing.assert_allclose(jac[:, :3, joint], linear, atol=1e-6)
        np.testing.assert_allclose(jac[:, 3:, joint], angular, atol=1e-6)


def _potential_energy(q: np.ndarray) -> np.ndarray:
    frames = ur10.link_frames(q)
    com = np.einsum("nlij,lj->nli", frames[:, 1:, :3, :3], ur10.CENTRE_OF_MASS)
    com += frames[:, 1:, :3, 3]
    energy: np.ndarray = -(ur10.MASS[None, :, None] * com * ur10.GRAVITY).sum(axis=(1, 2))
    return energy


def test_gravity_torques_are_the_gradient_of_potential_energy() -> None:
    q = _random_configurations(5, seed=3)
    torques = ur10.static_torques(ur10.link_frames(q), TOOL, np.zeros((5, 3)))
    step = 1e-6
    for joint in range(6):
        dq = np.zeros(6)
        dq[joint] = step
        gradient = (_potential_energy(q + dq) - _potential_energy(q - dq)) / (2 * step)
        np.testing.assert_allclose(torques[:, joint], gradient, atol=1e-5)
    np.testing.assert_allclose(torques[:, 0], 0.0, atol=1e-9)  # vertical base axis


@pytest.mark.parametrize("direction", [(0.0, 0.0, 10.0), (3.0, -2.0, 0.5)])
def test_tool_force_adds_minus_jacobian_transpose_times_force(
    direction: tuple[float, float, float],
) -> None:
    q = _random_configurations(4, seed=4)
    force = np.tile(direction, (4, 1))
    frames = ur10.link_frames(q)
    difference = ur10.static_torques(frames, TOOL, force) - ur10.static_torques(
        frames, TOOL, np.zeros((4, 3))
    )
    jac = ur10.jacobian(q, TOOL)
    expected = -np.einsum("nij,ni->nj", jac[:, :3], force)
    np.testing.assert_allclose(difference, expected, atol=1e-9)


def test_quaternions_are_unit_and_match_the_rotation() -> None:
    poses = ur10.forward(_random_configurations(10, seed=5))
    quat = ur10.quaternions(poses)
    np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(Rotation.from_quat(quat).as_matrix(), poses[:, :3, :3], atol=1e-12)
