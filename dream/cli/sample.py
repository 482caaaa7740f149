"""`dream sample`: the built-in keypoint-only synthetic sample written as a DREAM folder."""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dream.cli.options import (
    add_command,
    add_keypoints_arg,
    check_positive,
    check_seed,
    parse_keypoints,
    request_from,
)
from dream.errors import InputError


@dataclass(frozen=True)
class SampleRequest:
    """What `dream sample` does: the options of its command line."""

    out: str
    robot: str = "panda"
    keypoints: str | None = None
    num: int = 20
    noise_px: float = 1.0
    outliers: float = 0.0
    seed: int = 0
    overwrite: bool = False

    def __post_init__(self) -> None:
        check_seed(self.seed)
        check_positive(self.num, "--num", "give --num 1 or more frames")
        if not np.isfinite(self.noise_px) or self.noise_px < 0:
            raise InputError(f"--noise-px must be a finite number of pixels >= 0, got "
                             f"{self.noise_px}", fix="give e.g. --noise-px 1.0 (0: exact labels)")
        if not np.isfinite(self.outliers) or not 0 <= self.outliers <= 1:
            raise InputError(f"--outliers must be a fraction between 0 and 1, got "
                             f"{self.outliers}",
                             fix="give e.g. --outliers 0.1 (0: no outlier labels)")


def run_sample(request: SampleRequest) -> None:
    """The sample of `request` drawn and written to `request.out`."""
    from dream.io import write_dream
    from dream.pipeline import robot_with_option_keypoints
    from dream.sample import SampleSettings, make_sample

    keypoints = parse_keypoints(request.keypoints)
    if keypoints:
        robot_with_option_keypoints(request.robot, keypoints)   # the links checked, explained
    spec = SampleSettings(robot=request.robot, keypoints=keypoints, num_frames=request.num,
                          pixel_noise_px=request.noise_px, outlier_fraction=request.outliers,
                          seed=request.seed)
    write_dream(make_sample(spec), Path(request.out), overwrite=request.overwrite)
    print(f"wrote {spec.num_frames} keypoint-only frames of {spec.robot} to {request.out}")


def cmd_sample(args: argparse.Namespace) -> int:
    run_sample(request_from(SampleRequest, args))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """The `dream sample` parser."""
    p = add_command(sub, "sample", cmd_sample, "write the built-in keypoint-only synthetic sample")
    p.add_argument("--out", required=True, help="dataset folder to write (DREAM layout)")
    p.add_argument("--robot", default="panda",
                   help="built-in robot name or URDF path (default: %(default)s)")
    add_keypoints_arg(p)
    p.add_argument("--num", type=int, default=20, help="frames (default: %(default)s)")
    p.add_argument("--noise-px", type=float, default=1.0,
                   help="Gaussian noise of the 2D labels, pixels (default: %(default)s)")
    p.add_argument("--outliers", type=float, default=0.0,
                   help="fraction of random labels (default: %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing --out folder")
