"""The files a recording was read from, so that no output replaces one of them or lands where
the next read would take it for part of the recording (a frame of the DREAM layout, the joint
log or camera file of a folder of images)."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from dream.errors import InputError
from dream.io.csv_layout import CAMERA_INFO_FILE, CSV_FILE, K_FILE
from dream.io.dream_layout.names import CAMERA_SETTINGS, FRAME_FILE, FRAME_PART
from dream.sequence import Sequence

# files a recording's folder is read from besides its frames' own (any layout)
SIDE_FILES = (CAMERA_SETTINGS, CSV_FILE, CAMERA_INFO_FILE, K_FILE)


def _folder(data: Path) -> Path:
    """The recording's folder: `data`, or the folder of a file given (a bag, a joints.csv)."""
    return data if data.is_dir() else data.parent


def recording_files(seq: Sequence, data: str | Path) -> frozenset[Path]:
    """The resolved paths the recording `seq` was read from at `data` (a folder or a file):
    each frame's image, mask and record, `data` itself, and its folder's side files
    (`SIDE_FILES`, whether there or not: one written there changes what is read)."""
    data = Path(data)
    paths = {data, *(_folder(data) / name for name in SIDE_FILES)}
    for frame in seq.frames:
        paths.update(p for p in (frame.image_path, frame.mask_path, frame.source)
                     if p is not None)
    return frozenset(p.resolve() for p in paths)


def check_spares_recording(outputs: Iterable[str | Path], seq: Sequence, data: str | Path,
                           option: str = "--out") -> None:
    """An `InputError` naming the first of `outputs` that is one of the recording's files
    (`recording_files`) or, in the recording's folder, a name its frames are read by
    (`NNNNNN.json`, `NNNNNN.rgb.png`, ...)."""
    inputs = recording_files(seq, data)
    folder = _folder(Path(data)).resolve()
    for path in map(Path, outputs):
        target = path.resolve()
        if target in inputs:
            problem = f"is a file the recording is read from (--data {data})"
        elif target.parent == folder and (FRAME_FILE.match(target.name)
                                          or FRAME_PART.match(target.name)):
            problem = f"would be read as a frame of the recording in {data}"
        else:
            continue
        raise InputError(f"{problem}: writing it would change the recording", path,
                         f"choose another {option}, e.g. outside the data folder")
