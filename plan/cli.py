"""`dream plan`: registered through the `dream.commands` entry point; imports nothing heavy."""

from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from dream.cli.options import (
    KEYPOINTS_HELP,
    add_command,
    check_positive,
    check_seed,
    parse_intrinsics,
    parse_keypoints,
    parse_numbers,
)
from dream.errors import InputError

PROGRESS_PERIOD_S = 5.0   # candidate-search progress lines on stderr at most this often
FIX_CAMERA = ("give --camera RESULT.json (an earlier calibration), or --camera X,Y,Z with "
              "--look-at X,Y,Z and --intrinsics fx,fy,cx,cy,width,height (metres, base frame)")
NONE = "none"
INTRINSICS_FIELDS = ("fx", "fy", "cx", "cy", "width", "height")
REACH_SAMPLES = 64        # joint vectors whose link origins give the robot's reach
# below this share of the image's shorter side, the keypoints' spread is too small for the
# keypoint model and the outline alignment: `dream plan` warns
MIN_ROBOT_SPAN_FRACTION = 0.25


def _joint_ranges(items: list[str]) -> dict[str, tuple[float, float]]:
    fix = "give --joint-range NAME=LOW:HIGH, e.g. panda_joint1=-1.5:1.5 (radians)"
    out = {}
    for item in items:
        name, _, span = item.partition("=")
        low, _, high = span.partition(":")
        try:
            values = (float(low), float(high))
        except ValueError:
            raise InputError(f"--joint-range '{item}' is not NAME=LOW:HIGH", fix=fix) from None
        if name.strip() in out:
            raise InputError(f"--joint-range names {name.strip()} twice", fix="give one range "
                             "per joint")
        out[name.strip()] = values
    return out


@dataclass(frozen=True)
class PlanRequest:
    """What `dream plan` does: the options of its command line."""

    robot: str
    camera: str
    out: str
    look_at: str | None = None
    intrinsics: str | None = None
    position_sigma_m: float | None = None
    rotation_sigma_deg: float | None = None
    num: int = 12
    joint_range: tuple[str, ...] = ()
    table_z: str = "0"
    keep_out: tuple[str, ...] = ()
    model: str | None = None
    keypoints: str | None = None
    noise_px: float = 1.0
    margin_px: float = 20.0
    max_cut: float = 0.2
    clearance_m: float = 0.01
    candidates: int = 600
    max_draws: int = 60000
    camera_samples: int = 16
    start: str | None = None
    seed: int = 0
    overwrite: bool = False

    def __post_init__(self) -> None:
        check_seed(self.seed)
        check_positive(self.num, "--num", "give --num 1 or more poses")
        object.__setattr__(self, "joint_range", tuple(self.joint_range or ()))
        object.__setattr__(self, "keep_out", tuple(self.keep_out or ()))
        for name in ("position_sigma_m", "rotation_sigma_deg"):
            value = getattr(self, name)
            if value is not None and not (math.isfinite(value) and value >= 0):
                raise InputError(f"--{name.replace('_', '-')} must be a finite number >= 0, "
                                 f"got {value}")

    def camera_is_position(self) -> bool:
        """--camera is X,Y,Z rather than a result file."""
        return not Path(self.camera).is_file() and "," in self.camera

    def robot_names(self) -> set[str]:
        """Names a RESULT.json of this robot may record: as given, or a URDF's stem."""
        return {self.robot, Path(self.robot).stem}

    def table_z_m(self) -> float | None:
        if self.table_z.strip().lower() == NONE:
            return None
        return parse_numbers(self.table_z, (1,), "--table-z", "give the table height in metres "
                       "(base frame), or --table-z none")[0]


