"""Does `dream diagnose` name a tool the URDF lacks? Rendered fixed-camera trajectories of a Panda
whose hand carries a plate and whose joint log is held, and the same without either.

For each seed, `dream synth --config configs/synth/panda_teleop_like.yaml --model-extension`
renders 60 frames with a 0.30 x 0.22 x 0.01 m plate 0.14 m along the hand's z axis and joint
readings held for 0.2 s, then the same seed with no extension (null); `dream diagnose` reads
each from its labels (`--use-labels`) or from a model's detections (`--model`). Prints the
verdict, the box found (link, size, centre) and the camera position error against the rendered
ground truth before and after the diagnosis's extension; where a plate is not named, why not
and the points each rigid group kept (diagnosis.json's `attached_search`).

With `--polish`, each plate sequence is also calibrated from the same observations with the
silhouette polish against its rendered masks (`dream calibrate --polish`), which show the plate:
with the nominal model, with the diagnosis's extended_model.yaml, and with that extension
without its `link_geometry`, so the box's own share of the gain is seen.

    python benchmarks/attached_geometry.py [--seeds 8 9 10 11 12 13] [--model ONNX] [--polish]
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import io
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
os.environ.setdefault("MUJOCO_GL", "egl")

from dream.cli import main  # noqa: E402
from dream.extension import (  # noqa: E402
    HeldReadings,
    ModelExtension,
    extension_yaml,
    read_extension,
)
from dream.metrics import pose_errors  # noqa: E402
from dream.robot.link_geometry import BOX_KIND, LinkGeometry  # noqa: E402

RECIPE = REPO / "configs" / "synth" / "panda_teleop_like.yaml"
PLATE = LinkGeometry("panda_hand", BOX_KIND, size_m=(0.30, 0.22, 0.01),
                     position_m=(0.0, 0.0, 0.14))
HELD = HeldReadings(0.2)


def _quiet(argv: list[str]) -> int:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return main(argv)


def _diagnose(data: Path, report: Path, model: Path | None) -> dict:
    source = ["--model", str(model)] if model else ["--use-labels"]
    if _quiet(["diagnose", "--data", str(data), *source, "--out", str(report)]) != 0:
        sys.exit(f"dream diagnose failed on {data}")
    return json.loads((report / "diagnosis.json").read_text())


def _polished_mm(data: Path, out: Path, source: list[str], extension: Path | None) -> float:
    """Camera position error (mm) of `dream calibrate --polish` on `data` (its masks)."""
    from dream.io import read_sequence
    from dream.pipeline import truth_poses

    extra = ["--model-extension", str(extension)] if extension else []
    if _quiet(["calibrate", "--data", str(data), *source, "--polish", "--out", str(out),
               *extra]) != 0:
        sys.exit(f"dream calibrate --polish failed on {data}")
    T = np.array(json.loads(out.read_text())["T_cam_base"])
    return pose_errors(T, truth_poses(read_sequence(data))[0])[0] * 1e3


def _polish_columns(data: Path, report: Path, source: list[str]) -> str:
    """The polish's camera position errors: nominal, diagnosed extension, and the extension
    without its link_geometry."""
    found = report / "extended_model.yaml"
    no_box = report / "without_box.yaml"
    no_box.write_text(extension_yaml(dataclasses.replace(read_extension(found),
                                                         link_geometry=())))
    errors = [_polished_mm(data, report / f"p{i}.json", source, ext)
              for i, ext in enumerate((None, found, no_box))]
    return "  polish mm: nominal {:.1f}, extension {:.1f}, without its box {:.1f}".format(*errors)


def _row(seed: int, kind: str, doc: dict) -> str:
    found = (doc.get("image_findings") or {}).get("link_geometry") or {}
    box = "-"
    for link, params in found.items():
        size = "x".join(f"{100 * s:.0f}" for s in params["size_m"])
        centre = ",".join(f"{100 * c:.0f}" for c in params["position_m"])
        box = f"{link} {size} cm at ({centre}) cm"
    truth = doc.get("truth") or {}
    before = truth.get("before", {}).get("translation_error_m", float("nan")) * 1e3
    after = truth.get("after", {}).get("translation_error_m", float("nan")) * 1e3
    verdict = ", ".join(doc["verdict"]) or "none"
    return f"{seed:>4} {kind:>5}  {verdict:<36} {box:<42} {before:8.1f} {after:8.1f}"


def _not_named(doc: dict) -> str:
    """Why a plate was not named (empty where it was): the carving's reason and counts."""
    search = doc.get("attached_search") or {}
    if not search or search.get("named"):
        return ""
    counts = ", ".join(f"{k} {n}" for k, n in (search.get("carved_points_per_link") or {}).items())
    return f"\n      not named: {search['reason']}" + (f" ({counts})" if counts else "")


def run() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[8, 9, 10, 11, 12, 13])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--model", type=Path, help="detect keypoints with this ONNX model")
    parser.add_argument("--polish", action="store_true",
                        help="also calibrate each plate sequence with the silhouette polish")
    args = parser.parse_args()
    source = ["--model", str(args.model)] if args.model else ["--use-labels"]
    hidden = ModelExtension(held_readings=HELD, link_geometry=(PLATE,), robot="panda")
    named = {"plate": 0, "null": 0}
    print(f"{'seed':>4} {'set':>5}  {'verdict':<36} {'box found':<42} {'mm before':>8} "
          f"{'after':>8}")
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        ext = work / "hidden.yaml"
        ext.write_text(extension_yaml(hidden))
        for seed in args.seeds:
            for kind, extra in (("plate", ["--model-extension", str(ext)]), ("null", [])):
                data = work / f"{kind}{seed}"
                if _quiet(["synth", "--robot", "panda", "--config", str(RECIPE), "--num",
                           str(args.frames), "--seed", str(seed), "--out", str(data),
                           *extra]) != 0:
                    sys.exit(f"dream synth failed for seed {seed}")
                doc = _diagnose(data, work / f"r_{kind}{seed}", args.model)
                named[kind] += "link_geometry" in doc["verdict"]
                row = _row(seed, kind, doc)
                if args.polish and kind == "plate":
                    row += _polish_columns(data, work / f"r_{kind}{seed}", source)
                print(row + (_not_named(doc) if kind == "plate" else ""), flush=True)
    n = len(args.seeds)
    print(f"link_geometry named: {named['plate']} of {n} plate sequences, {named['null']} of "
          f"{n} null sequences")


if __name__ == "__main__":
    run()
