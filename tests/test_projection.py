import numpy as np
import pytest

from ocpipe.sim import projection as P


def test_intrinsics_at_90_degrees_match_the_spec():
    K = P.intrinsic_from_fov(128, 90.0)
    np.testing.assert_allclose(K, [[64, 0, 64], [0, 64, 64], [0, 0, 1]], atol=1e-9)


def test_look_at_is_a_rigid_transform_with_the_eye_at_the_origin():
    E = P.extrinsic_look_at([0.3, 0.0, 0.6], [-0.1, 0.0, 0.1])
    R, t = E[:, :3], E[:, 3]
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(R) == pytest.approx(1.0)
    np.testing.assert_allclose(R @ np.array([0.3, 0.0, 0.6]) + t, 0.0, atol=1e-12)


def test_target_projects_to_the_image_centre_and_offsets_go_the_opencv_way():
    eye, target, W = [0.4, 0.3, 0.5], [0.0, 0.0, 0.2], 128
    K, E = P.intrinsic_from_fov(W, 90.0), P.extrinsic_look_at(eye, target)
    np.testing.assert_allclose(P.project_points(np.array(target), K, E), [64, 64], atol=1e-9)
    # A camera at (0, 0, 1) looking straight down x-forward-ish: world +z is "up" in the image (smaller v).
    E2 = P.extrinsic_look_at([1.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    up = P.project_points(np.array([0.0, 0.0, 0.5]), K, E2)
    assert up[0] == pytest.approx(64) and up[1] == pytest.approx(64 - 64 * 0.5)
    # camera looks along -x, so its right-hand side is world +y
    right = P.project_points(np.array([0.0, 0.5, 0.0]), K, E2)
    assert right[0] == pytest.approx(64 + 32) and right[1] == pytest.approx(64)


def test_known_point_against_hand_computation():
    # camera at origin looking along world +x: right = -y, down = -z
    E = P.extrinsic_look_at([0, 0, 0], [1, 0, 0])
    K = P.intrinsic_from_fov(224, 90.0)
    uv = P.project_points(np.array([2.0, -0.5, 0.25]), K, E)
    np.testing.assert_allclose(uv, [112 + 112 * 0.5 / 2, 112 - 112 * 0.25 / 2])


def test_goal2d_is_normalized_clipped_and_ordered_by_camera():
    W = 64
    K = np.stack([P.intrinsic_from_fov(W, 90.0)] * 2)
    E = np.stack([P.extrinsic_look_at([1, 0, 0], [0, 0, 0]), P.extrinsic_look_at([0, 1, 0], [0, 0, 0])])
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 50.0]])  # centre; far above -> clipped to the top edge
    g = P.goal2d(pts, K, E, W)
    assert g.shape == (2, 4)
    np.testing.assert_allclose(g[0], [0.5, 0.5, 0.5, 0.5])
    assert g[1, 1] == 0.0 and g[1, 3] == 0.0 and 0.0 <= g.min() and g.max() <= 1.0


def test_per_frame_camera_matrices_broadcast():
    W = 64
    K = np.broadcast_to(P.intrinsic_from_fov(W, 90.0), (3, 1, 3, 3))
    E = np.broadcast_to(P.extrinsic_look_at([1, 0, 0], [0, 0, 0]), (3, 1, 3, 4))
    g = P.goal2d(np.zeros((3, 3)), K, E, W)
    np.testing.assert_allclose(g, 0.5)


def test_degenerate_look_at_is_rejected():
    with pytest.raises(ValueError, match="coincide"):
        P.extrinsic_look_at([0, 0, 1], [0, 0, 1])
    with pytest.raises(ValueError, match="up axis"):
        P.extrinsic_look_at([0, 0, 1], [0, 0, 0])
