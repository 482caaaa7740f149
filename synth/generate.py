"""Writing a synthetic dataset in the DREAM layout, in parallel, resumable.

A frame is complete when its `NNNNNN.json` exists: images are written first, the JSON last,
each atomically (temporary name + rename). A run that is killed leaves only complete frames
(and stray temporaries, removed on resume); running the same command again renders the missing
frames. Every frame depends only on (seed, frame index), so the result equals an uninterrupted
run. `_synth.json` records what was asked (robot, keypoints, seed, recipe, and the model
extension when one is given); resuming with other settings is refused.
"""

from __future__ import annotations

import json
import logging
import multiprocessing as mp
import os
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from dream import __version__
from dream.camera import CameraIntrinsics
from dream.errors import DreamError, InputError
from dream.extension import ModelExtension
from dream.io import (
    is_temporary,
    outermost_missing,
    remove_temporaries,
    write_bytes_atomic,
    write_json_atomic,
)
from dream.io.common import FRAME_DIGITS, frame_name
from dream.io.dream_layout.camera_settings import camera_settings_json
from dream.io.dream_layout.frame_record import frame_json
from dream.io.dream_layout.names import (
    CAMERA_SETTINGS,
    DEPTH_SUFFIX,
    FRAME_PART,
    JPEG_RGB_SUFFIX,
    JSON_SUFFIX,
    KEYPOINTS_KEY,
    MASK_SUFFIX,
    OBJECTS_KEY,
    PNG_RGB_SUFFIX,
)
from dream.io.fields import os_reason
from dream.robot import load_robot
from dream.sequence import Frame, Sequence
from synth.config import SynthConfig
from synth.extension import check_extension, normalised
from synth.nominal import nominal_camera
from synth.rendered import RenderedFrame

log = logging.getLogger(__name__)

SYNTH_INFO = "_synth.json"
DEPTH_UNIT_M = 1e-3           # depth PNGs store millimetres in uint16
CHUNK_FRAMES = 8              # frames handed to a worker at a time
PNG_COMPRESSION = 1           # zlib level: fast, files about 20 % larger than the default
RGB_SUFFIX = {"png": PNG_RGB_SUFFIX, "jpg": JPEG_RGB_SUFFIX}  # by output.image_format


@dataclass(frozen=True)
class SynthJob:
    """What to generate. `robot` is a built-in name or a URDF path (then `keypoints` needed).
    `extension`: the model extension whose world is rendered (`synth.extension`); None or an
    empty one renders the nominal world."""

    robot: str
    out_dir: Path
    num_frames: int
    config: SynthConfig
    seed: int = 0
    keypoints: tuple[str, ...] | None = None
    workers: int = 1
    extension: ModelExtension | None = None

    def __post_init__(self) -> None:
        if self.num_frames < 1:
            raise InputError(f"--num must be >= 1, got {self.num_frames}")
        if self.workers < 1:
            raise InputError(f"--workers must be >= 1, got {self.workers}")
        if self.seed < 0:
            raise InputError(f"--seed must be >= 0, got {self.seed}")
        object.__setattr__(self, "out_dir", Path(self.out_dir))
        object.__setattr__(self, "extension", normalised(self.extension))

    def info(self) -> dict[str, Any]:
        """The provenance written to `_synth.json` (compared on resume; num_frames may grow)."""
        info = {"robot": self.robot, "keypoints": list(self.keypoints or []), "seed": self.seed,
                "config": self.config.to_dict(), "generator_version": __version__}
        if self.extension is not None:
            info["model_extension"] = self.extension.to_dict()
        return info


def _encode(ext: str, image: np.ndarray, params: list[int] | None = None) -> bytes:
    ok, buf = cv2.imencode(ext, image, params or [])
    if not ok:
        raise InputError(f"could not encode a {ext} image")
    return buf.tobytes()


def frame_document(job: SynthJob, robot_name: str, joint_names: tuple[str, ...],
                   keypoint_names: tuple[str, ...], frame: RenderedFrame,
                   nominal: CameraIntrinsics) -> dict[str, Any]:
    """The frame JSON of docs/data_format.md#dream-layout plus extensions: per-keypoint
    `in_frame` and `occlusion`, the frame's own intrinsics when they differ from
    `_camera_settings.json`, and its seed."""
    name = frame_name(frame.index)
    one = Sequence(robot=robot_name, camera=nominal, joint_names=joint_names,
                   keypoint_names=keypoint_names,
                   frames=(Frame(name, frame.joints, timestamp=frame.timestamp,
                                 uv_labels=frame.uv, P_cam_labels=frame.P_cam,
                                 T_cam_base_true=frame.T_cam_base, camera=frame.camera),))
    doc = frame_json(one, one.frames[0])
    for kp, in_frame, occlusion in zip(doc[OBJECTS_KEY][0][KEYPOINTS_KEY], frame.in_frame,
                                       frame.occlusion, strict=True):
        kp["in_frame"] = bool(in_frame)
        kp["occlusion"] = occlusion
    doc["synth"] = {"seed": job.seed, "index": frame.index}
    return doc