def _prior(request: PlanRequest):
    from dream.plausibility import check_camera
    from plan.camera_prior import prior_from_look_at, prior_from_result

    camera = None
    if request.intrinsics is not None:
        if len(request.intrinsics.split(",")) != len(INTRINSICS_FIELDS):
            raise InputError(f"--intrinsics '{request.intrinsics}' must be six numbers "
                             f"{','.join(INTRINSICS_FIELDS)}",
                             fix="give e.g. --intrinsics 600,600,319.5,239.5,640,480 (pixels)")
        camera = parse_intrinsics(request.intrinsics)
        check_camera(camera)
    rotation = None if request.rotation_sigma_deg is None else \
        math.radians(request.rotation_sigma_deg)
    if not request.camera_is_position():
        if request.look_at is not None:
            raise InputError("--look-at goes with a camera position, not a result file",
                             fix=FIX_CAMERA)
        if not Path(request.camera).is_file():
            raise InputError(f"--camera '{request.camera}' is neither a RESULT.json file nor a "
                             "position X,Y,Z", fix=FIX_CAMERA)
        return prior_from_result(request.camera, camera, request.position_sigma_m, rotation,
                                 request.robot_names())
    if request.look_at is None or camera is None:
        raise InputError("a camera position needs --look-at and --intrinsics", fix=FIX_CAMERA)
    position = parse_numbers(request.camera, (3,), "--camera", FIX_CAMERA)
    target = parse_numbers(request.look_at, (3,), "--look-at", FIX_CAMERA)
    kwargs = {k: v for k, v in (("position_sigma_m", request.position_sigma_m),
                                ("rotation_sigma_rad", rotation)) if v is not None}
    return prior_from_look_at(position, target, camera, **kwargs)


def _check_scale(robot, prior, target) -> None:
    """Refuse a camera position or look-at point that cannot be metres for `robot`
    (`dream.coarse.hypotheses.check_guess_scale`, as `dream calibrate --camera-guess`), its
    reach the farthest link origin over `REACH_SAMPLES` joint vectors within its limits
    (continuous joints within a turn)."""
    import numpy as np

    from dream.coarse.hypotheses import check_guess_scale
    from dream.coarse.settings import SearchSettings

    lower = np.where(np.isfinite(robot.joint_lower), robot.joint_lower, -np.pi)
    upper = np.where(np.isfinite(robot.joint_upper), robot.joint_upper, np.pi)
    joints = np.random.default_rng(0).uniform(lower, upper, (REACH_SAMPLES, len(lower)))
    P = robot.link_poses(joints, robot.link_names)[..., :3, 3].reshape(-1, 3)
    settings = SearchSettings()
    check_guess_scale(prior.T_cam_base, prior.position_sigma_m, P.mean(axis=0),
                      float(np.max(np.linalg.norm(P, axis=1))), settings.max_guess_distance,
                      settings.max_guess_sigma, f"--camera {prior.source}", target,
                      sigma_fix="give --position-sigma-m in metres (e.g. 0.05), or leave it out")


def _check_above_table(prior, table_z_m: float | None) -> None:
    """Refuse a camera below the table plane: it would look at the robot through the table,
    which the plan does not model as hiding anything."""
    if table_z_m is None:
        return
    R, t = prior.T_cam_base[:3, :3], prior.T_cam_base[:3, 3]
    z = float((-R.T @ t)[2])
    if z < table_z_m:
        raise InputError(f"--camera {prior.source}: the camera lies at z = {z:.2f} m, below the "
                         f"table (--table-z {table_z_m:g}); it would see the robot through it",
                         fix="give the camera's position in the base frame above the table, "
                             "or --table-z none where there is no table")


def _robot(request: PlanRequest):
    """The robot with the model's keypoints (--keypoints must name the same links), else those
    of --keypoints, else its own."""
    from dream.detection import load_keypoint_model
    from dream.pipeline import check_option_agrees, robot_with_option_keypoints
    from dream.robot import load_robot

    keypoints = parse_keypoints(request.keypoints)
    if request.model is not None:
        names = tuple(load_keypoint_model(request.model).keypoint_names)
        if keypoints:
            check_option_agrees(keypoints, names, f"the model {request.model}")
        return load_robot(request.robot, names)
    if keypoints:
        return robot_with_option_keypoints(request.robot, keypoints)
    return load_robot(request.robot)


