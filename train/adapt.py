"""`dream adapt`: teach a keypoint network the user's own scene from a calibrated recording.

A fixed camera's calibrated extrinsic and the joint readings (as the calibration used them:
interpolated where the log was held) label every frame for free: forward kinematics puts each
keypoint in the base frame, the extrinsic projects it. Those pseudo-labels (keypoints outside
the image left unlabelled) teach the network on the recording's own frames, mixed with renders
of the same robot so it does not forget and with renders of the robot in the recording's own
scene (`train.scene_mix`: its camera at the calibrated extrinsic, its background, random joint
configurations), starting from the given ONNX model's weights (`trainer.init_from`); the result
is exported with the same interface and a model card.

Frames held out of teaching (`--holdout-frames`, default the last third by time) are then
detected by the model before and after adapting and scored against the same pseudo-labels:
keypoint medians and PCK@5 px, the share found, and how far each frame's own keypoint
extrinsic lies from the calibrated one. A result the calibration called `unreliable` teaches
nothing (it is refused); the data's reference or labels are never read.
"""

from __future__ import annotations

import dataclasses
import logging
import shutil
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dream.errors import InputError
from dream.robot.identity import same_robot_name
from dream.sequence import Sequence

log = logging.getLogger(__name__)

RESULT_OBJECTS = ("quality", "joint_readings", "data", "start", "distortion", "focal",
                  "principal")
CAMERA_RTOL = 1e-6          # the result's record of the camera against the recording's
HOLDOUT_SHARE = 3           # default: the last 1/3 of the frames by time are held out
PCK_PX = 5.0                # PCK threshold of the report, pixels
# the bundled model's recipe, in the repository dream is installed from (`pip install -e`)
BUNDLED_RECIPE = Path(__file__).resolve().parents[1] / "configs" / "train" / "panda_cpu.yaml"
FINE_TUNE_LR = 5e-4         # a quarter of the recipe's: the network already works on renders
SCORING_MINUTES = 1.5       # kept from --minutes for the export and the held-out scoring
MIN_TRAINING_MINUTES = 0.5
ZOOM_SHARE = 0.5            # --zoom: the share of training samples cut around their keypoints
UNRELIABLE = "unreliable"


@dataclass(frozen=True)
class AdaptRequest:
    """What `dream adapt` does: the options of its command line."""

    data: str
    result: str
    model: str
    out: str
    config: str = str(BUNDLED_RECIPE)
    holdout_frames: str | None = None
    minutes: float = 20.0
    renders: int = 1000
    scene_renders: int = 1000
    seed: int = 0
    zoom: bool = False
    overrides: tuple[str, ...] = ()
    overwrite: bool = False

    def __post_init__(self) -> None:
        least = SCORING_MINUTES + MIN_TRAINING_MINUTES
        if not (self.minutes >= least and np.isfinite(self.minutes)):
            raise InputError(f"--minutes {self.minutes} leaves no time to train: the export and "
                             f"the held-out scoring take {SCORING_MINUTES:g}, training at least "
                             f"{MIN_TRAINING_MINUTES:g}, and the labels and renders come first",
                             fix=f"give more than {least:g}, e.g. 20")
        if self.holdout_frames is not None:      # its form now, its range once read
            from dream.cli.options import parse_frame_bounds

            parse_frame_bounds(self.holdout_frames, "--holdout-frames")
        for flag, count in (("--renders", self.renders), ("--scene-renders",
                                                           self.scene_renders)):
            if count < 0:
                raise InputError(f"{flag} {count} must be >= 0", fix="e.g. 1000 (0: none)")
        if Path(self.out).suffix.lower() != ".onnx":
            raise InputError("the adapted model must be a .onnx file", self.out,
                             "name it e.g. adapted.onnx")