def write_frame(out_dir: Path, doc: dict[str, Any], frame: RenderedFrame,
                config: SynthConfig) -> None:
    """Images first, the JSON last: the frame exists only once it is complete. Atomic renames
    without fsync: a killed process leaves whole files; a power cut may need a re-run with
    --overwrite."""
    stem = out_dir / frame_name(frame.index)
    bgr = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR)
    if config.output.image_format == "jpg":
        rgb_bytes = _encode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, config.output.jpeg_quality])
    else:
        rgb_bytes = _encode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION])
    write_bytes_atomic(stem.with_name(stem.name + RGB_SUFFIX[config.output.image_format]),
                       rgb_bytes, durable=False)
    ids = frame.link_ids.astype(np.uint8 if frame.link_ids.max(initial=0) < 256 else np.uint16)
    write_bytes_atomic(stem.with_name(stem.name + MASK_SUFFIX),
                       _encode(".png", ids, [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION]),
                       durable=False)
    if frame.depth is not None and config.output.depth:
        mm = np.where(np.isfinite(frame.depth), np.rint(frame.depth / DEPTH_UNIT_M), 0)
        write_bytes_atomic(stem.with_name(stem.name + DEPTH_SUFFIX),
                           _encode(".png", np.clip(mm, 0, 65535).astype(np.uint16)),
                           durable=False)
    write_json_atomic(stem.with_name(stem.name + JSON_SUFFIX), doc, durable=False)


def done_indices(out_dir: Path) -> set[int]:
    """The indices of the complete frames in `out_dir` (those with their `NNNNNN.json`)."""
    return {int(p.name[:FRAME_DIGITS])
            for p in out_dir.glob("[0-9]" * FRAME_DIGITS + JSON_SUFFIX)}


def check_inputs(config: SynthConfig, robot) -> None:
    """Fail before anything is written when the recipe names a missing photo folder, a photo
    that cannot be read, a plate not of the camera's size, an unreadable joint log or an
    unknown other robot."""
    from synth.randomize import load_joint_log
    from synth.textures import list_photos, read_photo, read_plate

    if config.background.photos:
        for path in list_photos(config.background.photos):
            read_photo(path)
    if config.background.plate is not None:
        read_plate(config)
    if config.joints.log:
        load_joint_log(config.joints.log, robot)
    dc = config.distractors
    if max(dc.robot_prob, dc.loose_prob) > 0 and dc.robot_name is not None:
        load_robot(config.distractors.robot_name)   # an unknown name fails here


def check_camera(camera: CameraIntrinsics) -> None:
    """Fail before anything is written when the renderer cannot make `camera`'s image (e.g. a
    distortion that cannot be inverted over the image). `generate` checks the recipe's nominal
    camera with the default `RenderSettings` (`synth.extension.check_extension` a model
    extension's true camera); a frame's randomised intrinsics are checked only when that frame
    is rendered."""
    from synth.lens import plan_lens
    from synth.render import RenderSettings

    options = RenderSettings()
    for oversampling in sorted({1, options.id_oversampling}):
        plan_lens(camera, options.distortion_margin_px, options.max_render_scale, oversampling)


def check_output_path(out: Path) -> None:
    """Refuse an output path that is a file or lies under one (before anything is written)."""
    try:
        if out.exists() and not out.is_dir():
            raise InputError("the output path is a file, not a folder", out,
                             "give --out a new folder, an empty one or one dream synth made")
        for parent in out.parents:
            if parent.exists():
                if not parent.is_dir():
                    raise InputError(f"the output folder cannot be made: {parent} is a file",
                                     out, "give --out a folder that does not lie under a file")
                break
    except OSError as exc:
        raise InputError(f"cannot reach the output folder ({os_reason(exc)})", out,
                         "give --out a folder you can read and write") from None


def discard_unfinished(out: Path, created: Path | None) -> None:
    """After a failed run: when `out` holds no complete frame, remove what this run wrote
    there (settings, partial frames, temporaries) and the folders it created (`created` and
    those below it), so that no folder is left with metadata only. Complete frames are kept
    (a resumed folder, or frames of this run: running again resumes)."""
    if not out.is_dir() or done_indices(out):
        return
    try:
        for path in out.iterdir():
            if path.is_file() and (path.name in (SYNTH_INFO, CAMERA_SETTINGS)
                                   or is_temporary(path) or FRAME_PART.match(path.name)):
                path.unlink()
        if created is not None:
            for folder in (out, *out.parents):
                folder.rmdir()
                if folder == created:
                    break
    except OSError as exc:
        log.warning("could not clean up %s after the failed run: %s", out, os_reason(exc))


