"""Where robot description files live: example-robot-data's share folder and `package://` URIs.

example-robot-data is installed by pip as a cmeel package: its files are under
`<site-packages>/cmeel.prefix/share/example-robot-data/...`, and a URI `package://X/rest` of its
URDFs names `cmeel.prefix/share/X/rest`. The folder is found by searching the import path, never
through a hard-coded site-packages path.
"""

from __future__ import annotations

import functools
import logging
import os
import site
import sys
from pathlib import Path

from dream.errors import InputError

CMEEL_PREFIX = "cmeel.prefix"
ROBOT_DATA_PACKAGE = "example-robot-data"
PACKAGE_SCHEME = "package://"
FILE_SCHEME = "file://"
ROS_PACKAGE_PATH = "ROS_PACKAGE_PATH"  # ROS 1: roots holding packages, at any depth
AMENT_PREFIX_PATH = "AMENT_PREFIX_PATH"  # ROS 2: install prefixes, each package in share/<name>
PACKAGE_MANIFEST = "package.xml"
MAX_PACKAGE_DEPTH = 4  # how deep under a ROS_PACKAGE_PATH root a package folder is looked for

logger = logging.getLogger(__name__)


def _candidate_site_dirs() -> list[Path]:
    """Folders that may hold `cmeel.prefix`: the import path and the site-packages folders."""
    dirs: list[str] = list(sys.path)
    try:
        dirs += site.getsitepackages()
    except AttributeError:  # some embedded interpreters have no getsitepackages
        pass
    dirs.append(site.getusersitepackages())
    seen: list[Path] = []
    for d in dirs:
        if d and Path(d) not in seen:
            seen.append(Path(d))
    return seen


@functools.lru_cache(maxsize=1)
def share_dir() -> Path:
    """The cmeel `share` folder that holds example-robot-data (one folder per ROS package).

    Raises:
        InputError: example-robot-data is not installed in this interpreter's environment.
    """
    for d in _candidate_site_dirs():
        # cmeel puts its own site-packages (cmeel.prefix/lib/pythonX.Y/site-packages) on sys.path
        for base in (d, *d.parents[:4]):
            share = base / CMEEL_PREFIX / "share"
            if (share / ROBOT_DATA_PACKAGE).is_dir():
                return share
    raise InputError(f"the {ROBOT_DATA_PACKAGE} robot models are not installed",
                     fix="pip install example-robot-data")


def robot_data_dir() -> Path:
    """example-robot-data's own folder: `<share>/example-robot-data` (holds `robots/...`)."""
    return share_dir() / ROBOT_DATA_PACKAGE


def _ros_package_dirs(package: str) -> tuple[Path, ...]:
    """Folders named `package` that the ROS environment variables point to (ROS 1 and ROS 2)."""
    return _package_dirs_under(package, os.environ.get(AMENT_PREFIX_PATH, ""),
                               os.environ.get(ROS_PACKAGE_PATH, ""))


@functools.lru_cache(maxsize=64)
def _package_dirs_under(package: str, ament_prefix_path: str, ros_package_path: str
                        ) -> tuple[Path, ...]:
    """`_ros_package_dirs` for these variables' values: the walk of `ROS_PACKAGE_PATH`'s roots
    runs once per package, not once per mesh of a URDF."""
    found: list[Path] = []
    for prefix in ament_prefix_path.split(os.pathsep):
        if prefix:
            found.append(Path(prefix) / "share" / package)
    for root in ros_package_path.split(os.pathsep):
        if not root or not Path(root).is_dir():
            continue
        found.append(Path(root) / package)
        for depth in range(1, MAX_PACKAGE_DEPTH + 1):
            found += [m.parent for m in Path(root).glob("/".join(["*"] * depth) + "/"
                                                        + PACKAGE_MANIFEST)
                      if m.parent.name == package]
    return tuple(found)


def _package_candidates(uri: str, urdf_path: Path) -> tuple[list[Path], list[Path]]:
    """Where `package://X/rest` may lie: the folders named X, and the fallbacks.

    Named, most specific first: an ancestor folder of the URDF named X (the usual ROS source
    layout), the ROS environment's packages, example-robot-data's share folder. The fallbacks:
    any ancestor of the URDF holding `rest` (a package checked out under another folder name).
    `package:///X/rest` is read as `package://X/rest`, as pinocchio reads it.
    """
    package, _, rest = uri[len(PACKAGE_SCHEME):].lstrip("/").partition("/")
    if not package or not rest:
        raise InputError(f"malformed resource URI '{uri}'", urdf_path,
                         fix="write package://PACKAGE/path/to/file")
    ancestors = urdf_path.resolve().parents
    candidates = [parent / rest for parent in ancestors if parent.name == package]
    candidates += [d / rest for d in _ros_package_dirs(package)]
    try:
        candidates.append(share_dir() / package / rest)
    except InputError:
        pass  # no example-robot-data: only the URDF's own tree can hold the package
    return candidates, [parent / rest for parent in ancestors]


def resolve_resource(uri: str, urdf_path: str | Path, must_exist: bool = True) -> Path:
    """The file a URDF's resource reference (mesh filename) names.

    `package://X/rest` is looked up in an ancestor folder of the URDF named X, then in the
    packages `ROS_PACKAGE_PATH` and `AMENT_PREFIX_PATH` name, then in the cmeel share folder
    (`<share>/X/rest`), and last in any ancestor folder of the URDF that holds `rest`. `file://`
    and absolute paths are taken as they are; anything else is relative to the URDF's folder.

    Args:
        uri: the reference as written in the URDF.
        urdf_path: the URDF file that contains it.
        must_exist: raise when the file does not exist (else return the best candidate).

    Raises:
        InputError: the file does not exist (when `must_exist`), or the URI is malformed.

    Example:
        >>> from dream.robot import load_robot
        >>> urdf = load_robot("panda").urdf_path
        >>> resolve_resource("package://example-robot-data/robots/panda_description/"
        ...                  "meshes/visual/link0.dae", urdf).name
        'link0.dae'
    """
    urdf_path = Path(urdf_path)
    candidates: list[Path] = []
    fallbacks: list[Path] = []
    if uri.startswith(PACKAGE_SCHEME):
        candidates, fallbacks = _package_candidates(uri, urdf_path)
    elif uri.startswith(FILE_SCHEME):
        candidates.append(Path(uri[len(FILE_SCHEME):]))
    else:
        candidates.append(Path(uri) if Path(uri).is_absolute() else urdf_path.parent / uri)
    for c in candidates + fallbacks:
        if c.is_file():
            logger.debug("%s -> %s", uri, c)
            return c
    if must_exist or not candidates:
        looked = [str(c) for c in candidates] + (["the URDF's parent folders"] if fallbacks else [])
        raise InputError(f"resource '{uri}' not found (looked in: "
                         f"{', '.join(looked) or 'nowhere'})", urdf_path,
                         fix="install the package that holds it, name its folder in "
                             f"{ROS_PACKAGE_PATH}, or fix the path in the URDF")
    return candidates[0]


def filename_handler(urdf_path: str | Path):
    """A `filename_handler` for `yourdfpy.URDF.load` that resolves as `resolve_resource` does."""
    urdf_path = Path(urdf_path)

    def handler(fname: str) -> str:
        return str(resolve_resource(fname, urdf_path, must_exist=False))

    return handler
