"""Does `dream diagnose` name a tool the URDF lacks? Rendered fixed-camera trajectories of a Panda
whose hand carries a plate and whose joint log is held, and the same without either.

For each seed, `dream synth --config configs/synth/panda_teleop_like.yaml --model-extension`
renders 60 frames with a 0.30 x 0.22 x 0.01 m plate 0.14 m along the hand's z axis and joint
readings held for 0.2 s, then the same seed with no extension (null); `dream diagnose` reads
each from its labels (`--use-labels`) or from a model's detections (`--model`). Prints the
verdict, the box found (link, size, centre) and the camera position error against the rendered
ground truth before and after the diagnosis's extension.

    python benchmarks/attached_geometry.py [--seeds 8 9 10 11 12 13] [--model ONNX]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
os.environ.setdefault("MUJOCO_GL", "egl")

from dream.cli import main  # noqa: E402
from dream.extension import HeldReadings, ModelExtension, extension_yaml  # noqa: E402
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


def run() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[8, 9, 10, 11, 12, 13])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--model", type=Path, help="detect keypoints with this ONNX model")
    args = parser.parse_args()
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
                print(_row(seed, kind, doc))
    n = len(args.seeds)
    print(f"link_geometry named: {named['plate']} of {n} plate sequences, {named['null']} of "
          f"{n} null sequences")


if __name__ == "__main__":
    run()