# recipe keys of earlier versions that never changed a render (`appearance.reflectance` was
# never read): dropped from a folder's settings before comparing them, so it still resumes
RETIRED_CONFIG_KEYS = (("appearance", "reflectance"),)


# recipe keys added later, filled in with their defaults (rendering as before): old folders resume
ADDED_CONFIG_KEYS = tuple((section, key) for section, keys in (
    ("camera", ("closeup_prob", "closeup_radius_m", "closeup_aim", "T_cam_base")),
    ("joints", ("above_floor",)),
    ("appearance", ("white_plastic_prob", "metal_prob", "hide_hand_prob")),
    ("background", ("plate",)), ("sensor", ("blur_px", "gain_sigma", "noise_std", "exposure_s",
                 "exposure_samples")),
    ("distractors", ("held_parts", "held_checker_prob", "robot_prob", "robot_name",
                     "robot_distance_m", "robot_moves", "loose_prob", "loose_keypoints",
                     "loose_distance_m", "loose_height_m", "cable_prob", "cable_radius_m",
                     "cable_slack", "cable_clip_offset_m", "cable_start_m", "cable_segments",
                     "person_prob", "person_distance_m", "person_shoulder_height_m",
                     "hand_prob")))
    for key in keys)


def without_retired_keys(info: Any) -> Any:
    """A folder's `_synth.json` content without `RETIRED_CONFIG_KEYS` and with the defaults of
    `ADDED_CONFIG_KEYS` where it lacks them (changed in place)."""
    config = info.get("config") if isinstance(info, dict) else None
    if not isinstance(config, dict):
        return info
    for section, key in RETIRED_CONFIG_KEYS:
        if isinstance(config.get(section), dict):
            config[section].pop(key, None)
    defaults = SynthConfig().to_dict()
    for section, key in ADDED_CONFIG_KEYS:
        if isinstance(config.setdefault(section, {}), dict):
            config[section].setdefault(key, defaults[section][key])
    return info


def prepare_output(job: SynthJob, overwrite: bool) -> set[int]:
    """Create or check the output folder; returns the frames already complete."""
    out = job.out_dir
    info_path = out / SYNTH_INFO
    check_output_path(out)
    try:
        existing = out.exists() and any(out.iterdir())
    except OSError as exc:
        raise InputError(f"cannot read the output folder ({os_reason(exc)})", out,
                         "give --out a folder you can read and write") from None
    if existing:
        if not info_path.is_file():
            raise InputError("the output folder exists and is not a dream synth folder", out,
                             "choose an empty or new --out")
        try:
            previous = without_retired_keys(json.loads(info_path.read_text()))
        except (OSError, json.JSONDecodeError) as exc:
            raise InputError(f"unreadable {SYNTH_INFO} ({exc})", info_path) from None
        same = previous == json.loads(json.dumps(job.info()))
        last = max(done_indices(out), default=-1)
        if not overwrite:
            if not same:
                raise InputError("the output folder holds a run with other settings (robot, "
                                 "keypoints, seed, recipe or model extension)", out,
                                 "use the same settings to resume, or --overwrite")
            if last >= job.num_frames:
                raise InputError(f"the output folder already holds frames up to "
                                 f"{frame_name(last)}, beyond --num {job.num_frames}", out,
                                 f"resume with --num {last + 1} or more, use a new --out, or "
                                 "--overwrite")
        elif not same or last >= job.num_frames:
            for p in out.iterdir():
                if p.is_file():
                    p.unlink()
        remove_temporaries(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"cannot create the output folder ({os_reason(exc)})", out,
                         "give --out a folder in a writable location") from None
    write_json_atomic(info_path, job.info())
    return done_indices(out)


# ------------------------------------------------------------------------------ workers

_STATE: dict[str, Any] = {}


def worker_setup(job: SynthJob) -> None:
    """A rendering process's scene, loaded once (`render_chunk` then renders with it)."""
    os.environ.setdefault("MUJOCO_GL", "egl")
    from synth.frames import FrameMaker

    robot = load_robot(job.robot, list(job.keypoints) if job.keypoints else None)
    _STATE["job"] = job
    _STATE["maker"] = FrameMaker(robot, job.config, job.seed, job.extension)
    _STATE["robot"] = robot


def render_chunk(indices: list[int]) -> list[int]:
    """Render `indices`; encoding and writing run on a thread, overlapping the next render
    (both release the GIL). Returns once every frame of the chunk is on disk."""
    job: SynthJob = _STATE["job"]
    maker = _STATE["maker"]
    robot = _STATE["robot"]
    writer: ThreadPoolExecutor = _STATE.setdefault("writer", ThreadPoolExecutor(1))
    pending = []
    for i in indices:
        frame = maker.make(i)
        doc = frame_document(job, robot.name if job.keypoints is None else job.robot,
                             robot.joint_names, robot.keypoint_names, frame, maker.nominal_camera)
        pending.append(writer.submit(write_frame, job.out_dir, doc, frame, job.config))
    for future in pending:
        future.result()
    return indices


