"""Up axes and camera poses: ``warprt.look_at`` (one helper for every renderer, the up axis always
explicit), the roll warning for a pose made for another up axis, the Newton bridge honouring
``model.up_axis`` (a y-up and a z-up model of the same physical setup give the same images), and
the depth sensor's outputs in a batch through the bridge. Skipped where Newton is not installed
(the look_at tests need no Newton and run everywhere).

Tolerances: the y-up model's poses are the z-up model's turned by -90° about x, applied in float32
on each side: depth and colour agree to float32 rounding (measured worst 2e-6 relative on hits;
bound 1e-4), and a pixel on a silhouette may see another surface (a few allowed).
"""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import warp as wp

import warprt
from warprt.errors import RenderError
from warprt.poses import CameraRollWarning, camera_roll


def rotation(q):
    x, y, z, w = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


@pytest.mark.parametrize("up", ["y", "z", "-x", (0.0, 0.3, 1.0), 1])
def test_look_at_frame_is_the_camera_frame(up):
    eye, target = np.array([2.0, -1.0, 1.5]), np.array([0.1, 0.4, 0.2])
    pose = warprt.look_at(eye, target, up)
    np.testing.assert_array_equal(pose[:3], eye)
    R = rotation(pose[3:])
    U = {"y": (0, 1, 0), "z": (0, 0, 1), "-x": (-1, 0, 0), 1: (0, 1, 0)}.get(up, up)
    U = np.asarray(U, np.float64) / np.linalg.norm(U)
    # warprt.Camera's frame: w = normalize(eye - target), u = normalize(up x w), v = w x u
    cam = warprt.Camera(eye=tuple(eye), look_at=tuple(target), up=tuple(U))
    for k, axis in enumerate(cam.basis()):  # (the quaternion is float32's, as a device pose)
        np.testing.assert_allclose(R[:, k], axis, atol=3e-7)
    assert abs(np.linalg.det(R) - 1) < 1e-12
    assert camera_roll(pose, up) == pytest.approx(0.0, abs=3e-5)  # degrees: float32 rounding


def test_look_at_broadcasts_and_names_bad_input():
    eyes = np.array([[[3.0, 1.0, 0.0], [0.0, 2.0, 3.0]]] * 4)  # (W=4, C=2, 3)
    poses = warprt.look_at(eyes, (0.0, 0.0, 0.0), "y")
    assert poses.shape == (4, 2, 7)
    np.testing.assert_allclose(poses[1, 1], warprt.look_at(eyes[1, 1], (0, 0, 0), "y"))
    with pytest.raises(RenderError, match="parallel to up"):
        warprt.look_at((0.0, 5.0, 0.0), (0.0, 0.0, 0.0), "y")
    with pytest.raises(RenderError, match="same point"):
        warprt.look_at((1.0, 1.0, 1.0), (1.0, 1.0, 1.0), "z")
    with pytest.raises(RenderError, match="up: expected an axis"):
        warprt.look_at((1.0, 1.0, 1.0), (0.0, 0.0, 0.0), "w")
    with pytest.raises(TypeError):
        warprt.look_at((1.0, 1.0, 1.0), (0.0, 0.0, 0.0))  # the up axis is never implied


def test_roll_measures_a_pose_made_for_another_up_axis():
    level = warprt.look_at((3.0, 0.0, 0.0), (0.0, 0.0, 0.0), "y")
    wrong = warprt.look_at((3.0, 0.0, 0.0), (0.0, 0.0, 0.0), "z")  # horizontal view: rolled 90°
    assert camera_roll(level, "y") == pytest.approx(0.0, abs=3e-5)
    assert camera_roll(wrong, "y") == pytest.approx(90.0)
    flipped = warprt.look_at((3.0, 0.0, 0.0), (0.0, 0.0, 0.0), "-y")
    assert camera_roll(flipped, "y") == pytest.approx(180.0)
    down = warprt.look_at((0.0, 3.0, 0.0), (0.0, 0.0, 0.01), "z")  # straight down: roll not measured
    assert camera_roll(down, "y") == 0.0


# --- the Newton bridge ------------------------------------------------------------------------

H, X = 40, 48
FOV = 45.0
REGULAR = dict(sampler="regular", spp=1)  # the kernel of tests/test_newton_bridge.py


def turned_model(up: str, worlds: int = 2):
    """The ground, a tilted box and an offset sphere per world (tests/test_newton_bridge.py's
    model), built for a z-up or a y-up world: the y-up one is the z-up one turned by -90° about x
    (Newton's own turn from z up to y up), every position and rotation with it."""
    newton = pytest.importorskip("newton")
    turn = wp.quat_from_axis_angle(wp.vec3(1.0, 0.0, 0.0), -math.pi / 2) if up == "Y" else wp.quat_identity()

    def place(p, q=wp.quat_identity()):
        return wp.transform(wp.quat_rotate(turn, wp.vec3(*p)), turn * q)

    b = newton.ModelBuilder(up_axis=up)
    b.add_ground_plane(color=(0.8, 0.8, 0.75))
    sub = newton.ModelBuilder(up_axis=up)
    body = sub.add_body(xform=place((0.0, 0.0, 0.25), wp.quat_from_axis_angle(wp.vec3(0, 0, 1), 0.4)))
    sub.add_shape_box(body, hx=0.3, hy=0.2, hz=0.25, color=(0.9, 0.2, 0.2))
    body = sub.add_body(xform=place((0.9, 0.5, 0.35)))
    sub.add_shape_sphere(body, radius=0.35, color=(0.2, 0.4, 0.9), xform=wp.transform((0.0, 0.0, 0.1), wp.quat_identity()))
    b.replicate(sub, worlds)
    return b.finalize(device="cpu"), turn


