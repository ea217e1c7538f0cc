import numpy as np
import pytest
from tolerances import gamma, reduction_atol

from ocpipe.sim import projection as P

# f = (W / 2) / tan(deg2rad(90) / 2) in float64 is within gamma(6) of W / 2 (relative): pi and pi/180 round, the
# product rounds, tan is off by an ulp and its slope x tan'(x) / tan(x) = pi/2 at pi/4 scales the argument's error,
# the division rounds: about 8 half-ulps, under gamma(6) = 12 half-ulps
F_RTOL = gamma(6)


def test_intrinsics_at_90_degrees_match_the_spec():
    K = P.intrinsic_from_fov(128, 90.0)
    # derived: f within F_RTOL of 64; c = W / 2 and the zeros and one are exact
    np.testing.assert_allclose(K, [[64, 0, 64], [0, 64, 64], [0, 0, 1]], rtol=F_RTOL, atol=0)


def test_look_at_is_a_rigid_transform_with_the_eye_at_the_origin():
    E = P.extrinsic_look_at([0.3, 0.0, 0.6], [-0.1, 0.0, 0.1])
    R, t = E[:, :3], E[:, 3]
    # derived: three chained 3-term sums of unit-size terms: the normalizing norms, the cross products, this product
    np.testing.assert_allclose(R @ R.T, np.eye(3), rtol=0, atol=reduction_atol(3, 1.0, depth=3))
    # derived: R's orthonormality as above (depth 3) and the LU's elimination, one more 3-term reduction
    assert np.linalg.det(R) == pytest.approx(1.0, rel=0, abs=reduction_atol(3, 1.0, depth=4))
    # derived: t is -rot @ eye, the same 3-term dot products of terms <= |eye| = 0.6, maybe summed in another order
    # (R is a strided view, so numpy may take another loop)
    np.testing.assert_allclose(R @ np.array([0.3, 0.0, 0.6]) + t, 0.0, rtol=0, atol=reduction_atol(3, 0.6))


def test_target_projects_to_the_image_centre_and_offsets_go_the_opencv_way():
    eye, target, W = [0.4, 0.3, 0.5], [0.0, 0.0, 0.2], 128
    K, E = P.intrinsic_from_fov(W, 90.0), P.extrinsic_look_at(eye, target)
    f_over_z = 64 / np.linalg.norm(np.subtract(target, eye))
    atol = f_over_z * reduction_atol(3, 0.5, depth=3) + gamma(4) * W
    # derived: the target's camera x, y are 0 up to the round-off of rot @ target + t (two 3-term dot products of
    # terms <= 0.5, after the normalize/cross chain: depth 3), which the pixel scales by f / z; then the last
    # ops on a pixel of size <= W
    np.testing.assert_allclose(P.project_points(np.array(target), K, E), [64, 64], rtol=0, atol=atol)
    # A camera at (0, 0, 1) looking straight down x-forward-ish: world +z is "up" in the image (smaller v).
    E2 = P.extrinsic_look_at([1.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    # this camera's axes are exact unit vectors (entries 0 and +-1, t = (0, 0, 1)): a pixel is c where f meets a 0
    up = P.project_points(np.array([0.0, 0.0, 0.5]), K, E2)
    assert up[0] == 64  # exact: f * 0 + 64 * 1, over z = 1
    # derived: 64 - f * 0.5 with f within F_RTOL of 64, one rounding more
    assert up[1] == pytest.approx(64 - 64 * 0.5, rel=F_RTOL + gamma(1), abs=0)
    # camera looks along -x, so its right-hand side is world +y
    right = P.project_points(np.array([0.0, 0.5, 0.0]), K, E2)
    assert right[0] == pytest.approx(64 + 32, rel=F_RTOL + gamma(1), abs=0)  # derived: f * 0.5 + 64, as above
    assert right[1] == 64  # exact: f * 0 + 64 * 1, over z = 1


def test_known_point_against_hand_computation():
    # camera at origin looking along world +x: right = -y, down = -z
    E = P.extrinsic_look_at([0, 0, 0], [1, 0, 0])
    K = P.intrinsic_from_fov(224, 90.0)
    uv = P.project_points(np.array([2.0, -0.5, 0.25]), K, E)
    # derived: the camera's axes are exact here (entries 0 and +-1), so only f (within F_RTOL of 112) and one
    # rounding of the sum f * x + c * z carry error; the division by z = 2 is exact
    np.testing.assert_allclose(uv, [112 + 112 * 0.5 / 2, 112 - 112 * 0.25 / 2], rtol=F_RTOL + gamma(1), atol=0)


def test_goal2d_is_normalized_clipped_and_ordered_by_camera():
    W = 64
    K = np.stack([P.intrinsic_from_fov(W, 90.0)] * 2)
    E = np.stack([P.extrinsic_look_at([1, 0, 0], [0, 0, 0]), P.extrinsic_look_at([0, 1, 0], [0, 0, 0])])
    pts = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 50.0]])  # centre; far above -> clipped to the top edge
    g = P.goal2d(pts, K, E, W)
    assert g.shape == (2, 4)
    # exact: both cameras' axes are exact unit vectors and the point is the origin: u = v = c * z / z = 32, / 64
    np.testing.assert_array_equal(g[0], [0.5, 0.5, 0.5, 0.5])
    assert g[1, 1] == 0.0 and g[1, 3] == 0.0 and 0.0 <= g.min() and g.max() <= 1.0


def test_per_frame_camera_matrices_broadcast():
    W = 64
    K = np.broadcast_to(P.intrinsic_from_fov(W, 90.0), (3, 1, 3, 3))
    E = np.broadcast_to(P.extrinsic_look_at([1, 0, 0], [0, 0, 0]), (3, 1, 3, 4))
    g = P.goal2d(np.zeros((3, 3)), K, E, W)
    np.testing.assert_array_equal(g, 0.5)  # exact: the origin seen by an axis-aligned camera, as in the test above


def test_degenerate_look_at_is_rejected():
    with pytest.raises(ValueError, match="coincide"):
        P.extrinsic_look_at([0, 0, 1], [0, 0, 1])
    with pytest.raises(ValueError, match="up axis"):
        P.extrinsic_look_at([0, 0, 1], [0, 0, 0])
