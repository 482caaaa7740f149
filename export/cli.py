"""`dream export`: registered through the `dream.commands` entry point; imports torch only when run.

    dream export --checkpoint runs/tiny/best.ckpt --out model.onnx

Writes a self-describing ONNX model (see `export.onnx_export`) that `dream calibrate --model`
runs with onnxruntime alone, and its model card beside it (`export.card`).
"""

from __future__ import annotations

import argparse


def cmd_export(args: argparse.Namespace) -> int:
    from pathlib import Path

    from dream.errors import InputError
    from dream.io.atomic import write_bytes_atomic
    from export.card import card_path, model_card

    card = card_path(Path(args.out))
    for path, what in ((Path(args.out), "the model file"), (card, "the model's card")):
        if path.is_file() and not args.overwrite:   # a model in use, the bundled one...
            raise InputError(f"{what} exists", path,
                             "give another --out, or --overwrite to replace it")
    try:
        from export.onnx_export import PARITY_ATOL, export_model  # torch from here on
    except ImportError as exc:
        raise InputError(f"dream export needs torch and onnx ({exc})",
                         fix="install the training extras: pip install -e '.[train]'") from None

    report = export_model(args.checkpoint, args.out, opset=args.opset,
                          peak_overrides=args.peaks or ())
    write_bytes_atomic(card, model_card(report, args.checkpoint).encode())
    meta = report.metadata
    pre = meta.preprocess
    diffs = ", ".join(f"{name} {diff:.2g}" for name, diff in report.max_abs_diff.items())
    print(f"robot {meta.robot}, {len(meta.keypoint_names)} keypoints: "
          f"{', '.join(meta.keypoint_names)}")
    print(f"input {pre.input_width}x{pre.input_height} ({pre.mode}), output stride "
          f"{meta.output_stride}, outputs {', '.join(report.output_names)}")
    print(f"onnxruntime vs torch, max |difference|: {diffs} (limit {PARITY_ATOL:g})")
    print(f"wrote {report.path} and its card {card}")
    return 0


def register(subparsers: argparse._SubParsersAction) -> None:
    """Add the `export` command to `dream`'s sub-commands."""
    help_ = "export a dream train checkpoint to a self-describing ONNX model"
    p = subparsers.add_parser("export", help=help_, description=help_)
    p.add_argument("--checkpoint", required=True, help="a .ckpt written by dream train")
    p.add_argument("--out", required=True, help="the .onnx file to write (and its model card "
                   "beside it, .md: robot, training data and steps, export)")
    p.add_argument("--opset", type=int, default=None,
                   help="ONNX opset that torch's exporter writes, 18 to its version "
                        "converter's newest (25 with onnxscript 0.7); others are refused "
                        "(default: the exporter's own, 20 with torch 2.13)")
    p.add_argument("--peaks", action="append", metavar="NAME=VALUE",
                   help="peak-finder constant written into the model (repeatable), e.g. "
                        "ambiguity_ratio=0.8; the parameters not named keep the training "
                        "config's eval.peaks (default: all of eval.peaks)")
    p.add_argument("--overwrite", action="store_true",
                   help="replace an existing --out file and its card (refused without it)")
    p.set_defaults(func=cmd_export)
