"""On-disk cache of compiled scenes: one folder per key with `model.mjb` and `meta.json`.

The key hashes everything the model depends on: the URDF file's bytes, each mesh file's path,
size and modification time, the kinematic tree actually used (joint origins may differ from
the file, e.g. after `Robot.with_link_length_changes`), the base and keypoint links, the scene
options and the versions of this project, of the scene format and of MuJoCo. Folders are
written under a temporary name and renamed into place, so a reader never sees a partial entry;
an unreadable entry (bad checksum, unloadable model) is removed and reported to the caller,
which rebuilds it.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import secrets
import shutil
from collections.abc import Iterable
from pathlib import Path

import numpy as np

import dream
from dream.errors import InputError
from dream.io.common import cache_folder
from dream.robot import Robot
from synth.gl import mujoco

logger = logging.getLogger(__name__)

SCENES_FOLDER = "scenes"
SCENE_FORMAT_VERSION = 3  # bump when the model layout or naming changes
MODEL_FILE = "model.mjb"
META_FILE = "meta.json"
_TOKEN_BYTES = 4


class CacheMiss(Exception):
    """The entry is absent or unusable (the caller builds the scene)."""


def cache_root(cache_dir: str | Path | None = None) -> Path:
    """The folder that holds scene entries: `cache_dir`, `$DREAM_CACHE_DIR/scenes` or
    `~/.cache/dream/scenes`."""
    if cache_dir is not None:
        return Path(cache_dir).expanduser()
    return cache_folder(SCENES_FOLDER)


def _tree_digest(robot: Robot) -> str:
    h = hashlib.sha256()
    for joint in robot.tree.joints:
        mimic = None if joint.mimic is None else (joint.mimic.master, joint.mimic.multiplier,
                                                  joint.mimic.offset)
        h.update(repr((joint.name, joint.type, joint.parent, joint.child, joint.lower,
                       joint.upper, mimic)).encode())
        h.update(np.ascontiguousarray(joint.origin, dtype=float).tobytes())
        h.update(np.ascontiguousarray(joint.axis, dtype=float).tobytes())
    h.update(repr(robot.tree.links).encode())
    return h.hexdigest()


def _file_stamp(path: Path) -> list:
    try:
        st = path.stat()
    except OSError as e:
        raise InputError(f"cannot read the file ({e.strerror})", path) from e
    return [str(path.resolve()), st.st_size, st.st_mtime_ns]


def scene_key(robot: Robot, mesh_files: Iterable[Path], options: dict) -> tuple[str, dict]:
    """(hex key, the description it hashes) of a scene."""
    try:
        urdf_bytes = Path(robot.urdf_path).read_bytes()
    except OSError as e:
        raise InputError(f"cannot read the URDF ({e.strerror})", robot.urdf_path) from e
    description = {
        "format": SCENE_FORMAT_VERSION,
        "dream": dream.__version__,
        "mujoco": mujoco.__version__,
        "urdf": str(Path(robot.urdf_path).resolve()),
        "urdf_sha256": hashlib.sha256(urdf_bytes).hexdigest(),
        "meshes": sorted(_file_stamp(Path(p)) for p in set(mesh_files)),
        "tree": _tree_digest(robot),
        "base_link": robot.base_link,
        "keypoints": list(robot.keypoint_names) if options.get("keypoint_markers") else [],
        "options": options,
    }
    text = json.dumps(description, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:32], description


def load_entry(root: Path, key: str) -> mujoco.MjModel:
    """The cached model of `key`.

    Raises:
        CacheMiss: no entry, or one that cannot be read (it is then removed).
    """
    folder = root / key
    if not folder.is_dir():
        raise CacheMiss(key)
    try:
        meta = json.loads((folder / META_FILE).read_text())
        if meta.get("key") != key:
            raise ValueError("the entry's meta.json names another key")
        # checked before MuJoCo reads it: MuJoCo logs its own warnings on a damaged file
        digest = hashlib.sha256((folder / MODEL_FILE).read_bytes()).hexdigest()
        if meta.get("model_sha256") != digest:
            raise ValueError(f"{MODEL_FILE} does not match its checksum")
        return mujoco.MjModel.from_binary_path(str(folder / MODEL_FILE))
    except (OSError, ValueError, TypeError, AttributeError) as e:
        logger.warning("scene cache entry %s is unusable (%s); rebuilding it", folder, e)
        remove_entry(root, key)
        raise CacheMiss(key) from e


def remove_entry(root: Path, key: str) -> None:
    """Delete an entry (ignores one that another process removed first)."""
    shutil.rmtree(root / key, ignore_errors=True)


def save_entry(root: Path, key: str, model: mujoco.MjModel, description: dict) -> None:
    """Write an entry atomically; failures are logged, never raised (the cache is optional)."""
    temporary = root / f".{key}.tmp-{os.getpid()}-{secrets.token_hex(_TOKEN_BYTES)}"
    try:
        temporary.mkdir(parents=True)
        mujoco.mj_saveModel(model, str(temporary / MODEL_FILE), None)
        digest = hashlib.sha256((temporary / MODEL_FILE).read_bytes()).hexdigest()
        meta = {"key": key, "model_sha256": digest, "description": description}
        (temporary / META_FILE).write_text(json.dumps(meta, indent=1, default=str))
        os.rename(temporary, root / key)
    except OSError as e:
        if not (root / key).is_dir():
            logger.warning("cannot write scene cache entry %s (%s); continuing without it",
                           root / key, e)
    finally:
        shutil.rmtree(temporary, ignore_errors=True)
