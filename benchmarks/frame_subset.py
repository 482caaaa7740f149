"""The frames of a rendered set that show one randomisation draw, as folders to evaluate.

Redraws each frame's randomisation from the set's `_synth.json` (robot, seed, recipe) and keeps
the frames where the draw is present: `loose_parts` (loose parts of a robot), `other_robot` (a
whole second robot), `held` (an assembly at the flange) or `hidden_hand`. Writes `OUT` as links
to those frames' files (and the set's own `_*.json` files), and with
`--same-frames-of OTHER OTHER_OUT` the same frame indices of another set (e.g. one rendered from
the same seed without the draw), so that a model's errors can be compared on the same scenes
with and without it:

    python benchmarks/frame_subset.py HELDOUT_LOOSE --with loose_parts --out SUB_LOOSE
        --same-frames-of HELDOUT_RW SUB_RW
    python benchmarks/keypoint_errors.py --checkpoint RUN/last.ckpt --heldout SUB_LOOSE ...
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from dream.errors import DreamError, InputError
from dream.io.common import FRAME_DIGITS
from dream.robot import load_robot
from synth.config import config_from_dict
from synth.frames import FrameMaker
from synth.generate import SYNTH_INFO, done_indices

SET_FILE_PREFIX = "_"   # a set's own files (`_synth.json`, `_camera_settings.json`)

DRAWS = {
    "loose_parts": lambda s: s.other_robot is not None and s.other_robot.links is not None,
    "other_robot": lambda s: s.other_robot is not None and s.other_robot.links is None,
    "held": lambda s: s.held is not None,
    "hidden_hand": lambda s: s.hide_hand,
}


def frame_indices(folder: Path) -> list[int]:
    return sorted(done_indices(folder))


def frames_with(folder: Path, draw: str) -> list[int]:
    """Indices of the frames of `folder` whose scene draw shows `draw` (a key of DRAWS)."""
    try:
        info = json.loads((folder / SYNTH_INFO).read_text())
    except (OSError, ValueError) as exc:
        raise InputError(f"not a rendered set ({exc})", folder / SYNTH_INFO,
                         "give a folder written by `dream synth`") from None
    maker = FrameMaker(load_robot(info["robot"]), config_from_dict(info["config"]), info["seed"])
    try:
        shows = DRAWS[draw]
        return [i for i in frame_indices(folder) if shows(maker.params(i).scene)]
    finally:
        maker.close()


def link_frames(source: Path, indices: list[int], out: Path) -> None:
    """`out` as links to the files of `indices` in `source` and the set's own files
    (`_synth.json`, `_camera_settings.json`)."""
    if out.exists():
        raise InputError("the output folder exists", out, "give a new folder")
    wanted = set(indices)
    out.mkdir(parents=True)
    for path in sorted(source.iterdir()):
        if path.name.startswith(SET_FILE_PREFIX) or (path.name[:FRAME_DIGITS].isdigit()
                                       and int(path.name[:FRAME_DIGITS]) in wanted):
            (out / path.name).symlink_to(path.resolve())


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("source", type=Path, help="a folder written by `dream synth`")
    parser.add_argument("--with", dest="draw", choices=sorted(DRAWS), required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--same-frames-of", nargs=2, type=Path, metavar=("OTHER", "OTHER_OUT"))
    args = parser.parse_args(argv)
    try:
        indices = frames_with(args.source, args.draw)
        link_frames(args.source, indices, args.out)
        print(f"{args.out}: {len(indices)} of {len(frame_indices(args.source))} frames show "
              f"{args.draw}")
        if args.same_frames_of:
            other, other_out = args.same_frames_of
            link_frames(other, indices, other_out)
            print(f"{other_out}: the same frames of {other}")
    except DreamError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
