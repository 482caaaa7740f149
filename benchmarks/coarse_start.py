"""Calibration without keypoints: `dream calibrate` with neither `--model` nor `--use-labels`,
from a rough guess or by the automatic search, on rendered scenes and on real recordings.

renders: fixed-camera scenes of each `--robots` arm (a built-in name, or a URDF such as
example-robot-data's, rendered with its suggested keypoints) with the
`configs/synth/real_world.yaml` randomisation (clutter, a second robot, a tool or held object,
close-ups; `--set` overrides its keys, `--scale-to-robot` sizes its distances to the arm),
`--frames` frames each, seeds from `--first-seed`; the robot masks are deleted before
calibrating, so only the images are read. Each scene is calibrated from a guess `--guess-m` /
`--guess-deg` off the truth in a random direction (written as a RESULT.json holding only
T_cam_base), with `--auto` by the automatic search, and with `--mark-frames N` from a mark on
the end effector (the last keypoint link's origin) clicked in N frames: its labels plus
`--mark-noise-px`; with `--fooled` the keypoint path (`--use-labels`) from labels projected at
a camera that far off (through the intrinsics rendered with, whatever the calibration is given),
so that its refinements and their verdict are tested from a wrong start;
with `--given-focal F` the calibration is given fx, fy F times those rendered with (the search
fits the focal length where the outlines tell it: `dream.coarse.focal`); with
`--given-principal DU,DV` a principal point DU, DV pixels off (adopted where the outlines
ask for it; `--fixed-principal` keeps it, `--fixed-distortion` the given lens); with
`--given-no-distortion` no distortion coefficients for a lens rendered with them (raw images
given as rectified); with `--joint-offsets-deg S` every revolute joint's readings but the
first's off by a constant drawn from N(0, S) per joint and scene (an arm whose encoders' zeros
or URDF differ from the real one's); with `--video-codec` the frames go through a video codec
and back first (OpenCV's FFmpeg encoder at its default rate: `vp9`, transforms of several sizes
with a loop filter, as a modern video file or stream; `mpeg4`, MPEG-4 part 2 in 8x8 blocks);
`--reuse-scenes` takes scenes already rendered in `--work`.
Printed per scene: error, verdict, 1-sigma, time; then the share within `--right-mm` /
`--right-deg`, the wrong results called `good`, the right ones called `good` or `check`, and
how often the truth lies inside the written 95 % ellipsoid (each scene's chi-square of the
truth under the written covariance is printed).

real: a recording with a reference extrinsic (scored only), calibrated from `--guesses`
guesses off it, with `--auto` once by the automatic search, with `--mark` once from marks
clicked by eye (`dream mark`). A recording without a reference
(`franka_offline`) takes `--center RESULT.json` (a keypoint-started calibration): the guesses lie
around its extrinsic, and each result is compared with it and by its polish's IoU over the
frames that agree.

    python benchmarks/coarse_start.py renders [--robots panda,ur5,xarm7] [--scenes 3]
        [--first-seed 1000] [--frames 30] [--auto] [--mark-frames 5 --mark-noise-px 2]
        [--fooled] [--skip-guess] [--only panda_1003,xarm7_1010] [--work DIR]
        [--robots URDF,... --scale-to-robot] [--set intrinsics.width=960 ...]
        [--given-focal 0.96 [--fixed-focal]] [--given-principal 12,-8 [--fixed-principal]]
        [--set 'intrinsics.distortion=[-0.2,0.05,0,0,0]' --given-no-distortion]
        [--video-codec vp9] [--joint-offsets-deg 0.2]
        [--reuse-scenes]
        [--set sequence.mode=trajectory --frames 150 [--time-offset 0.05]]
    python benchmarks/coarse_start.py real --data ../shared/realdata/panda_teleop [--guesses 10]
    python benchmarks/coarse_start.py real --data ../shared/realdata/franka_offline --center R.json
    python benchmarks/coarse_start.py real --data ../shared/realdata/panda_teleop \
        --mark MARKS.csv --mark-link panda_link8
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from dream.cli.calibrate import CalibrateRequest, run_calibrate
from dream.errors import DreamError, InputError
from dream.io import read_sequence, write_dream
from dream.metrics import pose_errors
from dream.pipeline import truth_poses
from dream.pnp import increment_between
from dream.result import read_result
from dream.transforms import R_from_rotvec, invert_T

LABELS = Path("--use-labels")   # calibrate from the data's labels, not from a guess
CHI2_6DOF_95 = 12.592     # 95 % quantile of the chi-square distribution with 6 degrees of freedom
REAL_WORLD = Path(__file__).resolve().parents[1] / "configs" / "synth" / "real_world.yaml"
SIZE_SAMPLES = 500        # joint vectors drawn for a robot's size
SIZE_REFERENCE = "panda"  # the randomisation's distances and sizes were set for this robot
SCALED_KEYS = (("camera", "radius_m"), ("camera", "target_m"), ("camera", "target_jitter_m"),
               ("camera", "closeup_radius_m"), ("distractors", "size_m"),
               ("distractors", "distance_m"), ("distractors", "held_size_m"),
               ("distractors", "held_offset_m"), ("distractors", "robot_distance_m"),
               ("distractors", "loose_distance_m"), ("distractors", "loose_height_m"))
VIDEO_CODECS = {"vp9": ("VP90", ".mkv"), "mpeg4": ("mp4v", ".mp4")}   # FourCC, container
VIDEO_FPS = 10.0          # the rate written in the file; the encoder's default bit rate is kept
JOINT_OFFSET_STREAM = 7     # the joint offsets' random stream beside the scene's seed


def robot_keypoints(robot: str, given: tuple[str, ...] | None = None
                    ) -> tuple[str, ...] | None:
    """None for a built-in robot; the `given` or else the suggested keypoints of a URDF (the
    renders move the joints up to them and label them; calibrating without keypoints never
    reads the labels). Where the suggestion stops at alike branches (two arms on a torso) it
    is carried on along every one of them, so that the renders move every arm."""
    from dream.robot import builtin_robots, parse_urdf
    from dream.robot.keypoint_choice import analyse_keypoints

    if robot.strip().lower() in {entry.name for entry in builtin_robots()}:
        return None
    if given:
        return given
    advice = analyse_keypoints(parse_urdf(Path(robot)))
    return tuple(dict.fromkeys(link for links in (advice.suggested, *advice.branch_keypoints)
                               for link in links))


def robot_size(robot: str, keypoints: tuple[str, ...] | None = None) -> float:
    """The robot's size (m): the median over random joint vectors of the largest extent of its
    keypoints (Panda 0.68, SO-101 0.28)."""
    from dream.robot import load_robot

    model = load_robot(robot, robot_keypoints(robot, keypoints))
    P = model.forward_kinematics(model.sample_joints(np.random.default_rng(0), (SIZE_SAMPLES,)))
    return float(np.median(np.ptp(P, axis=1).max(axis=-1)))


def randomisation(robot: str, scale_to_robot: bool, overrides: tuple[str, ...] = (),
                  keypoints: tuple[str, ...] | None = None):
    """`real_world.yaml` for fixed-camera scenes with `overrides` (`KEY=VALUE`, as `dream synth
    --set`); with `scale_to_robot` the camera's and the distractors' distances and sizes
    (`SCALED_KEYS`; the lights stay where they are) times the robot's size over the Panda's,
    for which they were set."""
    from synth.config import config_from_dict, load_config

    config = load_config(REAL_WORLD, ("sequence.mode=fixed_camera", *overrides))
    if not scale_to_robot:
        return config
    full = config.to_dict()
    factor = robot_size(robot, keypoints) / robot_size(SIZE_REFERENCE)
    for section, key in SCALED_KEYS:
        full[section][key] = (np.asarray(full[section][key], float) * factor).tolist()
    return config_from_dict(full)


def rendered_for(job) -> bool:
    """Whether `job.out_dir` holds a finished scene of that `synth.generate.SynthJob`: its
    record (`_synth.json`: robot, keypoints, seed, randomisation with every override, the
    joint log's lag) the job's, its `num_frames` frames written and its masks deleted; not one
    whose rendering was stopped or that was rendered with other settings."""
    from synth.generate import SYNTH_INFO, without_retired_keys

    record = job.out_dir / SYNTH_INFO
    if not record.is_file() or any(job.out_dir.glob("*.seg.png")):
        return False
    written = sum(1 for path in job.out_dir.glob("*.json") if path.stem.isdigit())
    asked = json.loads(json.dumps(job.info()))
    return written == job.num_frames and \
        without_retired_keys(json.loads(record.read_text())) == asked


def render_scene(robot: str, out: Path, seed: int, frames: int,
                 scale_to_robot: bool = False, overrides: tuple[str, ...] = (),
                 reuse: bool = False, keypoints: tuple[str, ...] | None = None,
                 time_offset_s: float = 0.0, keep_masks: bool = False) -> Path:
    """A fixed-camera `real_world.yaml` scene of `robot` (a built-in name or a URDF), its robot
    masks deleted (`keep_masks`: kept); with `reuse`, a scene already rendered in `out` with
    the same settings (`rendered_for`; with `keep_masks`, with its masks) is taken as it is.
    `time_offset_s`: the written joint readings lag the images by this (a `trajectory` scene,
    `synth.extension`)."""
    from dream.extension import ModelExtension
    from synth.generate import generate

    job = scene_job(robot, out, seed, frames, scale_to_robot, overrides, keypoints,
                    ModelExtension(time_offset_s=time_offset_s) if time_offset_s else None)
    if reuse and rendered_for(job) and (not keep_masks or any(out.glob("*.seg.png"))):
        return out
    generate(job, overwrite=True, on_progress=lambda done: None)
    for mask in [] if keep_masks else out.glob("*.seg.png"):
        mask.unlink()
    return out


def scene_job(robot: str, out: Path, seed: int, frames: int, scale_to_robot: bool = False,
              overrides: tuple[str, ...] = (), keypoints: tuple[str, ...] | None = None,
              extension=None):
    """The `synth.generate.SynthJob` of a `render_scene` scene."""
    from synth.generate import SynthJob

    return SynthJob(robot=robot, out_dir=out, num_frames=frames,
                    config=randomisation(robot, scale_to_robot, overrides, keypoints),
                    seed=seed, keypoints=robot_keypoints(robot, keypoints), extension=extension)


def given_principal(data: Path, shift_px: tuple[float, float], out: Path) -> Path:
    """A copy of `data` whose principal point lies `shift_px` (du, dv) from the one it was
    rendered with (the image centre given for a calibrated cx, cy), written anew."""
    from dream.coarse.principal import with_principal_shift

    seq = read_sequence(data)
    return write_dream(seq.with_fixed_camera(with_principal_shift(seq.camera, shift_px)), out,
                       overwrite=True)


def given_undistorted(data: Path, out: Path) -> Path:
    """A copy of `data` whose camera carries no distortion coefficients (raw images of a
    distorted lens given as if rectified), written anew over an earlier one."""
    seq = read_sequence(data)
    return write_dream(seq.with_fixed_camera(replace(seq.camera, distortion=None)), out,
                       overwrite=True)


def given_focal(data: Path, scale: float, out: Path) -> Path:
    """A copy of `data` whose fx, fy are `scale` times those it was rendered with (intrinsics
    given wrong, as after resizing an image without its K), written anew over an earlier one."""
    from dream.coarse.focal import with_focal_scale

    seq = read_sequence(data)
    return write_dream(seq.with_fixed_camera(with_focal_scale(seq.camera, scale)), out,
                       overwrite=True)


def given_joint_offsets(data: Path, sigma_rad: float, seed: int, out: Path
                        ) -> tuple[Path, np.ndarray]:
    """A copy of `data` (written anew) whose revolute and continuous joints but the first read
    a constant offset from the rendered angle, drawn from N(0, `sigma_rad`) per joint (seeded
    by the scene's `seed`, so that a run with and one without draw the same guesses), and the
    offsets (J,) in the order of its joints (0 for the others). The first joint's offset turns
    everything beyond it about its axis, as a turn of the camera about that axis would: the
    extrinsic in the robot's own kinematics holds it, and only the base link's outline could
    tell (the joints in URDF order, the first nearest the base)."""
    from dream.robot.registry import load_robot
    from dream.robot.tree import CONTINUOUS, REVOLUTE

    seq = read_sequence(data)
    tree = load_robot(seq.robot, seq.keypoint_names).tree
    rotating = np.array([tree.joints[tree.joint_index[name]].type in (REVOLUTE, CONTINUOUS)
                         for name in seq.joint_names])
    rotating[np.argmax(rotating)] = False     # the first: turns the whole arm (doc above)
    offsets = np.random.default_rng([seed, JOINT_OFFSET_STREAM]).normal(
        0.0, sigma_rad, len(rotating)) * rotating
    return write_dream(seq.with_joints(seq.joints + offsets), out, overwrite=True), offsets


def video_coded(data: Path, codec: str, out: Path) -> Path:
    """A copy of `data` (written anew) whose images went through the video `codec`
    (`VIDEO_CODECS`) and back, in frame order.

    Raises:
        InputError: the codec cannot be written here, or returns another number of frames.
    """
    import cv2

    fourcc, container = VIDEO_CODECS[codec]
    copy = write_dream(read_sequence(data), out, overwrite=True)
    paths = [frame.image_path for frame in read_sequence(copy).frames]
    images = [cv2.imread(str(path), cv2.IMREAD_COLOR) for path in paths]
    height, width = images[0].shape[:2]
    with tempfile.TemporaryDirectory() as tmp:
        video = str(Path(tmp) / f"frames{container}")
        writer = cv2.VideoWriter(video, cv2.VideoWriter_fourcc(*fourcc), VIDEO_FPS,
                                 (width, height))
        if not writer.isOpened():
            raise InputError(f"OpenCV cannot write {codec} here", str(data),
                             f"choose another of {sorted(VIDEO_CODECS)}")
        for image in images:
            writer.write(image)
        writer.release()
        reader, decoded = cv2.VideoCapture(video), []
        while len(decoded) <= len(paths):
            ok, image = reader.read()
            if not ok:
                break
            decoded.append(image)
        reader.release()
    if len(decoded) != len(paths):
        raise InputError(f"{codec} gave back {len(decoded)} of {len(paths)} frames", str(data))
    for path, image in zip(paths, decoded, strict=True):
        cv2.imwrite(str(path), image)
    return copy


def guess_file(T_true: np.ndarray, offset_m: float, offset_rad: float,
               rng: np.random.Generator, folder: Path) -> Path:
    """A RESULT.json holding only a T_cam_base `offset_m` / `offset_rad` off `T_true` in a
    random direction."""
    T = invert_T(T_true)
    direction, axis = rng.normal(size=3), rng.normal(size=3)
    T[:3, 3] += offset_m * direction / np.linalg.norm(direction)
    T[:3, :3] = T[:3, :3] @ R_from_rotvec(offset_rad * axis / np.linalg.norm(axis))
    path = folder / f"guess_{rng.integers(1 << 30)}.json"
    path.write_text(json.dumps({"T_cam_base": invert_T(T).tolist()}))
    return path


def mark_file(data: Path, T_true: np.ndarray, count: int, noise_px: float,
              rng: np.random.Generator, folder: Path) -> tuple[Path, str]:
    """Marks of the robot's last keypoint link's origin (the end effector) where the images
    show it (its labels; without them projected with `T_true` from the readings) plus
    `noise_px` per axis, in `count` frames evenly spaced among those showing it (all of them
    where fewer show it). Where the readings lag the images (`--time-offset`) only the labels
    are where a user clicks."""
    from dream.camera import project
    from dream.pipeline import joints_in_robot_order, robot_for
    from dream.transforms import transform_points

    seq = read_sequence(data)
    robot = robot_for(seq, None, tuple(seq.keypoint_names) or None)
    link = robot.keypoint_names[-1]
    P = robot.link_poses(joints_in_robot_order(seq, robot), (link,))[:, 0, :3, 3]
    uv = (seq.uv_labels()[:, seq.keypoint_names.index(link)] if link in seq.keypoint_names
          else project(seq.camera, transform_points(T_true, P)))
    uv = uv + rng.normal(0, noise_px, (len(P), 2))
    seen = np.flatnonzero(seq.camera.in_image(uv))
    chosen = seen[np.unique(np.round(np.linspace(0, len(seen) - 1, count)).astype(int))]
    path = folder / f"marks_{data.name}.csv"
    path.write_text("frame,u,v\n" + "".join(f"{seq.frames[i].name},{uv[i, 0]:.2f},"
                                             f"{uv[i, 1]:.2f}\n" for i in chosen))
    return path, link


def fooled_labels(data: Path, T_true: np.ndarray, offset_m: float, offset_rad: float,
                  rng: np.random.Generator, out: Path, camera=None) -> Path:
    """A copy of `data` whose keypoint labels are the projections at a camera `offset_m` /
    `offset_rad` off `T_true` (a detector fooled the same way in every frame), through
    `camera` (the one the images were rendered with; default: the data's)."""
    import dataclasses

    from dream.camera import project
    from dream.pipeline import robot_for
    from dream.transforms import transform_points

    seq = read_sequence(data)
    robot = robot_for(seq, None, tuple(seq.keypoint_names) or None)
    T_off = read_result(guess_file(T_true, offset_m, offset_rad, rng, out.parent))["T_cam_base"]
    camera = camera or seq.camera
    frames = tuple(dataclasses.replace(f, uv_labels=project(camera, transform_points(
        np.asarray(T_off), robot.forward_kinematics(f.joints)))) for f in seq.frames)
    return write_dream(dataclasses.replace(seq, frames=frames), out)


def calibrate(data: Path, out: Path, guess: Path | None,
              T_true: np.ndarray | None = None, mark: tuple[Path, str, str] | None = None,
              fixed_focal: bool = False, fixed_principal: bool = False,
              fixed_distortion: bool = False) -> dict:
    """One `dream calibrate` without keypoints (from `guess`, or from `mark`: the marks file,
    its link and offset): its error against `T_true` (default the data's reference), time,
    verdict, 1-sigma and IoUs."""
    start = time.perf_counter()
    marks = {} if mark is None else {"mark": str(mark[0]), "mark_link": mark[1],
                                     "mark_offset": mark[2]}
    if guess == LABELS:
        guess, marks = None, {"use_labels": True}
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        doc = run_calibrate(CalibrateRequest(data=str(data), out=str(out),
                                             fixed_focal=fixed_focal,
                                             fixed_principal=fixed_principal,
                                             fixed_distortion=fixed_distortion,
                                             camera_guess=None if guess is None else str(guess),
                                             **marks))
    seconds = time.perf_counter() - start
    T_true = truth_poses(read_sequence(data))[0] if T_true is None else T_true
    T = np.asarray(doc["T_cam_base"])
    t_err, r_err = pose_errors(T, T_true)
    xi = increment_between(T, T_true)
    chi2 = float(xi @ np.linalg.pinv(np.asarray(doc["covariance_xi"])) @ xi)
    sigma = float(np.linalg.norm(doc["sigma_camera_position_base_m"]))
    focal = (doc.get("start") or {}).get("focal")
    away = (doc.get("start") or {}).get("away") or {"share": 0.0}
    timing = (doc.get("start") or {}).get("timing") or {"adopted": False}
    principal = (doc.get("start") or {}).get("principal")
    distortion = (doc.get("start") or {}).get("distortion")
    return {"focal": ("" if distortion is None else ", radial shift at the corner "
                      f"{100 * distortion['corner_shift']:+.1f} % (1-sigma "
                      f"{100 * (distortion['sigma'] or float('nan')):.1f} %"
                      + ("" if distortion.get("k2_sigma") is None else
                         f"; {100 * distortion['k2_share']:+.1f} % through k2")
                      + ", IoU "
                      f"{distortion['iou_given']:.3f} -> {distortion['iou_fitted']:.3f}) "
                      f"{'adopted' if distortion['adopted'] else 'kept as given'}")
            + ("" if focal is None else f", focal x{focal['scale']:.3f} "
                      f"{'adopted' if focal['adopted'] else 'kept as given'}")
            + ("" if principal is None else ", principal point asked {:+.1f}, {:+.1f} px "
               "({:.2f} deg){}".format(*principal["shift_px"],
                                       np.rad2deg(principal["angle_rad"]),
                                       (", adopted" if principal.get("adopted") else
                                        ", flagged" if principal["flagged"] else "")))
            + ("" if not timing["adopted"] else f", the readings {1000 * timing['seconds']:+.0f}"
               f" ms on ({timing['rounds']} searches again)")
            + ("" if not away["share"] else f", {100 * away['share']:.1f} % of the moving "
               f"pixels away from the robot (IoU without them {away['iou_without']:.3f})")
            + _adopted_on_keypoint_path(doc),
            "mm": t_err * 1e3, "deg": float(np.rad2deg(r_err)), "verdict":
            doc["quality"]["verdict"], "sigma_mm": sigma * 1e3,
            "inside95": chi2 <= CHI2_6DOF_95, "chi2": chi2, "seconds": seconds,
            "polish_iou": doc.get("polish", {}).get("iou_after"),
            "iou": (doc.get("start") or {}).get("iou", (doc.get("silhouette_check") or {}).get(
                "iou_silhouettes", float("nan"))),
            "found_iou": (doc.get("start") or {}).get("found_iou"),
            "mark_mm": mark_error_mm(doc, T_true) if mark is not None else None}


def mark_error_mm(doc: dict, T_true: np.ndarray) -> float | None:
    """The mark's own PnP pose's error (mm), None where it had too few frames for one."""
    T_mark = doc["start"]["mark"]["T_cam_base"]
    return None if T_mark is None else pose_errors(np.asarray(T_mark), T_true)[0] * 1e3


def summary(rows: list[dict], right_mm: float, right_deg: float, label: str) -> None:
    if not rows:
        return
    right = [r for r in rows if r["mm"] <= right_mm and r["deg"] <= right_deg]
    wrong = [r for r in rows if r not in right]
    far = [r for r in rows if r["mm"] > 50 or r["deg"] > 5]
    print(f"{label}: {len(right)}/{len(rows)} within {right_mm:g} mm / {right_deg:g} deg; "
          f"median {np.median([r['mm'] for r in rows]):.1f} mm; "
          f"good among >5 cm/5 deg wrong: {sum(r['verdict'] == 'good' for r in far)}/{len(far)}; "
          f"good among wrong: {sum(r['verdict'] == 'good' for r in wrong)}/{len(wrong)}; "
          f"good or check among right: "
          f"{sum(r['verdict'] != 'unreliable' for r in right)}/{len(right)}; "
          f"truth in 95% ellipsoid: {sum(r['inside95'] for r in rows)}/{len(rows)}; "
          f"median time {np.median([r['seconds'] for r in rows]):.0f} s")


def render_keypoints(args: argparse.Namespace) -> tuple[str, ...] | None:
    """`--render-keypoints` as link names; it names one URDF's links, so one URDF only."""
    if not args.render_keypoints:
        return None
    robots = args.robots.split(",")
    if len(robots) != 1 or robot_keypoints(robots[0]) is None:
        raise InputError(f"--render-keypoints names the links of one URDF, and --robots is "
                         f"{args.robots!r}", fix="give --robots one URDF file")
    return tuple(name.strip() for name in args.render_keypoints.split(",") if name.strip())


def _pixel_pair(text: str) -> tuple[float, float]:
    try:
        du, dv = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected DU,DV in pixels, got {text!r}") from None
    return du, dv


def run_renders(args: argparse.Namespace) -> None:
    keypoints = render_keypoints(args)
    rng = np.random.default_rng(args.seed)
    by_mode: dict[str, list[dict]] = {"guess": [], "auto": [], "mark": [], "fooled": []}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = args.work or Path(tmp)
        for robot in args.robots.split(","):
            name = Path(robot).stem
            for seed in range(args.first_seed, args.first_seed + args.scenes):
                data = render_scene(robot, tmp / f"{name}_{seed}", seed, args.frames,
                                    args.scale_to_robot, tuple(args.set), args.reuse_scenes,
                                    keypoints, args.time_offset)
                if args.video_codec:
                    data = video_coded(data, args.video_codec,
                                       tmp / f"{name}_{seed}_{args.video_codec}")
                rendered = read_sequence(data).camera     # the labels' camera
                if args.given_focal != 1.0:
                    data = given_focal(data, args.given_focal,
                                       tmp / f"{name}_{seed}_focal{args.given_focal:g}")
                if args.given_no_distortion:
                    data = given_undistorted(data, tmp / f"{name}_{seed}_undistorted")
                if args.joint_offsets_deg:
                    data, offsets = given_joint_offsets(
                        data, np.deg2rad(args.joint_offsets_deg), seed,
                        tmp / f"{name}_{seed}_joints{args.joint_offsets_deg:g}")
                    print(f"{name} {seed}: joint offsets "
                          f"{np.round(np.rad2deg(offsets), 2).tolist()} deg", flush=True)
                if args.given_principal is not None:
                    du, dv = args.given_principal
                    data = given_principal(data, (du, dv),
                                           tmp / f"{name}_{seed}_principal{du:g}_{dv:g}")
                T_true = truth_poses(read_sequence(data))[0]
                modes = [] if args.skip_guess else [("guess", guess_file(
                    T_true, args.guess_m, np.deg2rad(args.guess_deg), rng, tmp))]
                if args.auto:
                    modes.append(("auto", None))
                if args.mark_frames:
                    modes.append(("mark", None))
                if args.fooled:
                    modes.append(("fooled", LABELS))
                for mode, guess in modes:
                    mark, source = None, data
                    if mode == "fooled":
                        source = fooled_labels(data, T_true, args.guess_m,
                                               np.deg2rad(args.guess_deg), rng,
                                               tmp / f"{name}_{seed}_fooled", rendered)
                    if mode == "mark":
                        path, link = mark_file(data, T_true, args.mark_frames,
                                               args.mark_noise_px, rng, tmp)
                        mark = (path, link, "0,0,0")
                    if args.only and f"{name}_{seed}" not in args.only.split(","):
                        continue    # its guesses and marks drawn all the same
                    try:
                        row = calibrate(source, tmp / f"{name}_{seed}_{mode}.json", guess,
                                        T_true, mark=mark, fixed_focal=args.fixed_focal,
                                        fixed_principal=args.fixed_principal,
                                        fixed_distortion=args.fixed_distortion)
                    except DreamError as exc:
                        print(f"{name} {seed} {mode}: failed: {exc}", flush=True)
                        continue
                    by_mode[mode].append(row)
                    print(f"{name} {seed} {mode}: {row['mm']:.1f} mm {row['deg']:.2f} deg, "
                          f"{row['verdict']}, 1-sigma {row['sigma_mm']:.1f} mm (truth at "
                          f"chi2 {row['chi2']:.1f}), IoU {row['iou']:.3f}"
                          + ("" if row["found_iou"] is None
                             else f" ({row['found_iou']:.3f} with the held pixels kept)")
                          + f", {row['seconds']:.0f} s{row['focal']}"
                          + ("" if mark is None else ", the mark too few for a pose"
                             if row["mark_mm"] is None else f", the mark's own pose "
                             f"{row['mark_mm']:.0f} mm off"), flush=True)
    for mode, rows in by_mode.items():
        summary(rows, args.right_mm, args.right_deg, mode)


def _adopted_on_keypoint_path(doc: dict) -> str:
    """What the keypoint path's cross-check asked of the intrinsics and what was adopted."""
    check = doc.get("silhouette_check") or {}
    if not check.get("ran") or check.get("principal") is None:
        return ""
    p = check["principal"]
    text = (", outlines ask x{:.3f}, {:+.1f}, {:+.1f} px ({:.2f} deg)".format(
        check["focal"]["scale"], *p["shift_px"], np.rad2deg(p["angle_rad"])))
    lens = check.get("distortion")
    if lens is not None and lens["asked"]:
        text += f", lens distortion asked ({100 * lens['corner_shift']:+.1f} % at the corner)"
    lens = doc.get("distortion")
    if lens:
        text += ", adopted k1, k2 {:.3f}, {:.3f} ({:+.1f} % at the corner)".format(
            *lens["used"]["distortion"][:2], 100 * lens["corner_shift"])
    for key, what in (("focal", "fx, fy {fx:.1f}, {fy:.1f}"), ("principal", "cx, cy {cx:.1f}, "
                                                                          "{cy:.1f}")):
        if doc.get(key):
            text += f", adopted {what.format(**doc[key]['used'])}"
    return text


def run_real(args: argparse.Namespace) -> None:
    rng = np.random.default_rng(args.seed)
    data = Path(args.data)
    T_true = (np.asarray(read_result(args.center)["T_cam_base"]) if args.center else
              truth_poses(read_sequence(data))[0])
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        guesses = [guess_file(T_true, args.guess_m, np.deg2rad(args.guess_deg), rng, tmp)
                   for _ in range(args.guesses)] + ([None] if args.auto else [])
        mark = None if args.mark is None else (args.mark, args.mark_link, args.mark_offset)
        if mark is not None:
            guesses = [None]
        for k, guess in enumerate(guesses):
            row = calibrate(data, tmp / f"r{k}.json", guess, T_true, mark, args.fixed_focal,
                            args.fixed_principal, args.fixed_distortion)
            rows.append(row)
            polish = ("" if row["polish_iou"] is None else
                      f", polish IoU {row['polish_iou']:.3f}")
            label = "mark" if mark else "auto" if guess is None else f"guess {k}"
            print(f"{label}: {row['mm']:.1f} mm "
                  f"{row['deg']:.2f} deg{' from the centre' if args.center else ''}, "
                  f"{row['verdict']}, 1-sigma {row['sigma_mm']:.1f} mm (chi2 "
                  f"{row['chi2']:.1f}), search IoU "
                  f"{row['iou']:.3f}{polish}, {row['seconds']:.0f} s{row['focal']}", flush=True)
    summary(rows, args.right_mm, args.right_deg, data.name)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="what", required=True)
    for name in ("renders", "real"):
        s = sub.add_parser(name)
        s.add_argument("--guess-m", type=float, default=0.3)
        s.add_argument("--guess-deg", type=float, default=20.0)
        s.add_argument("--auto", action="store_true")
        s.add_argument("--seed", type=int, default=0)
        s.add_argument("--fixed-focal", action="store_true", help="calibrate with the data's "
                       "fx, fy as given (no focal-length fit)")
        s.add_argument("--fixed-principal", action="store_true", help="keep the data's cx, "
                       "cy as given (a principal point the outlines ask for is reported)")
        s.add_argument("--fixed-distortion", action="store_true", help="keep the data's "
                       "distortion as given (a lens the outlines ask for is reported)")
        s.add_argument("--right-mm", type=float, default=10.0 if name == "renders" else 10.0)
        s.add_argument("--right-deg", type=float, default=0.5 if name == "renders" else 1.0)
    r = sub.choices["renders"]
    r.add_argument("--robots", default="panda,ur5,xarm7", help="built-in names or URDF files "
                   "(their keypoints suggested, `dream robots --urdf`)")
    r.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override a randomisation key (repeatable), e.g. "
                   "intrinsics.width=960 distractors.robot_prob=1")
    r.add_argument("--render-keypoints", metavar="LINKS", help="a URDF's keypoint links for the "
                   "renders (they move every joint up to them); default its suggested ones, "
                   "carried along every arm of a robot with two")
    r.add_argument("--scale-to-robot", action="store_true", help="the randomisation's "
                   "camera and distractor distances and sizes times the robot's size over "
                   "the Panda's (a small arm seen from as near as a user would put the camera)")
    r.add_argument("--given-focal", type=float, default=1.0, help="give the calibration fx, "
                   "fy this many times those rendered with (default 1: as rendered)")
    r.add_argument("--given-no-distortion", action="store_true",
                   help="give the calibration no distortion coefficients (the lens rendered "
                        "with `--set intrinsics.distortion=[...]`)")
    r.add_argument("--given-principal", type=_pixel_pair, default=None, metavar="DU,DV",
                   help="give the calibration a principal point DU, DV pixels from the one "
                   "rendered with")
    r.add_argument("--video-codec", choices=sorted(VIDEO_CODECS), help="the frames through "
                   "this video codec and back before calibrating (a recording kept as video)")
    r.add_argument("--reuse-scenes", action="store_true", help="take a scene already "
                   "rendered in --work as it is (the same seed and settings render the same)")
    r.add_argument("--time-offset", type=float, default=0.0, metavar="S", help="the joint "
                   "readings lag the images by S seconds (with --set sequence.mode=trajectory)")
    r.add_argument("--joint-offsets-deg", type=float, default=0.0, metavar="S",
                   help="give the calibration each revolute joint's readings but the first's "
                   "off by a constant drawn from N(0, S deg) per joint and scene")
    r.add_argument("--scenes", type=int, default=3)
    r.add_argument("--first-seed", type=int, default=1000)
    r.add_argument("--frames", type=int, default=30)
    r.add_argument("--work", type=Path, help="keep the scenes and results here (default: a "
                   "temporary folder)")
    r.add_argument("--mark-frames", type=int, default=0, help="also calibrate from a mark on "
                   "the end effector clicked in this many frames (labels plus noise)")
    r.add_argument("--mark-noise-px", type=float, default=2.0)
    r.add_argument("--fooled", action="store_true", help="also the keypoint path from labels "
                   "projected at a camera --guess-m / --guess-deg off (a fooled detector): "
                   "the edge alignment and the silhouettes' cross-check from there")
    r.add_argument("--only", help="calibrate only these scenes (ROBOT_SEED,...), the others "
                   "rendered and their guesses and marks drawn as in a whole run, so that "
                   "each listed scene gets the same guess as there")
    r.add_argument("--skip-guess", action="store_true", help="not from a guess (only --auto, "
                   "--mark-frames)")
    sub.choices["real"].add_argument("--data", required=True)
    sub.choices["real"].add_argument("--guesses", type=int, default=10)
    sub.choices["real"].add_argument("--mark", help="MARKS.csv (clicked by eye): calibrate "
                                     "once from it instead of from guesses")
    sub.choices["real"].add_argument("--mark-link")
    sub.choices["real"].add_argument("--mark-offset", default="0,0,0")
    sub.choices["real"].add_argument("--center", help="RESULT.json: the guesses' centre and "
                                     "the comparison, for data without a reference")
    args = p.parse_args()
    (run_renders if args.what == "renders" else run_real)(args)


if __name__ == "__main__":
    main()
