"""Where a recording's robot masks put the robot's outline, against its silhouettes rendered at a
known pose: the median distance (pixels, positive outside) of the masks' outline from the
silhouettes' outline on the silhouettes' left-, right-, up- and down-facing edges, for frames
before and after `--split-frame`, with the focal length scaled by each of `--focal-scales`.

The masks are those the silhouette search compares (`dream.coarse.calibration.search_masks`:
the data's own, else motion masks; never the reference). With the right pose and intrinsics
every side lies within half a pixel; an outline offset that follows the
arm's motion is a time lag or blur, one that flips sign between the arm far from and near the
camera is a magnification (the focal length), one the same everywhere a shifted pose. Pixels
the robot covers in most frames (in the background model of motion masks) are left out.

    python benchmarks/outline_offsets.py --data ../shared/realdata/panda_teleop \
        --split-frame 230 --focal-scales 1,1.02,1.04,1.06
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np

from dream.api import load_robot
from dream.coarse.calibration import MOTION_MASKS, search_masks
from dream.coarse.evidence import held_pixels
from dream.coarse.settings import SearchSettings
from dream.errors import InputError
from dream.io import read_sequence
from dream.pipeline import truth_poses
from dream.polish.objective import signed_distance
from dream.result import read_result
from dream.silhouette import render_frames, vertices_in_base

SIDES = ("left", "right", "up", "down")
FACING = 0.7          # an edge faces a side where its outward normal's component there exceeds this
MAX_OFFSET_PX = 8.0   # farther outline points are another object's (or none), not this edge's
HELD_MARGIN_PX = 2    # the held pixels are widened by this before their edges are left out


def outline_offsets(rendered: np.ndarray, mask: np.ndarray,
                    excluded: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Per side, the mask outline's distances (pixels, positive outside) at the rendered
    silhouette's outline pixels (H, W bool each) facing that side, without `excluded` pixels.

    >>> square = np.zeros((40, 40), bool); square[10:30, 10:30] = True
    >>> wider = np.zeros((40, 40), bool); wider[10:30, 8:30] = True
    >>> {k: float(np.median(v)) for k, v in outline_offsets(square, wider).items()}
    {'left': 2.0, 'right': 0.0, 'up': 0.0, 'down': 0.0}
    """
    rendered, mask = np.asarray(rendered, bool), np.asarray(mask, bool)
    if rendered.shape != mask.shape or rendered.ndim != 2:
        raise InputError(f"silhouette {rendered.shape} and mask {mask.shape} must be one (H, W)")
    sd_rendered = signed_distance(rendered)
    grad_y, grad_x = np.gradient(sd_rendered)
    edge = np.abs(sd_rendered) <= 0.5
    if excluded is not None:
        edge &= ~np.asarray(excluded, bool)
    # the pixel lies sd_rendered outside the silhouette's outline, the mask's outline lies
    # -sd_mask outside the pixel
    offset = sd_rendered[edge] - signed_distance(mask)[edge]
    near = np.abs(offset) < MAX_OFFSET_PX
    nx, ny, offset = grad_x[edge][near], grad_y[edge][near], offset[near]
    return dict(zip(SIDES, (offset[nx < -FACING], offset[nx > FACING], offset[ny < -FACING],
                            offset[ny > FACING]), strict=True))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", required=True, help="a fixed-camera recording")
    p.add_argument("--result", help="RESULT.json whose T_cam_base to render at (default: the "
                   "data's reference extrinsic)")
    p.add_argument("--split-frame", type=int, default=None,
                   help="report the frames before and from this index apart")
    p.add_argument("--focal-scales", default="1", help="comma-separated factors on fx and fy")
    args = p.parse_args()
    sequence = read_sequence(Path(args.data))
    T = (np.asarray(read_result(args.result)["T_cam_base"]) if args.result
         else truth_poses(sequence)[0])
    robot = load_robot(sequence)
    inputs = search_masks(sequence, robot, SearchSettings())
    P = vertices_in_base(inputs.meshes, inputs.joints)
    split = args.split_frame if args.split_frame is not None else int(inputs.frames.max()) + 1
    kernel = np.ones((2 * HELD_MARGIN_PX + 1,) * 2, np.uint8)
    print(f"{inputs.source} of {len(inputs.frames)} frames; median outline offset, px "
          f"(positive: the masks' outline outside the silhouettes')")
    for scale in (float(s) for s in args.focal_scales.split(",")):
        camera = replace(sequence.camera, fx=sequence.camera.fx * scale,
                         fy=sequence.camera.fy * scale)
        rendered = render_frames(P, inputs.meshes.faces, T, camera)
        held = cv2.dilate(held_pixels(rendered).astype(np.uint8), kernel).astype(bool) \
            if inputs.source == MOTION_MASKS else None
        groups: dict[str, dict[str, list]] = {}
        for frame, r, m in zip(inputs.frames, rendered, inputs.masks, strict=True):
            if not m.any():
                continue
            name = f"frames < {split}" if frame < split else f"frames >= {split}"
            for side, values in outline_offsets(r, m, held).items():
                groups.setdefault(name, {s: [] for s in SIDES})[side] += list(values)
        print(f"focal x{scale:g}: " + " | ".join(
            f"{name}: " + " ".join(f"{side} {np.median(v):+.1f}" if v else f"{side} -"
                                   for side, v in sides.items())
            for name, sides in groups.items()), flush=True)


if __name__ == "__main__":
    main()