def worker_close() -> None:
    writer = _STATE.pop("writer", None)
    if writer is not None:
        writer.shutdown(wait=True)
    maker = _STATE.pop("maker", None)
    if maker is not None:
        maker.close()


def chunks(indices: list[int], size: int = CHUNK_FRAMES) -> Iterator[list[int]]:
    """`indices` in consecutive runs of `size` (what one worker renders at a time)."""
    for start in range(0, len(indices), size):
        yield indices[start:start + size]


Runner = Callable[[list[int], Callable[[int], None]], None]


def generate(job: SynthJob, overwrite: bool = False,
             on_progress: Callable[[int], None] | None = None,
             on_start: Callable[[int, int], None] | None = None,
             runner: Runner | None = None) -> dict[str, Any]:
    """Render the missing frames of `job`; returns counts and the rate.

    Everything that can be checked (robot, recipe inputs, camera, model extension, output
    folder) is checked before the folder is touched. When the run then fails and the folder
    holds no complete frame, what the run wrote is removed again (`discard_unfinished`).

    Args:
        on_progress: called with the number of frames just written, after each chunk.
        on_start: called once as `on_start(total, already)` (frames asked for, frames already
            complete) before rendering starts. The library prints nothing: `dream synth`'s
            progress line is `synth.cli.Progress`.
        runner: renders the frames `runner(todo, on_progress)` elsewhere (`dream batch synth`:
            `worker_setup` and `render_chunk` on an engine's workers); default: `job.workers`
            processes on this machine.
    """
    robot = load_robot(job.robot, list(job.keypoints) if job.keypoints else None)
    check_inputs(job.config, robot)
    if job.extension is not None:
        check_extension(job.extension, robot, job.config, job.num_frames)
    nominal = nominal_camera(job.config, job.seed)
    check_camera(nominal)
    settings = Sequence(robot=robot.name, camera=nominal, joint_names=robot.joint_names,
                        keypoint_names=robot.keypoint_names,
                        frames=(Frame("0", np.zeros(len(robot.joint_names))),))
    settings_doc = camera_settings_json(settings)
    created = outermost_missing(job.out_dir)  # prepare_output checks the path first
    prepared = finished = False
    try:
        done = prepare_output(job, overwrite)
        prepared = True
        write_json_atomic(job.out_dir / CAMERA_SETTINGS, settings_doc)
        todo = [i for i in range(job.num_frames) if i not in done]
        if on_start is not None:
            on_start(job.num_frames, len(done))
        start = time.perf_counter()
        workers = worker_count(job.workers, len(todo)) if runner is None else job.workers
        if workers < job.workers:
            log.info("%d rendering processes instead of %d: %d frames to render, %d cores",
                     workers, job.workers, len(todo), os.cpu_count() or 1)
        report = on_progress or (lambda n: None)
        if todo and runner is not None:
            runner(todo, report)
        elif todo:
            _run(job, todo, report, workers)
        seconds = time.perf_counter() - start
        finished = True
    finally:
        if not finished and (prepared or created is not None):
            discard_unfinished(job.out_dir, created)
    log.info("%s: %d frames rendered, %d already there", job.out_dir, len(todo), len(done))
    return {"frames": job.num_frames, "rendered": len(todo), "skipped": len(done),
            "seconds": seconds, "frames_per_s": len(todo) / seconds if todo else 0.0,
            "workers": workers}


def worker_count(asked: int, frames: int, cores: int | None = None) -> int:
    """The rendering processes to start: `asked`, but no more than the frames to render (in
    chunks of `CHUNK_FRAMES`) or the CPU's cores; each process loads its own scene, so more
    would only wait."""
    cores = cores if cores is not None else (os.cpu_count() or 1)
    return max(1, min(asked, -(-frames // CHUNK_FRAMES), cores))


def _run(job: SynthJob, todo: list[int], report: Callable[[int], None], workers: int) -> None:
    if workers == 1:
        worker_setup(job)
        try:
            for chunk in chunks(todo, CHUNK_FRAMES):
                report(len(render_chunk(chunk)))
        finally:
            worker_close()
        return
    ctx = mp.get_context("spawn")
    runs: Iterable[list[int]] = chunks(todo, CHUNK_FRAMES)
    with ctx.Pool(workers, initializer=worker_setup, initargs=(job,)) as pool:
        try:
            for chunk in pool.imap_unordered(render_chunk, runs):
                report(len(chunk))
        except DreamError:
            pool.terminate()
            raise
