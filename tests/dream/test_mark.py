"""One mark on the end effector as a start (`dream.coarse.mark`, `dream calibrate --mark`): the
marks file, the tracker on a moving dot, the PnP over time (random pose -> project -> solve ->
compare), and the calibration from five noisy clicks."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from dream.camera import CameraIntrinsics, project
from dream.cli import main
from dream.coarse.mark import (
    MarkSettings,
    mark_pose,
    mark_sigma,
    placed_by_mark,
    read_marks,
    track_mark,
)
from dream.errors import InputError
from dream.io import read_sequence
from dream.metrics import pose_errors
from dream.transforms import R_from_rotvec, look_at, transform_points
from tests.dream.test_edges import image_dataset

CLICK_NOISE_PX = 2.0
MARK_LINK, MARK_OFFSET = "panda_hand", np.array([0.0, 0.0, 0.1])   # between the fingers


def dot_images(path: np.ndarray, size: tuple[int, int] = (120, 160), seed: int = 0
               ) -> list[np.ndarray]:
    """Grey images of a textured background with a black-and-white dot at each (u, v)."""
    rng = np.random.default_rng(seed)
    background = cv2.GaussianBlur(rng.uniform(0, 255, size).astype(np.uint8), (0, 0), 3)
    out = []
    for u, v in path:
        image = background.copy()
        cv2.circle(image, (round(u * 16), round(v * 16)), 6 * 16, 0, -1, cv2.LINE_AA, 4)
        cv2.circle(image, (round(u * 16), round(v * 16)), 3 * 16, 255, -1, cv2.LINE_AA, 4)
        out.append(image)
    return out


def test_tracker_follows_a_moving_dot_between_clicks_and_stops_where_it_is_lost():
    t = np.arange(30)
    path = np.stack([40 + 2.5 * t, 60 + 10 * np.sin(t / 5)], axis=1)
    images = dot_images(path)
    images[25] = np.zeros_like(images[25])          # a lost frame (dropped, blank)
    P_base = np.zeros((30, 3))                      # a dense recording: the mark barely moves
    frames, uv = track_mark(lambda i: images[i], np.array([0, 12]), path[[0, 12]], P_base)
    assert 0 in frames and 12 in frames and 24 in frames
    assert 25 not in frames and 29 not in frames   # the track stops at the lost frame
    error = np.linalg.norm(uv - path[frames], axis=1)
    assert error.max() < 0.5, error
    # a mark that jumps between frames (a sparse recording): only the clicks remain
    jumps = np.arange(30)[:, None] * np.array([[0.1, 0.0, 0.0]])
    frames, _ = track_mark(lambda i: images[i], np.array([0, 12]), path[[0, 12]], jumps)
    assert frames.tolist() == [0, 12]


def random_view(rng: np.random.Generator, points: int) -> tuple[np.ndarray, np.ndarray]:
    """A random camera looking at a robot's workspace, and `points` random points in it."""
    T = look_at(rng.uniform([1.0, -1.0, 0.5], [1.8, 1.0, 1.5]), rng.uniform(-0.1, 0.1, 3)
                + [0.0, 0.0, 0.4], rng.uniform(-0.3, 0.3))
    return T, rng.uniform([-0.3, -0.5, 0.1], [0.6, 0.5, 0.8], (points, 3))


def test_mark_pose_recovers_random_cameras_from_five_noisy_clicks():
    camera = CameraIntrinsics(400.0, 400.0, 319.5, 239.5, 640, 480)
    rng = np.random.default_rng(0)
    for _ in range(5):
        T, P = random_view(rng, 5)
        uv = project(camera, transform_points(T, P)) + rng.normal(0, CLICK_NOISE_PX, (5, 2))
        fit = mark_pose(P, uv, camera)
        m, rad = pose_errors(fit.T_cam_base, T)
        sigma_m, sigma_rad = mark_sigma(fit, MarkSettings(), 0.3, np.deg2rad(20.0))
        # the search around the mark's pose covers its error
        assert m < 2 * sigma_m and rad < 2 * sigma_rad, (m, sigma_m, rad, sigma_rad)