def holdout_range(text: str | None, count: int) -> range:
    """The held-out frames of `--holdout-frames START:STOP` (indices, STOP excluded), default
    the last third.

    >>> holdout_range(None, 9), holdout_range("2:5", 9)
    (range(6, 9), range(2, 5))
    """
    if text is None:
        return range(count - count // HOLDOUT_SHARE, count)
    from dream.cli.options import parse_frame_range

    return parse_frame_range(text, count, "--holdout-frames")


def check_teacher(doc: dict, path: str) -> None:
    """A result that may teach: all frames of a fixed camera, not `unreliable`."""
    for key in RESULT_OBJECTS:
        if doc.get(key) is not None and not isinstance(doc[key], dict):
            raise InputError(f"its '{key}' is not an object: not a RESULT.json of dream "
                             "calibrate", path, "give the RESULT.json dream calibrate wrote")
    verdict = (doc.get("quality") or {}).get("verdict")
    if verdict == UNRELIABLE:
        raise InputError("is `unreliable` and cannot teach a network", path,
                         "calibrate again (a camera guess, a mark, more arm motion) until the "
                         "verdict is good or check")
    if doc.get("frames_mode", "all") != "all":
        raise InputError("is a per-frame result (--frames each); adapting needs the one "
                         "extrinsic of a fixed camera", path, "calibrate with --frames all")


def pseudo_labels(sequence: Sequence, robot, T_cam_base: np.ndarray) -> np.ndarray:
    """(F, K, 2) each frame's keypoints projected at `T_cam_base` from its joint readings; NaN
    where a keypoint falls outside the image or behind the camera."""
    from dream.camera import project
    from dream.pipeline import joints_in_robot_order
    from dream.transforms import transform_points

    P_base = robot.forward_kinematics(joints_in_robot_order(sequence, robot))
    uv = project(sequence.camera, transform_points(np.asarray(T_cam_base), P_base))
    inside = sequence.camera.in_image(uv) & np.all(np.isfinite(uv), axis=-1)
    return np.where(inside[..., None], uv, np.nan)


def teaching_set(sequence: Sequence, keypoints: tuple[str, ...], uv: np.ndarray,
                 frames: np.ndarray, out: Path) -> Path:
    """A DREAM-layout copy of `frames` with the pseudo-labels `uv` as their labels (and no
    ground truth or masks), written to `out`."""
    from dream.io import write_dream

    chosen = tuple(dataclasses.replace(sequence.frames[int(i)], uv_labels=uv[int(i)],
                                       P_cam_labels=None, T_cam_base_true=None, mask_path=None)
                   for i in frames)
    taught = dataclasses.replace(sequence, frames=chosen, keypoint_names=keypoints,
                                 T_cam_base_reference=None)
    return write_dream(taught, out)


def render_mix(robot: str, keypoints: tuple[str, ...], count: int, out: Path,
               seed: int) -> Path:
    """`count` domain-randomised renders of `robot` (its keypoints named as the model's)."""
    from synth.config import config_from_dict
    from synth.generate import SynthJob, generate

    generate(SynthJob(robot=robot, out_dir=out, num_frames=count, config=config_from_dict(None),
                      seed=seed, keypoints=keypoints), on_progress=lambda done: None)
    return out


def teacher(request: AdaptRequest, out) -> tuple:
    """The recording as the calibration used it (joint readings interpolated where it did, the
    frames after a held log's last update left out), the result's extrinsic, the model, the
    result's document and the recording's own frame count."""
    from dream.cli.options import joint_readings
    from dream.io import read_sequence
    from dream.provenance import check_same_data
    from dream.result import read_result
    from export.runner import OnnxKeypointModel

    doc = read_result(request.result)
    check_teacher(doc, request.result)
    seq = read_sequence(request.data)
    check_same_data(doc, seq, request.data, request.result, part_ok=True)
    seq = _teachers_camera(doc, seq, request)
    recorded = len(seq)
    interpolated = bool((doc.get("joint_readings") or {}).get("interpolated"))
    seq, _ = joint_readings(seq, interpolated, out)
    model = OnnxKeypointModel(request.model)
    return seq, np.asarray(doc["T_cam_base"], float), model, doc, recorded


def _teachers_camera(doc: dict, seq: Sequence, request: AdaptRequest) -> Sequence:
    """`seq` through the camera its extrinsic was solved with: refused where the result was
    made for another robot or through other intrinsics than the recording's own; with the
    intrinsics the calibration adopted (`dream.result.adopted_intrinsics`)."""
    from dream.provenance import camera_record
    from dream.result import adopted_intrinsics

    robot = doc.get("robot")
    if robot and seq.robot and not same_robot_name(robot, seq.robot):
        raise InputError(f"was calibrated for the robot {robot!r}, --data {request.data} "
                         f"records {seq.robot!r}", request.result,
                         "give the RESULT.json of this recording's calibration")
    used = (doc.get("data") or {}).get("camera")
    own = camera_record(seq.camera)
    if isinstance(used, dict) and any(
            not np.isclose(float(used.get(k, np.nan)), float(own[k]), rtol=CAMERA_RTOL)
            for k in ("width", "height", "fx", "fy", "cx", "cy")):
        raise InputError(f"was calibrated through another camera ({_camera_words(used)}) "
                         f"than --data {request.data} holds ({_camera_words(own)})",
                         request.result, "calibrate the recording with its own intrinsics "
                         "(or write the intrinsics used into it), then adapt")
    fitted = adopted_intrinsics(doc)
    if fitted:
        seq = seq.with_fixed_camera(dataclasses.replace(seq.camera, **fitted))
    return seq


def _camera_words(record: dict) -> str:
    return (f"{record.get('width')}x{record.get('height')}, fx {record.get('fx')}, "
            f"fy {record.get('fy')}")


def training_config(request: AdaptRequest, folders: list[str], repeat: int, minutes: float):
    """The recipe with the teaching folder (`repeat` times, to weigh the real frames as much
    as the renders) and the renders as data, the model's weights as the start, the fine-tune
    learning rate and the training's time budget `minutes`."""
    from train.config import load_config

    if not Path(request.config).is_file():
        raise InputError("the recipe the model was trained with is not here", request.config,
                         "give --config RECIPE.yaml (the bundled model's is "
                         "configs/train/panda_cpu.yaml of the repository)")
    train = ",".join([folders[0]] * repeat + folders[1:])
    return load_config(request.config, (
        f"data.train=[{train}]", f"trainer.init_from={request.model}",
        f"trainer.time_budget_minutes={minutes}", f"optim.lr={FINE_TUNE_LR}",
        f"trainer.seed={request.seed}", "trainer.checkpoint_every_n_steps=0",
        *([f"augment.zoom_p={ZOOM_SHARE}"] if request.zoom else []), *request.overrides))


def training_minutes(total: float, spent_s: float) -> float:
    """The training's share of the `--minutes` budget: what the labels and renders left,
    less the export and scoring's; at least `MIN_TRAINING_MINUTES`, so that a budget the
    renders overran still ends in an adapted model (a warning says by how much it runs over).

    >>> training_minutes(20.0, 60.0)
    17.5
    >>> training_minutes(2.5, 60.0)
    0.5
    """
    left = total - spent_s / 60 - SCORING_MINUTES
    if left < MIN_TRAINING_MINUTES:
        log.warning("the labels and renders took %.1f of the %g minutes: training %g minutes, "
                    "%.2f beyond the budget (give more --minutes, or fewer --renders and "
                    "--scene-renders)", spent_s / 60, total, MIN_TRAINING_MINUTES,
                    MIN_TRAINING_MINUTES - left)
        return MIN_TRAINING_MINUTES
    return left


def run_adapt(request: AdaptRequest, out, progress: Callable[[str], None] | None = None
              ) -> dict:
    """`dream adapt` (module doc): returns the held-out report before and after, also written
    beside the model as its card (`ADAPTED.md`)."""
    from dream.io import check_output_file, outermost_missing, write_files_atomic
    from export.card import card_path
    from train.adapt_report import worse_lines

    say = progress or (lambda line: None)
    target = check_output_file(request.out, parents_made=True)
    if target.resolve() == Path(request.model).resolve():
        raise InputError("--out names the model being adapted, which it would replace",
                         target, "give --out a file of its own, e.g. adapted.onnx")
    for path in (target, card_path(target)):
        if path.exists() and not request.overwrite:
            raise InputError("exists (dream adapt --out writes it)", path,
                             "give another --out, or --overwrite to replace it")
    if not Path(request.model).is_file():                 # before the recording is read
        raise InputError("no such model file", request.model,
                         "give --model the ONNX model to adapt (dream export writes one)")
    recipe = training_config(request, [str(target.parent)], 1, request.minutes)  # now
    seq, T, model, doc, recorded = teacher(request, out)
    if model.zoom is not None and not request.zoom:
        request = dataclasses.replace(request, zoom=True)
        recipe = training_config(request, [str(target.parent)], 1, request.minutes)
        will = ("is trained to as well" if recipe.augment.zoom_settings() is not None else
                "will not (augment.zoom_p is 0)")
        say(f"the model looks a second time at the keypoints' region (its zoom); the adapted "
            f"model {will}")
    peaks = peak_change(model.metadata.peak_params, recipe.eval.peaks)
    created = outermost_missing(target.parent)
    try:
        report, model_bytes = _adapt(request, target, seq, T, model, doc, recorded, say,
                                     peaks)
        report["lines"] += worse_lines(report["before"], report["after"], request.model)
        write_files_atomic({target: model_bytes,            # the model and its card together
                            card_path(target): card_text(target, report, doc)})
    except BaseException:
        if created is not None and not any(p.is_file() for p in created.rglob("*")):
            shutil.rmtree(created, ignore_errors=True)     # the folder made for --out, empty
        raise
    return report


def peak_change(model_peaks, recipe_peaks) -> str:
    """In words, how the peak finder's constants the adapted model is exported with (the
    recipe's `eval.peaks`) differ from the model's it starts from; "" where they agree or the
    model has none."""
    if model_peaks is None or model_peaks == recipe_peaks:
        return ""
    changed = [f"{k} {getattr(model_peaks, k):g} -> {v:g}"
               for k, v in dataclasses.asdict(recipe_peaks).items()
               if getattr(model_peaks, k) != v]
    return ("peak finder: the recipe's eval.peaks are written into the adapted model, not the "
            f"input model's ({', '.join(changed)}; --set eval.peaks.NAME=VALUE keeps the input "
            "model's value)")


def _adapt(request: AdaptRequest, target: Path, seq: Sequence, T: np.ndarray, model, doc: dict,
           recorded: int, say: Callable[[str], None], peaks: str) -> tuple[dict, bytes]:
    """The labels, renders, fine-tune, export and held-out scores of `run_adapt` (`peaks`:
    `peak_change`'s words, said once the inputs are checked): the report and the adapted
    model's bytes, not yet placed at `target`."""
    from dream.pipeline import robot_for
    from export.onnx_export import export_model
    from train.adapt_report import holdout_report, report_lines
    from train.run import run_training
    from train.scene_mix import render_scene_mix

    made_from = (doc.get("data") or {}).get("num_frames", recorded)
    if not isinstance(made_from, int) or made_from > recorded:
        raise InputError(f"was calibrated on {made_from} frames, more than the {recorded} of "
                         f"--data {request.data}", request.result,
                         "give --data the recording the result was made from")
    if made_from != recorded:
        say(f"the result was calibrated on {made_from} of the recording's {recorded} frames; "
            "its extrinsic labels them all (a fixed camera)")
    robot = robot_for(seq, None, tuple(model.keypoint_names))
    held = holdout_range(request.holdout_frames, len(seq))
    uv = pseudo_labels(seq, robot, T)
    teach = np.array([i for i in range(len(seq)) if i not in held])
    if not len(teach):
        raise InputError(f"--holdout-frames {held.start}:{held.stop} holds out all "
                         f"{len(seq)} frames: none is left to teach",
                         fix=f"hold out fewer, e.g. {len(seq) - len(seq) // HOLDOUT_SHARE}:"
                         f"{len(seq)} (the default: the last third)")
    if not len(held):
        raise InputError(f"{len(seq)} frames are too few to hold some out and score them",
                         request.data, f"record at least {HOLDOUT_SHARE} frames, or give "
                         "--holdout-frames START:STOP")
    if peaks:
        say(peaks)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the folder ({exc.strerror})", target.parent,
                         "choose a writable location") from None
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="dream-adapt-", dir=target.parent) as work:
        work = Path(work)
        folders = [str(teaching_set(seq, robot.keypoint_names, uv, teach, work / "teach"))]
        say(f"pseudo-labels of {len(teach)} frames (frames {held.start}-{held.stop - 1} held "
            f"out); rendering {request.renders} frames of {robot.name} to mix in")
        if request.renders:
            folders.append(str(render_mix(seq.robot or robot.name, robot.keypoint_names,
                                          request.renders, work / "renders", request.seed)))
        if request.scene_renders:
            say(f"rendering {request.scene_renders} frames of {robot.name} in the recording's "
                "own scene (its camera at the result's extrinsic, its background)")
            folders.append(str(render_scene_mix(seq, robot, seq.robot or robot.name, T, teach,
                                                request.scene_renders, work / "scene",
                                                request.seed)))
        # the real frames weigh as much as the renders of both kinds together
        repeat = max(1, round((request.renders + request.scene_renders) / max(len(teach), 1)))
        minutes = training_minutes(request.minutes, time.perf_counter() - start)
        say(f"fine-tuning {request.model} for {minutes:.1f} minutes")
        trained = time.perf_counter()
        run = run_training(training_config(request, folders, repeat, minutes), work / "run")
        trained = (time.perf_counter() - trained) / 60
        adapted = export_model(run.best_checkpoint, work / target.name).path
        minutes = (time.perf_counter() - start) / 60
        say("scoring the held-out frames before and after")
        held_seq = dataclasses.replace(seq, frames=tuple(seq.frames[i] for i in held))
        before = holdout_report(held_seq, robot, request.model, uv[list(held)], T)
        after = holdout_report(held_seq, robot, str(adapted), uv[list(held)], T)
        model_bytes = adapted.read_bytes()
    return {"data": _absolute(request.data), "result": _absolute(request.result),
            "model": _absolute(request.model), "recipe": _absolute(request.config),
            "teaching_frames": len(teach), "holdout": [held.start, held.stop],
            "renders": request.renders, "scene_renders": request.scene_renders,
            "seed": request.seed, "zoom": run.config.augment.zoom_settings() is not None,
            "overrides": list(request.overrides),
            "peaks": peaks,
            "steps": run.config.trainer.steps_trained, "training_minutes": trained,
            "minutes": minutes, "before": before, "after": after,
            "lines": report_lines(before, after)}, model_bytes


