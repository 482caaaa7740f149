"""`dream adapt`: registered through the `dream.commands` entry point; imports torch only when
run (`train.adapt`).

    dream adapt --data REC --result RESULT.json --model M.onnx --out ADAPTED.onnx \\
        [--holdout-frames START:STOP] [--minutes 20] [--zoom] [--overwrite]
"""

from __future__ import annotations

import argparse
import logging
import sys


def cmd_adapt(args: argparse.Namespace) -> int:
    from train.adapt import AdaptRequest

    recipe = {} if args.config is None else {"config": args.config}
    request = AdaptRequest(data=args.data, result=args.result, model=args.model, out=args.out,
                           **recipe, holdout_frames=args.holdout_frames,
                           minutes=args.minutes, renders=args.renders,
                           scene_renders=args.scene_renders, seed=args.seed,
                           zoom=args.zoom, overrides=tuple(args.set or ()),
                           overwrite=args.overwrite)
    logging.getLogger("train").setLevel(logging.INFO)
    from train.adapt import run_adapt

    report = run_adapt(request, sys.stdout,
                       progress=lambda line: print(f"adapt: {line}", file=sys.stderr))
    for line in report["lines"]:
        print(line)
    print(f"wrote {args.out} and its card {args.out.rsplit('.', 1)[0]}.md "
          f"({report['minutes']:.1f} minutes)")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `adapt` command to `dream`'s sub-commands."""
    help_ = ("fine-tune a keypoint model on a calibrated recording of your own scene (labels "
             "from the result's extrinsic and the joint readings)")
    p = subparsers.add_parser("adapt", help=help_, description=help_)
    p.add_argument("--data", required=True, help="the recording the result was calibrated from")
    p.add_argument("--result", required=True, help="its RESULT.json (all frames, not "
                   "unreliable): the extrinsic that labels the frames")
    p.add_argument("--model", required=True, help="the ONNX model to start from")
    p.add_argument("--out", required=True, help="the adapted .onnx (and its card, .md)")
    p.add_argument("--config",
                   help="the recipe the model was trained with (default: the bundled model's, "
                        "configs/train/panda_cpu.yaml of the repository dream is installed "
                        "from)")
    p.add_argument("--holdout-frames", metavar="START:STOP",
                   help="frames left out of adapting and scored after it (default: the last "
                        "third)")
    p.add_argument("--minutes", type=float, default=20.0,
                   help="training time budget (default: %(default)s)")
    p.add_argument("--renders", type=int, default=1000,
                   help="renders of the robot mixed in so it does not forget (default: "
                        "%(default)s)")
    p.add_argument("--scene-renders", type=int, default=1000,
                   help="renders of the robot in random poses in the recording's own scene (its "
                        "camera at the result's extrinsic, its background) (default: "
                        "%(default)s; 0: none)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the renders and the training (default: %(default)s)")
    p.add_argument("--zoom", action="store_true",
                   help="train on inputs cut around the keypoints too, and detect a second time "
                        "on such a cut of each frame (for an arm that fills a small part of the "
                        "image; twice the network time)")
    p.add_argument("--set", action="append", metavar="KEY=VALUE",
                   help="override a recipe key, e.g. data.batch_size=8")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --out model and its card")
    p.set_defaults(func=cmd_adapt)
