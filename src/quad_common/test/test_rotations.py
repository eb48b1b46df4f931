import numpy as np
import pytest

from quad_common import rotations as rot


def test_matrix_round_trip_and_orthonormal():
    rng = np.random.default_rng(0)
    for q in rng.normal(size=(50, 4)):
        q = rot.normalize(q)
        R = rot.to_matrix(q)
        assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.isclose(np.linalg.det(R), 1.0)
        q2 = rot.from_matrix(R)
        assert np.allclose(q2, q if q[3] >= 0 else -q, atol=1e-12)


def test_yaw_quarter_turn_maps_x_to_y():
    assert np.allclose(rot.to_matrix(rot.from_yaw(np.pi / 2)) @ [1, 0, 0], [0, 1, 0])


def test_euler_round_trip_and_product_matches_matrices():
    q1, q2 = rot.from_euler(0.1, -0.2, 0.3), rot.from_euler(-0.4, 0.5, 2.0)
    assert np.allclose(rot.to_euler(q1), [0.1, -0.2, 0.3])
    assert np.allclose(rot.to_matrix(rot.multiply(q1, q2)), rot.to_matrix(q1) @ rot.to_matrix(q2))
    assert np.allclose(rot.multiply(q1, rot.conjugate(q1)), [0, 0, 0, 1])


def test_hat_vee_and_wrap():
    a, b = np.array([1.0, 2.0, 3.0]), np.array([-1.0, 0.5, 2.0])
    assert np.allclose(rot.hat(a) @ b, np.cross(a, b))
    assert np.allclose(rot.vee(rot.hat(a)), a)
    assert np.isclose(rot.wrap_angle(3 * np.pi / 2), -np.pi / 2)


@pytest.mark.parametrize('bad', [[0, 0, 0, 0], [np.nan, 0, 0, 1]])
def test_normalize_refuses_bad_quaternion(bad):
    with pytest.raises(ValueError, match='quaternion'):
        rot.normalize(bad)


def test_rotate_and_rotate_back_are_the_matrix_and_its_transpose():
    rng = np.random.default_rng(5)
    for _ in range(200):
        q, v = rot.normalize(rng.normal(size=4)), rng.normal(scale=10.0, size=3)
        R = rot.to_matrix(q)
        np.testing.assert_allclose(rot.rotate(q.tolist(), v.tolist()), R @ v, rtol=1e-14, atol=1e-13)
        np.testing.assert_allclose(rot.rotate_back(q.tolist(), v.tolist()), R.T @ v, rtol=1e-14, atol=1e-13)
        np.testing.assert_allclose(rot.rotate(q, rot.rotate_back(q, v)), v, rtol=1e-13, atol=1e-12)