def _feasibility(request: PlanRequest):
    from plan.feasibility import Box, Feasibility

    fix = "give --keep-out xmin,ymin,zmin,xmax,ymax,zmax in metres (base frame)"
    boxes = []
    for text in request.keep_out:
        v = parse_numbers(text, (6,), "--keep-out", fix)
        boxes.append(Box(v[:3], v[3:]))
    return Feasibility(table_z_m=request.table_z_m(), keep_out=tuple(boxes),
                       clearance_m=request.clearance_m, margin_px=request.margin_px,
                       max_cut=request.max_cut)


class _Progress:
    def __init__(self) -> None:
        self.last = time.perf_counter()

    def __call__(self, found: int, draws: int) -> None:
        now = time.perf_counter()
        if now - self.last >= PROGRESS_PERIOD_S:
            self.last = now
            print(f"plan: {found} valid poses in {draws} draws", file=sys.stderr, flush=True)


def run_plan(request: PlanRequest) -> None:
    """Plan, write PLAN_DIR, print a summary."""
    import numpy as np

    from dream.io.atomic import check_output_dir
    from plan.output import render_sheet, write_plan
    from plan.planner import (
        PlanSettings,
        choose_poses,
        find_candidates,
        joint_ranges,
        start_joints,
    )

    check_output_dir(Path(request.out), request.overwrite)
    robot = _robot(request)
    prior = _prior(request)
    if request.camera_is_position():
        _check_scale(robot, prior, np.asarray(parse_numbers(request.look_at, (3,), "--look-at",
                                                            FIX_CAMERA), float))
    feasibility = _feasibility(request)
    _check_above_table(prior, feasibility.table_z_m)
    settings = PlanSettings(num_poses=request.num, candidates=request.candidates,
                            max_draws=request.max_draws, camera_samples=request.camera_samples,
                            noise_px=request.noise_px, seed=request.seed)
    ranges = joint_ranges(robot, _joint_ranges(list(request.joint_range)))
    start = start_joints(robot, None if request.start is None else parse_numbers(
        request.start, (robot.num_joints,), "--start",
        f"give {robot.num_joints} joint values ({', '.join(robot.joint_names)}), radians"))
    candidates = find_candidates(robot, prior, feasibility, settings, ranges, _Progress())
    plan = choose_poses(robot, prior, candidates, settings, start)
    write_plan(request.out, plan, robot, prior, feasibility, settings,
               render_sheet(plan, robot, prior, feasibility), request.overwrite)
    p, r = plan.predicted, plan.random_predicted
    print(f"planned {len(plan.joints)} poses of {robot.name} from {len(candidates.joints)} valid "
          f"candidates ({candidates.draws} draws); joint path {plan.path_length:.2f} rad")
    print(f"predicted 1-sigma at {request.noise_px:g} px keypoint noise: camera position "
          f"{p['position_worst_m'] * 1e3:.2f} mm, rotation "
          f"{math.degrees(p['rotation_worst_rad']):.3f} deg (random valid poses: "
          f"{r['position_worst_m'] * 1e3:.2f} mm, {math.degrees(r['rotation_worst_rad']):.3f} "
          "deg)")
    _warn_small_robot(robot, prior, plan.joints)
    moves = plan.move_clearance_m
    if moves is not None and np.any(moves < feasibility.clearance_m):
        print(f"warning: {int(np.sum(moves < feasibility.clearance_m))} of {len(moves)} "
              "straight joint moves between the poses pass closer than the clearance to a "
              "link, box or the table (plan.json \"moves\"): drive those with a motion planner")
    print(f"wrote {request.out}/joints.txt, plan.json, contact_sheet.png")


