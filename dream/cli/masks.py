"""`dream masks`: the motion masks of a fixed-camera recording, written for inspection (the
masks `dream calibrate --polish --motion-masks` aligns with)."""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from typing import TextIO

import numpy as np

from dream.cli.options import (
    DATA_FILE_HELP,
    DataOptions,
    add_command,
    add_intrinsics_args,
    read_data,
    request_from,
)

PROGRESS_EVERY = 100            # frames between progress lines


@dataclass(frozen=True)
class MasksRequest(DataOptions):
    """What `dream masks` does: the options of its command line."""

    data: str
    out: str


def run_masks(request: MasksRequest, out: TextIO | None = None) -> int:
    """Write `background.png` and one `NNNNNN.motion.png` (0 / 255) per frame of
    `request.data` into `request.out`, all or none; returns how many masks were written.

    Raises:
        InputError: data without images, too few frames, an arm that hardly moves.
    """
    from dream.edges.motion import (
        MotionSettings,
        check_motion,
        motion_masks,
        sequence_motion_model,
    )
    from dream.io import check_output_folder, load_image
    from dream.io.atomic import staged_directory
    from dream.io.images import encode_png

    out = out or sys.stdout
    check_output_folder(request.out)                     # before any reading
    seq = read_data(request)
    background, settings = sequence_motion_model(seq, MotionSettings())
    cover = np.zeros(len(seq))
    with staged_directory(request.out) as stage:         # a failure leaves nothing
        (stage / "background.png").write_bytes(encode_png(background, stage / "background.png"))
        for i, frame in enumerate(seq.frames):
            mask = motion_masks(load_image(frame, seq.camera)[None], background, settings)[0]
            cover[i] = mask.mean()
            path = stage / f"{frame.name}.motion.png"
            path.write_bytes(encode_png(mask.astype(np.uint8) * 255, path))
            if (i + 1) % PROGRESS_EVERY == 0:
                print(f"motion masks: {i + 1}/{len(seq)} frames", file=sys.stderr)
        check_motion(cover, settings, request.data)
    print(f"wrote {len(seq)} motion masks and background.png to {request.out} (median "
          f"{np.median(cover):.1%} of the image moving; links that never move are not in them)",
          file=out)
    return len(seq)


def cmd_masks(args: argparse.Namespace) -> int:
    run_masks(request_from(MasksRequest, args))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """The `dream masks` parser."""
    p = add_command(sub, "masks", cmd_masks,
                    "motion masks of a fixed-camera recording (the pixels that differ from a "
                    "background model: the moving arm)")
    p.add_argument("--data", required=True, help=DATA_FILE_HELP)
    p.add_argument("--out", required=True,
                   help="folder for background.png and NNNNNN.motion.png (0 / 255)")
    add_intrinsics_args(p)

