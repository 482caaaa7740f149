"""`dream demo`: the main job on the embedded default scene (render -> detect -> calibrate ->
compare with the truth -> overlays), or the keypoint-only sample calibrated from its labels."""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import dataclass
from pathlib import Path

from dream.cli.calibrate import CalibrateRequest, run_calibrate
from dream.cli.options import add_command, check_seed, request_from
from dream.errors import InputError
from dream.models import BUNDLED_MODEL

SAMPLE_OUTLIER_FRACTION = 0.1


@dataclass(frozen=True)
class DemoRequest:
    """What `dream demo` does: the options of its command line."""

    out: str | None = None
    seed: int | None = None
    model: str | None = None
    keypoints_only: bool = False

    def __post_init__(self) -> None:
        check_seed(self.seed)


def run_demo(request: DemoRequest) -> dict:
    """The demo of `request` in `request.out` (default: a new temporary folder); returns
    RESULT.json's document."""
    from dream.io import check_output_folder

    if request.out:
        check_output_folder(request.out)
    work = Path(request.out) if request.out else Path(tempfile.mkdtemp(prefix="dream-demo-"))
    if request.keypoints_only:
        return _keypoints_only(work, request.seed)
    return _rendered_scene(work, request.seed, request.model)


def _keypoints_only(work: Path, seed: int | None) -> dict:
    """`--keypoints-only`: the keypoint-only sample calibrated from its labels."""
    from dream.io import write_dream
    from dream.sample import SampleSettings, make_sample

    data = work / "sample"
    spec = SampleSettings(seed=0 if seed is None else seed,
                          outlier_fraction=SAMPLE_OUTLIER_FRACTION)
    print(f"built-in synthetic sample: {spec.num_frames} frames of {spec.robot}, "
          f"{spec.pixel_noise_px:g} px noise, {spec.outlier_fraction:.0%} outlier labels "
          f"-> {data}")
    write_dream(make_sample(spec), data, overwrite=True)
    doc = run_calibrate(CalibrateRequest(data=str(data), out=str(work / "result.json"),
                                         use_labels=True))
    print(f"same as: dream calibrate --data {data} --use-labels --out "
          f"{work / 'result.json'}")
    return doc


def _rendered_scene(work: Path, seed: int | None, model_path: str | None) -> dict:
    """The demo scene rendered (MuJoCo), its keypoints detected with the model (default: the
    bundled one, checked before the rendering) and calibrated."""
    import importlib

    model = Path(model_path) if model_path else BUNDLED_MODEL
    if not model.is_file():
        raise InputError("the keypoint model is missing", model,
                         "reinstall the project (the bundled model ships in dream/models/), "
                         "give --model MODEL.onnx, or run dream demo --keypoints-only")
    from dream.detection import load_keypoint_model, robot_for_model
    from dream.robot import load_robot

    loaded = load_keypoint_model(model)  # a bad model fails here, before the rendering
    demo = importlib.import_module("synth.demo")  # the renderer (MuJoCo), loaded only here
    robot_for_model(load_robot(demo.DEMO_ROBOT), loaded)
    seed = demo.DEMO_SEED if seed is None else seed
    data = work / "scene"
    print(f"rendering the demo scene: {demo.DEMO_FRAMES} frames of {demo.DEMO_ROBOT}, one fixed "
          f"camera, seed {seed} -> {data}")
    demo.render_demo_scene(data, seed=seed)
    doc = run_calibrate(CalibrateRequest(data=str(data), out=str(work / "result.json"),
                                         model=str(model), overlays=str(work / "overlays"),
                                         loaded_model=loaded))
    print(f"overlays in {work / 'overlays'}; same as: dream calibrate --data {data} --model "
          f"{model} --overlays {work / 'overlays'} --out {work / 'result.json'}")
    return doc


def cmd_demo(args: argparse.Namespace) -> int:
    run_demo(request_from(DemoRequest, args))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """The `dream demo` parser."""
    p = add_command(sub, "demo", cmd_demo, "the main job on the embedded default scene: render "
                    "a Panda sequence, detect its keypoints with the bundled model, calibrate, "
                    "compare with the truth, draw overlays")
    p.add_argument("--out", help="working folder (default: a new temporary folder)")
    p.add_argument("--seed", type=int, default=None, help="scene seed (default: the fixed one)")
    p.add_argument("--model", metavar="MODEL.onnx", help="another model than the bundled one")
    p.add_argument("--keypoints-only", action="store_true",
                   help="calibrate the keypoint-only sample from its labels instead (no "
                        "rendering, no network)")