def test_mark_pose_needs_four_frames_off_one_line():
    camera = CameraIntrinsics(400.0, 400.0, 319.5, 239.5, 640, 480)
    T = look_at(np.array([1.5, 0.0, 1.0]), np.zeros(3))
    with pytest.raises(InputError, match="at least 4"):
        mark_pose(np.eye(3), project(camera, transform_points(T, np.eye(3))), camera)
    line = np.linspace(0, 1, 6)[:, None] * np.array([[0.2, 0.1, 0.3]])
    with pytest.raises(InputError, match="on one line|fixes no camera pose"):
        mark_pose(line, project(camera, transform_points(T, line)), camera)


def test_two_clicks_place_random_camera_orientations():
    """Random pose -> project two points -> place the true orientation -> the true pose; an
    orientation a few degrees off is placed where its clicks land nearer than at the true
    position; cameras that would see a click behind them are dropped; one-pixel clicks fail."""
    camera = CameraIntrinsics(400.0, 400.0, 319.5, 239.5, 640, 480)
    rng = np.random.default_rng(3)
    for _ in range(5):
        T, P = random_view(rng, 2)
        uv = project(camera, transform_points(T, P))
        placed = placed_by_mark(T[None, :3, :3], P, uv, camera)
        assert np.allclose(placed[0], T, atol=1e-9)
        turned = T.copy()
        turned[:3, :3] = R_from_rotvec(rng.normal(0.0, np.deg2rad(3.0), 3)) @ T[:3, :3]
        placed = placed_by_mark(turned[None, :3, :3], P, uv, camera)[0]
        assert np.allclose(placed[:3, :3], turned[:3, :3])
        off = np.linalg.norm(project(camera, transform_points(placed, P)) - uv, axis=1)
        unplaced = np.linalg.norm(project(camera, transform_points(turned, P)) - uv, axis=1)
        assert off.max() < unplaced.max(), (off, unplaced)
    backwards = look_at(np.array([1.5, 0.0, 1.0]), np.array([3.0, 0.0, 1.0]))[:3, :3]
    assert placed_by_mark(np.stack([T[:3, :3], backwards]), P, uv, camera).shape == (1, 4, 4)
    with pytest.raises(InputError, match="one pixel"):
        placed_by_mark(T[None, :3, :3], P, np.repeat(uv[:1], 2, axis=0), camera)
    with pytest.raises(InputError, match="known in 1 frame"):
        placed_by_mark(T[None, :3, :3], P[:1], uv[:1], camera)


def marks_file(folder, rows: list[str]):
    path = folder / "marks.csv"
    path.write_text("\n".join(rows) + "\n")
    return path


def clicks(panda, seq, T_true: np.ndarray, offset: np.ndarray, folder, noise_px: float,
           count: int = 5):
    """A marks file of the point at `offset` in `MARK_LINK`'s frame, clicked with `noise_px`
    in the first `count` frames that show it."""
    joints = np.stack([f.joints for f in seq.frames])
    T_link = panda.link_poses(joints, (MARK_LINK,))[:, 0]
    uv = project(seq.camera, transform_points(T_true, T_link[:, :3, :3] @ offset
                                              + T_link[:, :3, 3]))
    uv = uv + np.random.default_rng(1).normal(0, noise_px, uv.shape)
    chosen = np.flatnonzero(seq.camera.in_image(uv))[:count]
    assert len(chosen) == count
    return marks_file(folder, ["frame,u,v"] + [f"{seq.frames[i].name},{uv[i, 0]:.2f},"
                                               f"{uv[i, 1]:.2f}" for i in chosen])


