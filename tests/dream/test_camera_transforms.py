import numpy as np
import pytest

from dream.camera import (
    CameraIntrinsics,
    distort_normalized,
    pixels_to_normalized,
    project,
    project_with_jacobian,
)
from dream.errors import InputError
from dream.transforms import (
    R_from_quaternion_xyzw,
    T_from_rotvec_t,
    camera_coordinates,
    check_pose,
    compose,
    invert_T,
    is_rigid,
    look_at,
    quaternion_xyzw_from_R,
    rotvec_t_from_T,
    transform_points,
)

CAM = CameraIntrinsics(500.0, 510.0, 319.5, 239.5, 640, 480)
CAM_DIST = CAM.with_distortion((0.1, -0.05, 0.002, -0.001, 0.01))


def test_pixel_convention_principal_point():
    # A point on the optical axis lands on (cx, cy); the top-left pixel centre is (0, 0).
    assert np.allclose(project(CAM, np.array([0.0, 0.0, 2.0])), [319.5, 239.5])
    uv = project(CAM, np.array([-319.5 / 500.0, -239.5 / 510.0, 1.0]))
    assert np.allclose(uv, [0.0, 0.0])
    assert CAM.in_image(np.array([[0.0, 0.0], [639.4, 479.4]])).all()
    assert not CAM.in_image(np.array([[-0.6, 10.0]])).any()


def test_points_behind_camera_are_nan():
    assert np.all(np.isnan(project(CAM, np.array([0.1, 0.1, -1.0]))))


@pytest.mark.parametrize("camera", [CAM, CAM_DIST])
def test_projection_jacobian_matches_finite_differences(camera, rng):
    P = rng.uniform([-0.5, -0.4, 0.8], [0.5, 0.4, 2.0], (20, 3))
    uv, J = project_with_jacobian(camera, P)
    assert np.allclose(uv, project(camera, P))
    eps = 1e-7
    for k in range(3):
        d = np.zeros(3)
        d[k] = eps
        fd = (project(camera, P + d) - project(camera, P - d)) / (2 * eps)
        assert np.allclose(J[:, :, k], fd, rtol=1e-6, atol=1e-4)


def test_undistort_inverts_distort(rng):
    xy = rng.uniform(-0.5, 0.5, (100, 2))
    xy_d = distort_normalized(xy, CAM_DIST.dist_coeffs)
    uv = np.stack([CAM_DIST.fx * xy_d[:, 0] + CAM_DIST.cx, CAM_DIST.fy * xy_d[:, 1] + CAM_DIST.cy],
                  -1)
    assert np.allclose(pixels_to_normalized(CAM_DIST, uv), xy, atol=1e-10)


def test_matches_opencv_projection(rng):
    import cv2

    P = rng.uniform([-0.5, -0.4, 0.8], [0.5, 0.4, 2.0], (30, 3))
    ref, _ = cv2.projectPoints(P, np.zeros(3), np.zeros(3), CAM_DIST.K, CAM_DIST.dist_coeffs)
    assert np.allclose(project(CAM_DIST, P), ref.reshape(-1, 2), atol=1e-9)


@pytest.mark.parametrize("bad", [
    dict(fx=-1.0), dict(fx=float("nan")), dict(width=0), dict(width=3.5),
    dict(distortion=(0.1, 0.2)), dict(distortion=(0.1, float("inf"), 0, 0, 0)),
])
def test_invalid_intrinsics_raise(bad):
    kwargs = dict(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)
    kwargs.update(bad)
    with pytest.raises(InputError):
        CameraIntrinsics(**kwargs)


def test_pose_round_trips(rng):
    for _ in range(20):
        rotvec, t = rng.normal(size=3), rng.normal(size=3)
        T = T_from_rotvec_t(rotvec, t)
        r2, t2 = rotvec_t_from_T(T)
        assert np.allclose(T_from_rotvec_t(r2, t2), T)
        q = quaternion_xyzw_from_R(T[:3, :3])
        assert q[3] >= 0 and np.isclose(np.linalg.norm(q), 1)
        assert np.allclose(R_from_quaternion_xyzw(q), T[:3, :3])
        assert np.allclose(compose(T, invert_T(T)), np.eye(4))
        P = rng.normal(size=(5, 3))
        assert np.allclose(transform_points(invert_T(T), transform_points(T, P)), P)


def test_camera_coordinates_are_each_cameras_transformed_points(rng):
    T = np.stack([T_from_rotvec_t(rng.normal(size=3), rng.normal(size=3)) for _ in range(4)])
    P = rng.normal(size=(3, 6, 3))
    X, Y, Z = camera_coordinates(P, T)
    assert X.shape == (4, 3, 6)
    for b in range(4):
        np.testing.assert_allclose(np.stack([X[b], Y[b], Z[b]], -1), transform_points(T[b], P),
                                   atol=1e-12)
    with pytest.raises(InputError, match=r"must be \(\.\.\., 3\) and \(B, 4, 4\)"):
        camera_coordinates(P, T[0])


def test_quaternion_convention_is_xyzw():
    # 90 deg about z: [0, 0, sin 45, cos 45]
    R = np.array([[0.0, -1, 0], [1, 0, 0], [0, 0, 1]])
    assert np.allclose(quaternion_xyzw_from_R(R), [0, 0, np.sqrt(0.5), np.sqrt(0.5)])


@pytest.mark.parametrize("scale", [0.0, 1e-9, 1e-5, 1e-4, 1e-3, 0.5, 3.0])
def test_rodrigues_matches_scipy_for_one_and_many_vectors(scale, rng):
    from scipy.spatial.transform import Rotation

    from dream.transforms import R_from_rotvec

    rotvec = scale * rng.normal(size=(20, 3))
    expected = Rotation.from_rotvec(rotvec).as_matrix()
    assert np.allclose(R_from_rotvec(rotvec), expected, atol=1e-15)
    assert np.allclose(R_from_rotvec(rotvec.reshape(4, 5, 3)), expected.reshape(4, 5, 3, 3),
                       atol=1e-15)
    for v, R in zip(rotvec, expected, strict=True):
        assert np.allclose(R_from_rotvec(v), R, atol=1e-15)


def test_look_at_refuses_a_target_at_the_camera_and_non_finite_points():
    T = look_at(np.array([1.0, 0.0, 1.0]), np.zeros(3))
    assert is_rigid(T)
    assert np.allclose(transform_points(T, np.zeros(3))[:2], 0.0)   # the target is on the axis
    for position, target, message in ((np.zeros(3), np.zeros(3), "0.0 m apart"),
                                      (np.zeros(3), np.array([np.nan, 0, 0]), "target_base"),
                                      (np.zeros(2), np.ones(3), "position_base"),
                                      (np.zeros(3), np.array([0, 0, 1.0]), "straight along"),
                                      (np.zeros(3), "abc", "target_base"),
                                      ([0, [1, 2], 3], np.ones(3), "position_base")):
        with pytest.raises(InputError, match=message):
            look_at(position, target)
    for kwargs, message in (({"roll_rad": np.nan}, "roll_rad"), ({"roll_rad": "x"}, "roll_rad"),
                            ({"up_base": np.array([0, np.nan, 1.0])}, "up_base")):
        with pytest.raises(InputError, match=message):
            look_at(np.array([1.0, 0.0, 1.0]), np.zeros(3), **kwargs)
    with pytest.raises(InputError, match="T_init must be a finite 4x4 transform"):
        check_pose([[1, 2], [3]], "T_init")