def _warn_small_robot(robot, prior, joints) -> None:
    """Warn where the planned poses' keypoints span little of the image (median over the
    poses of their bounding box's longer side): a camera far from the robot."""
    import numpy as np

    from dream.camera import project
    from dream.transforms import transform_points

    P = robot.link_poses(joints, robot.keypoint_names)[..., :3, 3]
    uv = project(prior.camera, transform_points(prior.T_cam_base, P))
    span = float(np.nanmedian(np.max(np.nanmax(uv, axis=1) - np.nanmin(uv, axis=1), axis=1)))
    side = min(prior.camera.width, prior.camera.height)
    if span < MIN_ROBOT_SPAN_FRACTION * side:
        print(f"warning: the robot's keypoints span about {span:.0f} px of the "
              f"{prior.camera.width}x{prior.camera.height} image (median over the poses); "
              f"below {MIN_ROBOT_SPAN_FRACTION:.0%} of its {side} px the keypoints and outlines "
              "are too small for an accurate calibration: place the camera nearer the robot")


def cmd_plan(args: argparse.Namespace) -> int:
    from dream.cli.options import request_from

    run_plan(request_from(PlanRequest, args))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """The `dream plan` parser."""
    p = add_command(sub, "plan", cmd_plan, "choose the robot poses to record for the most "
                    "accurate calibration (D-optimal, collision-free, keypoints in view)")
    p.add_argument("--robot", required=True, help="built-in robot name or URDF path")
    p.add_argument("--camera", required=True, metavar="RESULT.json|X,Y,Z",
                   help="the camera roughly: an earlier calibration's RESULT.json, or its "
                        "position in the base frame (m, with --look-at; write --camera=-1,0,1 "
                        "when the first number is negative)")
    p.add_argument("--look-at", metavar="X,Y,Z", help="a point the camera looks at, base frame, m")
    p.add_argument("--intrinsics", metavar="FX,FY,CX,CY,W,H",
                   help="camera intrinsics and image size in pixels; with a result, they replace "
                        "its camera, distortion included (default: the result's)")
    p.add_argument("--position-sigma-m", type=float, help="1-sigma of the camera position per "
                   "axis, m (default: the result's, else 0.05)")
    p.add_argument("--rotation-sigma-deg", type=float, help="1-sigma of the camera orientation "
                   "per axis, deg (default: the result's, else 3)")
    p.add_argument("--num", type=int, default=12, help="poses to plan (default: %(default)s)")
    p.add_argument("--out", required=True, help="plan folder to write")
    p.add_argument("--joint-range", action="append", metavar="NAME=LOW:HIGH",
                   help="narrow a joint's range within its URDF limits, rad (repeatable; "
                        "default: the limits)")
    p.add_argument("--table-z", default="0", help="height of the table plane no link may go "
                   "below, m in the base frame, or 'none' (default: %(default)s)")
    p.add_argument("--keep-out", action="append", metavar="XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX",
                   help="a box no link may enter, m in the base frame (repeatable; write "
                        "--keep-out=-1,... when the first number is negative; default: none)")
    p.add_argument("--model", metavar="MODEL.onnx", help="take the keypoints this detector "
                   "finds (default: the robot's own keypoints)")
    p.add_argument("--keypoints", metavar="LINK,LINK,...", help=KEYPOINTS_HELP)
    p.add_argument("--noise-px", type=float, default=1.0, help="expected keypoint noise, px "
                   "1-sigma (default: %(default)s)")
    p.add_argument("--margin-px", type=float, default=20.0, help="keypoints at least this far "
                   "inside the image border (default: %(default)s)")
    p.add_argument("--max-cut", type=float, default=0.2, help="largest share of the robot "
                   "outside the image (default: %(default)s)")
    p.add_argument("--clearance-m", type=float, default=0.01, help="least distance between "
                   "links, to boxes and to the table, m (default: %(default)s)")
    p.add_argument("--candidates", type=int, default=600, help="valid poses to choose from "
                   "(default: %(default)s)")
    p.add_argument("--max-draws", type=int, default=60000, help="random poses drawn at most "
                   "while looking for them (default: %(default)s)")
    p.add_argument("--camera-samples", type=int, default=16, help="camera poses drawn from its "
                   "uncertainty to average the criterion over (default: %(default)s)")
    p.add_argument("--start", metavar="Q1,...,QJ", help="the configuration the robot starts "
                   "from, rad, its move to the first pose checked (--start=-1,... when the first "
                   "is negative; default: none, the path begins at the pose nearest zero "
                   "clipped into the limits)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out folder")