def test_marks_file_errors_name_the_line_and_the_fix(panda, meshes, tmp_path):
    image_dataset(panda, meshes, tmp_path)
    seq = read_sequence(tmp_path / "data")
    frames, uv = read_marks(marks_file(tmp_path, ["frame,u,v", "000003,10,20", "1,5.5,6"]),
                            seq)
    assert frames.tolist() == [1, 3] and uv.tolist() == [[5.5, 6.0], [10.0, 20.0]]
    for rows, message in ((["f,u,v", "1,2,3"], "header"),
                          (["frame,u,v", "999999,2,3"], "not in"),
                          (["frame,u,v", "1,2"], "fields"),
                          (["frame,u,v", "1,a,3"], "numbers"),
                          (["frame,u,v", "1,2000,3"], "outside"),
                          (["frame,u,v", "1,2,3", "000001,4,5"], "twice"),
                          (["frame,u,v"], "no rows"),
                          (["frame,u,v", "1,0.31,0.52", "3,0.62,0.40"], "normalised")):
        with pytest.raises(InputError, match=message):
            read_marks(marks_file(tmp_path, rows), seq)


def calibrated_from_clicks(panda, meshes, tmp_path, capsys, count: int, offset: np.ndarray,
                           mark_offset: str, *extra: str) -> tuple[np.ndarray, dict, str]:
    """`dream calibrate --mark` of `image_dataset`'s scene, the point at `offset` in
    `MARK_LINK`'s frame clicked in `count` frames (`CLICK_NOISE_PX` where `offset` is the
    mark's, exact otherwise) and given as `mark_offset`: the truth, RESULT.json, the console."""
    T_true = image_dataset(panda, meshes, tmp_path)
    seq = read_sequence(tmp_path / "data")
    noise = CLICK_NOISE_PX if np.array_equal(offset, MARK_OFFSET) else 0.0
    marks = clicks(panda, seq, T_true, offset, tmp_path, noise, count=count)
    out = tmp_path / "r.json"
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--out", str(out), "--mark",
                 str(marks), "--mark-link", MARK_LINK, "--mark-offset", mark_offset, *extra])
    printed, err = capsys.readouterr()
    assert code == 0, err
    return T_true, json.loads(out.read_text()), printed


def test_calibrate_from_a_mark_clicked_in_five_frames(panda, meshes, tmp_path, capsys):
    """Images only, a mark between the fingers clicked (2 px noise) in 5 of 10 frames of random
    poses (too far apart to track): the search around the mark's pose lands on the camera, and
    the clicks agree with it."""
    T_true, doc, printed = calibrated_from_clicks(panda, meshes, tmp_path, capsys, 5,
                                                  MARK_OFFSET, "0,0,0.1")
    assert "mark: 5 clicked and 0 tracked frames" in printed
    t_err, r_err = pose_errors(np.asarray(doc["T_cam_base"]), T_true)
    assert t_err < 0.01 and r_err < np.deg2rad(0.5), (t_err, np.rad2deg(r_err))
    mark = doc["start"]["mark"]
    assert mark["clicked_frames"] == 5 and np.median(mark["click_residuals_px"]) < 5
    assert "around the pose of the mark on panda_hand" in doc["start"]["hypotheses"]
    assert doc["quality"]["verdict"] in ("good", "check")


def test_calibrate_from_a_mark_clicked_in_two_frames(panda, meshes, tmp_path, capsys):
    """Too few clicks for the mark's own pose (2 of 10 frames, 2 px noise): they place the
    automatic search's orientations, which compete with its shell (each as placed and aimed),
    and the clicks agree with the pose found."""
    T_true, doc, printed = calibrated_from_clicks(panda, meshes, tmp_path, capsys, 2,
                                                  MARK_OFFSET, "0,0,0.1", "--refine", "none")
    assert "too few for a pose of their own" in printed
    t_err, r_err = pose_errors(np.asarray(doc["T_cam_base"]), T_true)
    assert t_err < 0.01 and r_err < np.deg2rad(0.5), (t_err, np.rad2deg(r_err))
    mark = doc["start"]["mark"]
    assert mark["T_cam_base"] is None and mark["placed_hypotheses"] > 0
    assert np.median(mark["click_residuals_px"]) < 5
    # as given, aimed at the robot and at the part in view (the masks reach the image border)
    assert doc["start"]["hypotheses_scored"]["mark"] == 3 * mark["placed_hypotheses"]