ZOOM_WORDS = (" Zoom: trained on inputs cut around the keypoints too; detection looks a "
              "second time at each frame's keypoints (`dream.zoom`).")


def _absolute(path: str) -> str:
    return str(Path(path).resolve())


def card_text(target: Path, report: dict, doc: dict) -> bytes:
    """The adapted model's card: what it was adapted on and the held-out figures."""
    verdict = (doc.get("quality") or {}).get("verdict")
    overrides = ", ".join(f"`{o}`" for o in report["overrides"]) or "none"
    peaks = report["peaks"] or "Peak finder: the recipe's eval.peaks."
    text = "\n".join([
        f"# {target.name}: adapted to one recording",
        "",
        f"Fine-tuned from `{report['model']}` ({report['steps']} steps, "
        f"{report['training_minutes']:.1f} minutes of training, {report['minutes']:.1f} in "
        f"all) on {report['teaching_frames']} frames of `{report['data']}`, labelled by the "
        f"calibrated extrinsic of `{report['result']}` (verdict `{verdict}`) and the joint "
        f"readings, mixed with {report['renders']} renders of the robot and "
        f"{report['scene_renders']} of it in the recording's scene (its camera, its "
        f"background). Recipe `{report['recipe']}`, overrides {overrides}, seed "
        f"{report['seed']}. {peaks}{ZOOM_WORDS if report.get('zoom') else ''}",
        "",
        f"Frames {report['holdout'][0]}-{report['holdout'][1] - 1} were held out; on them, "
        "against the same labels (before -> after):",
        "", "```", *report["lines"], "```", ""])
    return text.encode()
