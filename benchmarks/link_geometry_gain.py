"""Does describing a tool the URDF lacks help the image refinement? Rendered sequences of a
Panda carrying a plate at the hand, calibrated with and without the plate in the model
extension.

For each seed: `dream synth --config configs/synth/panda_teleop_like.yaml --model-extension
PLATE` renders a fixed-camera trajectory whose hand carries a box (`--size-m`, at
`--offset-m` along the hand's z axis); `dream calibrate --model MODEL` then solves it from the
detector's keypoints refined by the edges (`--refine edges`) or by the silhouette polish with
the rendered masks, which show the plate (`--refine polish`: `dream calibrate --polish`), once
with the nominal URDF and once with `--model-extension PLATE`. Prints the camera position and
rotation error against the rendered ground truth, per seed and as medians.

    python benchmarks/link_geometry_gain.py [--seeds 3 4 5 6 7] [--frames 60] [--model ONNX]
        [--refine edges|polish]
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

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
os.environ.setdefault("MUJOCO_GL", "egl")

from dream.cli import main  # noqa: E402
from dream.extension import ModelExtension, extension_yaml  # noqa: E402
from dream.metrics import pose_errors  # noqa: E402
from dream.robot.link_geometry import BOX_KIND, LinkGeometry  # noqa: E402

RECIPE = REPO / "configs" / "synth" / "panda_teleop_like.yaml"
REFINEMENTS = {"edges": ["--refine", "edges"], "polish": ["--polish"]}


def _quiet(argv: list[str]) -> int:
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return main(argv)


def _error(result: Path, data: Path) -> tuple[float, float]:
    from dream.io import read_sequence
    from dream.pipeline import truth_poses

    T = np.array(json.loads(result.read_text())["T_cam_base"])
    t, r = pose_errors(T, truth_poses(read_sequence(data))[0])
    return t * 1e3, float(np.rad2deg(r))


def main_() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[3, 4, 5, 6, 7])
    parser.add_argument("--frames", type=int, default=60)
    parser.add_argument("--model", type=Path, default=REPO / "dream" / "models" / "panda_cpu.onnx")
    parser.add_argument("--size-m", type=float, nargs=3, default=[0.30, 0.22, 0.01])
    parser.add_argument("--offset-m", type=float, default=0.14)
    parser.add_argument("--refine", choices=REFINEMENTS, default="edges")
    args = parser.parse_args()
    plate = ModelExtension(link_geometry=(LinkGeometry(
        "panda_hand", BOX_KIND, size_m=tuple(args.size_m),
        position_m=(0.0, 0.0, args.offset_m)),), robot="panda")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        ext = work / "plate.yaml"
        ext.write_text(extension_yaml(plate))
        print(f"{'seed':>4} {'nominal mm':>10} {'deg':>6} {'plate mm':>9} {'deg':>6}")
        for seed in args.seeds:
            data = work / f"set{seed}"
            if _quiet(["synth", "--robot", "panda", "--config", str(RECIPE), "--num",
                       str(args.frames), "--seed", str(seed), "--model-extension", str(ext),
                       "--out", str(data)]) != 0:
                sys.exit(f"dream synth failed for seed {seed}")
            row = []
            for extra in ([], ["--model-extension", str(ext)]):
                out = work / f"r{seed}_{len(extra)}.json"
                if _quiet(["calibrate", "--data", str(data), "--model", str(args.model),
                           *REFINEMENTS[args.refine], "--out", str(out), *extra]) != 0:
                    sys.exit(f"dream calibrate failed for seed {seed}")
                row.extend(_error(out, data))
            rows.append(row)
            print(f"{seed:>4} {row[0]:>10.2f} {row[1]:>6.3f} {row[2]:>9.2f} {row[3]:>6.3f}")
    med = np.median(np.array(rows), axis=0)
    print(f"median: nominal {med[0]:.2f} mm, {med[1]:.3f} deg; with the plate {med[2]:.2f} mm, "
          f"{med[3]:.3f} deg; better in {sum(r[2] < r[0] for r in rows)} of {len(rows)}")


if __name__ == "__main__":
    main_()