def test_a_wrong_mark_offset_is_a_finding(panda, meshes, tmp_path, capsys):
    """Clicks of one point, --mark-offset of another 15 cm away: the verdict says so."""
    _, doc, _ = calibrated_from_clicks(panda, meshes, tmp_path, capsys, 5, np.zeros(3),
                                       "0,0,0.15", "--refine", "none")
    warnings = " ".join(doc["quality"]["warnings"])
    assert doc["quality"]["verdict"] != "good" and "from where it was clicked" in warnings


def test_a_mark_offset_in_millimetres_is_refused(panda, meshes, tmp_path, capsys):
    T_true = image_dataset(panda, meshes, tmp_path)
    seq = read_sequence(tmp_path / "data")
    marks = clicks(panda, seq, T_true, MARK_OFFSET, tmp_path, CLICK_NOISE_PX)
    out = tmp_path / "r.json"
    code = main(["calibrate", "--data", str(tmp_path / "data"), "--out", str(out), "--mark",
                 str(marks), "--mark-link", MARK_LINK, "--mark-offset", "0,0,100"])
    _, err = capsys.readouterr()
    assert code == 2 and "are these millimetres?" in err and not out.exists(), err


def test_mark_options_are_checked_before_any_work(tmp_path, capsys):
    cases = [
        (["--mark", "m.csv"], "--mark-link"),
        (["--mark-link", "panda_hand"], "no --mark was given"),
        (["--mark", "m.csv", "--mark-link", "panda_hand", "--camera-guess", "1,0,1",
          "--look-at", "0,0,0"], "both say where to search"),
        (["--mark", "m.csv", "--mark-link", "panda_hand", "--mark-offset", "0,0"],
         "--mark-offset"),
        (["--use-labels", "--frames", "each", "--mark", "m.csv", "--mark-link", "panda_hand"],
         "--frames all"),
    ]
    for extra, message in cases:
        code = main(["calibrate", "--data", str(tmp_path / "missing"), "--out",
                     str(tmp_path / "r.json"), *extra])
        _, err = capsys.readouterr()
        assert code == 2 and message in err, (extra, err)


def test_a_file_the_frames_share_is_read_once_before_the_page_serves(tmp_path):
    """An image stack (or bag) holding every frame is hashed up front: the marks file's
    comment then needs no read of it (here: it is gone)."""
    from dream.coarse.mark import read_mark_rows
    from dream.io.marks import marks_comment, read_shared_files, shared_files
    from dream.sequence import Frame, Sequence

    stack, alone = tmp_path / "frames.npz", tmp_path / "alone.png"
    stack.write_bytes(b"stack bytes")
    alone.write_bytes(b"png bytes")
    frames = tuple(Frame(name=f"{i:06d}", joints=np.zeros(7), image_path=stack, image_index=i)
                   for i in range(3)) + (Frame(name="000003", joints=np.zeros(7),
                                               image_path=alone),)
    seq = Sequence(robot="panda", camera=CameraIntrinsics(100, 100, 31.5, 23.5, 64, 48),
                   joint_names=tuple(f"j{i}" for i in range(7)), keypoint_names=(),
                   frames=frames)
    expected = marks_comment("/d", seq, [0, 2])
    cache: dict = {}
    read_shared_files(shared_files(seq), cache)
    assert shared_files(seq) == [stack] and list(cache) == [stack]
    stack.unlink()
    assert marks_comment("/d", seq, [0, 2], cache) == expected
    marks = tmp_path / "marks.csv"
    marks.write_text(f"{expected}\nframe,u,v\n000000,10,10\n000002,20,20\n")
    frames, _ = read_mark_rows(marks, seq, cache)    # a resumed page: the stack is not read
    assert list(frames) == [0, 2]