def test_a_y_up_and_a_z_up_model_of_one_setup_give_the_same_images():
    from warprt.newton_bridge import NewtonRenderer

    images = {}
    for up in ("Z", "Y"):
        m, turn = turned_model(up)
        r = NewtonRenderer(m, cameras=2, camera=warprt.Camera(fov=FOV, width=X, height=H),
                           render=warprt.RenderSettings(**REGULAR))
        R = rotation(np.array(turn, np.float64))
        np.testing.assert_allclose(r.up_axis, R @ (0, 0, 1), atol=1e-7)
        light = r.scene.lights[0].direction  # Newton's default light, turned: it always points down
        np.testing.assert_allclose(light, R @ (np.array([-1.0, 1.0, -1.0]) / math.sqrt(3)), atol=1e-12)
        assert np.dot(light, r.up_axis) < 0
        eyes = np.array([[3.0, -3.0, 2.2], [-2.0, -3.0, 1.5]]) @ R.T
        target = R @ (0.3, 0.2, 0.3)
        with warnings.catch_warnings():
            warnings.simplefilter("error", CameraRollWarning)  # level cameras: no warning
            r.set_camera_poses(warprt.look_at(np.broadcast_to(eyes, (2, 2, 3)), target, r.up_axis))
        r.update(m.state())
        out = r.render(aovs=["depth", "object_id"])
        images[up] = (out.numpy(), out.aovs_numpy())
    (cz, az), (cy, ay) = images["Z"], images["Y"]
    same = az["object_id"] == ay["object_id"]
    assert np.mean(~same) < 3e-3
    hit = same & np.isfinite(az["depth"])
    assert hit.mean() > 0.5
    np.testing.assert_allclose(ay["depth"][hit], az["depth"][hit], rtol=1e-4)
    lit = same & (cz.sum(-1) > 1e-3)
    np.testing.assert_allclose(cy[lit], cz[lit], rtol=1e-3, atol=1e-5)
    assert np.mean(np.abs(cy[lit] - cz[lit]) <= 1e-4 * cz[lit] + 1e-6) > 0.99


def test_poses_for_another_up_axis_are_warned_about():
    from warprt.newton_bridge import NewtonRenderer, look_at_pose

    m, _ = turned_model("Y", worlds=1)
    r = NewtonRenderer(m, cameras=1, camera=warprt.Camera(fov=FOV, width=8, height=8))
    np.testing.assert_array_equal(r.up_axis, (0.0, 1.0, 0.0))
    assert r.scene.camera.up == (0.0, 1.0, 0.0)  # the default camera is levelled for the model
    with pytest.warns(CameraRollWarning, match=r"camera_poses\[0, 0\].*rolled 90° .*up axis \+y.*up='\+y'"):
        r.set_camera_poses(look_at_pose((3.0, 0.5, 0.0), (0.0, 0.5, 0.0))[None, None])  # z up, in a y-up world
    with warnings.catch_warnings():
        warnings.simplefilter("error", CameraRollWarning)
        r.set_camera_poses(warprt.look_at((3.0, 0.5, 0.0), (0.0, 0.5, 0.0), r.up_axis)[None, None])


def test_the_depth_sensor_in_a_batch_through_the_bridge():
    from warprt.newton_bridge import NewtonRenderer

    m, _ = turned_model("Z")
    sensor = warprt.DepthSensor(baseline=0.05, focal_length=300.0, disparity_sigma=0.3, max_range=5.5,
                                dropout_start=60.0, dropout_end=85.0, invalid="zero")
    r = NewtonRenderer(m, cameras=2, camera=warprt.Camera(fov=FOV, width=X, height=H),
                       render=warprt.RenderSettings(**REGULAR), depth_sensor=sensor)
    r.set_camera_poses(warprt.look_at(np.broadcast_to([[3.0, -3.0, 2.2], [-2.0, -3.0, 1.5]], (2, 2, 3)),
                                      (0.3, 0.2, 0.3), r.up_axis))
    r.update(m.state())
    out = r.render(seed=9, aovs=["z", "sensor_z", "sensor_depth"])
    assert list(out.aovs) == ["z", "sensor_z", "sensor_depth"]
    a = out.aovs_numpy()
    z, sz = a["z"], a["sensor_z"]
    assert sz.shape == z.shape == (2, 2, H, X)
    valid = sz != 0.0
    assert (sz[valid] <= 5.5).all() and (np.isfinite(z[valid])).all()
    assert valid.mean() > 0.3 and (~valid & np.isfinite(z) & (z < 4.0)).any()  # grazing pixels dropped
    err = 300.0 * 0.05 / sz[valid] - 300.0 * 0.05 / z[valid]
    assert abs(err.std() / 0.3 - 1) < 0.1 and abs(err.mean()) < 0.03  # thousands of pixels
    # the same seed gives the same noise; world 1 has noise of its own (its pixels' own keys)
    again = r.render(seed=9, aovs=["sensor_z"]).aovs_numpy()["sensor_z"]
    np.testing.assert_array_equal(again, sz)
    np.testing.assert_array_equal(z[0], z[1])  # the same state in both worlds
    assert np.mean(sz[0][valid[0] & valid[1]] != sz[1][valid[0] & valid[1]]) > 0.9
    frame = out.frame(1, 0)
    assert set(frame.aovs) == {"z", "sensor_z", "sensor_depth"} and frame.aovs["sensor_z"].dtype == np.float32
