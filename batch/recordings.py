"""The recordings of a batch: `--data` as a glob pattern or a list file, each recording's
folder name under the output folder, and the content hash of everything a result depends on.

A list file's line is a recording's path, optionally followed by `dream calibrate` options of
its own, from the first ` --` on (shell quoting; they replace the batch's for that recording):

    lab/ep1
    lab/ep2 --frame-range 0:120 --camera-guess 1.2,0.3,0.8 --look-at 0,0,0.4
    lab/ep2 --frame-range 120:300

>>> folder_names([Path("lab/a/ep1"), Path("lab/b/ep1"), Path("lab/b/ep2.npz")])
['a-ep1', 'b-ep1', 'ep2']
>>> folder_names([Path("lab/ep2"), Path("lab/ep2"), Path("lab/ep3")])
['ep2-part1', 'ep2-part2', 'ep3']
"""

from __future__ import annotations

import glob
import hashlib
import itertools
import json
import logging
import re
import shlex
from collections import Counter
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from dream.errors import InputError
from dream.io.csv_layout import CSV_FILE
from dream.io.detect import MANIUNICON, PANDA_TELEOP, detect_format
from dream.io.dream_layout.names import CAMERA_SETTINGS
from dream.io.images import NPZ_SUFFIX
from dream.io.panda_teleop import INFO_FILE, find_episode
from dream.io.rosbag import ROS1_SUFFIX, ROS2_FILES, is_bag

log = logging.getLogger(__name__)

LIST_SUFFIX = ".txt"              # --data LIST.txt: one recording per line
LAYOUT_FILES = (INFO_FILE, CSV_FILE, CAMERA_SETTINGS)   # each makes its folder a recording
COMMENT = "#"
HASH_BLOCK_BYTES = 1 << 20
UNSAFE_NAME_CHARS = re.compile(r"[^A-Za-z0-9._-]+")
HASH_FORMAT = 1                   # bumped when what the hash covers changes
FIX_DATA = ("give --data a glob pattern in quotes ('recordings/*') or a .txt file with one "
            "recording per line")
OPTIONS_START = re.compile(r"\s--")   # a list line's own options begin here
LINE_COMMENT = re.compile(r"\s#.*$")  # a comment after the path
PART = "part"                     # a recording listed more than once: NAME-part1, NAME-part2
# the suffixes of a recording that is a file: an .npz, a ROS 1 bag, a ROS 2 bag's storage
RECORDING_FILES = (NPZ_SUFFIX, ROS1_SUFFIX, *ROS2_FILES)
OWN, HOLDER = "own", "holder"     # `recording_kind`: by its own files, through one inside it
NAMED_LEFT_OUT = 3                # left-out matches named in the log line (then a count)


@dataclass(frozen=True)
class Listed:
    """One recording of a batch: its path and, from a list file, the `dream calibrate` options
    of its line (`argv`; its relative file names are from the folder of the list, `source`;
    `line`, 1-based, names it in errors)."""

    path: Path
    argv: tuple[str, ...] = ()
    source: Path | None = None
    line: int = 0

    @property
    def where(self) -> str:
        """The line that listed it, in words ('' for a glob's match)."""
        return f"line {self.line} of {self.source}" if self.source is not None else ""


def list_recordings(data: str) -> list[Listed]:
    """The recordings of `--data`: the lines of a `.txt` list file (relative paths from the
    list's folder; blank lines and `#` comments skipped; each line's own options kept) or the
    recordings a glob pattern matches (sorted; `**` recurses; `recordings_of` keeps the
    matches that are recordings), each path and options once. A listed recording that does
    not exist is not an error here: it fails alone, as a recording that cannot be read does."""
    if not data or not data.strip():
        raise InputError("--data is empty", fix=FIX_DATA)
    listed = Path(data)
    if listed.suffix == LIST_SUFFIX and listed.is_file():
        entries = _read_list(listed)
    else:
        entries = [Listed(path) for path in _glob_recordings(data)]
    seen: dict[tuple, Listed] = {}
    for entry in entries:
        seen.setdefault((entry.path, entry.argv), entry)
    return list(seen.values())


def _glob_recordings(data: str) -> list[Path]:
    """The recordings among the matches of the glob pattern `data` (the others logged)."""
    matches = list(dict.fromkeys(_folder_of_layout_file(Path(p).resolve())
                                 for p in sorted(glob.glob(data, recursive=True))))
    kept = recordings_of(matches)
    if not kept:
        among = f" ({len(matches)} match(es), none a recording)" if matches else ""
        raise InputError(f"--data '{data}' matches no recording{among}", fix=FIX_DATA)
    _log_left_out(data, [p for p in matches if p not in kept], kept)
    return [p for p in matches if p in kept]


def _folder_of_layout_file(path: Path) -> Path:
    """The folder a recording's layout file names (`*/info.json`, `*/joints.csv`,
    `*/_camera_settings.json` matched by a pattern: each stands for its recording, as
    `dream calibrate --data` reads it), else `path`."""
    return path.parent if path.name in LAYOUT_FILES and path.is_file() else path


def recordings_of(paths: Iterable[Path]) -> set[Path]:
    """The paths that are recordings (`recording_kind`), less those that are part of another
    (inside a recording of its own files: the frames and folders of a recording matched by
    `**`) and the folders that hold another (a folder whose one .npz or episode folder is a
    match itself, which stands for it)."""
    found = {path: kind for path in paths if (kind := recording_kind(path)) is not None}
    own = {path for path, kind in found.items() if kind == OWN}
    found = {path: kind for path, kind in found.items() if not own.intersection(path.parents)}
    holders = {folder for path in found for folder in path.parents}
    return {path for path in found if path not in holders}


def recording_kind(path: Path) -> str | None:
    """Whether `path` is one recording `dream calibrate --data` reads, and how: `OWN`, a
    recording file (a ROS bag, an .npz) or a folder of one of the layouts it detects
    (`dream.io.detect`) by its own files; `HOLDER`, a folder that is one through its one .npz
    or its one panda_teleop episode folder; None, anything else (a frame or the settings of a
    recording's folder, a folder of several recordings, a stray file)."""
    if path.suffix.lower() in RECORDING_FILES and path.is_file():
        return _file_kind(path)
    if not path.is_dir():
        return None
    try:
        layout = detect_format(path)
        inner = find_episode(path) != path if layout == PANDA_TELEOP else layout == MANIUNICON
    except InputError:                  # no layout, or several panda_teleop episodes
        return None
    return HOLDER if inner else OWN


def _file_kind(path: Path) -> str | None:
    return OWN if path.suffix.lower() == NPZ_SUFFIX or is_bag(path) else None


def _log_left_out(data: str, left_out: list[Path], kept: set[Path]) -> None:
    """Say which matches are no recording: a warning for those neither inside a recording nor
    a folder above one (a stray file, an empty folder), a note for the others."""
    above = {folder for path in kept for folder in path.parents}
    stray = [p for p in left_out if p not in above and not kept.intersection(p.parents)]
    if stray:
        log.warning("--data '%s': left out %d match(es) that are not recordings: %s", data,
                    len(stray), _named(stray))
    if len(left_out) > len(stray):
        log.info("--data '%s': left out %d match(es) inside a recording or above one (its "
                 "files, the folders that hold recordings)", data, len(left_out) - len(stray))


def _named(paths: list[Path]) -> str:
    named = ", ".join(str(p) for p in paths[:NAMED_LEFT_OUT])
    more = len(paths) - NAMED_LEFT_OUT
    return f"{named} and {more} more" if more > 0 else named


def _read_list(path: Path) -> list[Listed]:
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the list of recordings ({exc})", path, FIX_DATA) from None
    entries = [_list_line(path, number, line.strip())
               for number, line in enumerate(lines, start=1)
               if line.strip() and not line.strip().startswith(COMMENT)]
    if not entries:
        raise InputError("the list of recordings is empty", path, FIX_DATA)
    return entries


def _list_line(path: Path, number: int, line: str) -> Listed:
    """One line of a list file: the recording's path (spaces allowed, or quoted), then its
    options from the first whitespace followed by `--`; a `#` after whitespace starts a
    comment.

    >>> line = _list_line(Path("/lab/list.txt"), 3, 'ep 1\t--seed 4 --camera-guess "a b.json"  # x')
    >>> line.path.as_posix(), line.argv
    ('/lab/ep 1', ('--seed', '4', '--camera-guess', 'a b.json'))
    >>> line = _list_line(Path("/lab/list.txt"), 4, '"ep 2"  # was --seed 4')
    >>> line.path.as_posix(), line.argv
    ('/lab/ep 2', ())
    """
    found, comment = OPTIONS_START.search(line), LINE_COMMENT.search(line)
    if comment is not None and (found is None or comment.start() < found.start()):
        line, found = line[:comment.start()], None          # the path's own comment
    name, options = (line, "") if found is None else (line[:found.start()], line[found.start():])
    try:
        argv = tuple(shlex.split(options, comments=True))
        if name.lstrip().startswith(("'", '"')):
            name = " ".join(shlex.split(name, comments=True))
    except ValueError as exc:
        raise InputError(f"line {number} of the list of recordings: cannot split it ({exc})",
                         path, "quote values with spaces in them as in a shell, with both "
                         "quotes") from None
    if argv == ("--",):                    # options begun, none given
        argv = ()
    return Listed((path.parent / name.strip()).resolve(), argv, path, number)


def folder_names(paths: list[Path]) -> list[str]:
    """Each recording's folder name under the output folder: its own name (a file's without
    its suffix), led by as many of its parent folders as set it apart from every other
    recording's name of the same depth, joined by '-'; a path listed more than once (other
    frames, other options) gets `-part1`, `-part2`... in the order listed."""
    distinct = list(dict.fromkeys(paths))
    parts = [[_safe(p) for p in path.parts[:-1] if p != path.anchor]
             + [_safe(path.stem if path.suffix and not path.is_dir() else path.name)]
             for path in distinct]
    names = {}
    for i, own in enumerate(parts):
        for depth in range(1, len(own) + 1):
            name = "-".join(own[-depth:])
            if all("-".join(other[-depth:]) != name for j, other in enumerate(parts) if j != i):
                break
        names[distinct[i]] = name
    counts = Counter(paths)
    taken: dict[Path, int] = {}
    out = []
    for path in paths:
        taken[path] = taken.get(path, 0) + 1
        out.append(f"{names[path]}-{PART}{taken[path]}" if counts[path] > 1 else names[path])
    if len(set(out)) < len(out):
        return [f"{i:04d}-{name}" for i, name in enumerate(out)]
    return out


def earlier_names(keys: list[tuple[str, str]], names: list[str],
                  earlier: Mapping[tuple[str, str], str]) -> list[str]:
    """`names` (`folder_names`), except that a recording an earlier batch into the same output
    folder wrote under another name keeps that name (`keys`: each recording's path and its
    list line's options; `earlier`: the same key -> the folder that holds its record), so that
    adding a recording whose name clashes does not rename and redo a finished one; and that
    the folder of a recording not in this batch is not written over (a name it holds gets
    `-2`, `-3`...). A name that another recording of this batch takes is not given back.

    >>> earlier_names([("/a/rec", ""), ("/b/rec", "")], ["a-rec", "b-rec"],
    ...               {("/a/rec", ""): "rec"})
    ['rec', 'b-rec']
    >>> earlier_names([("/b/rec", "")], ["rec"], {("/a/rec", ""): "rec"})
    ['rec-2']
    """
    counts = Counter(keys)
    out = list(names)
    for i, key in enumerate(keys):
        old = earlier.get(key)
        if old is not None and counts[key] == 1 and old not in out:
            out[i] = old
    listed = {path for path, _ in keys}
    held = {name for (path, _), name in earlier.items() if path not in listed}
    for i, name in enumerate(out):
        if name in held:
            out[i] = next(f"{name}-{n}" for n in itertools.count(2)
                          if f"{name}-{n}" not in held | set(out) | set(earlier.values()))
    return out


def _safe(name: str) -> str:
    return UNSAFE_NAME_CHARS.sub("_", name).strip("._") or "recording"


def _hash_file(digest, path: Path) -> None:
    with path.open("rb") as f:
        while block := f.read(HASH_BLOCK_BYTES):
            digest.update(block)


def _files(path: Path) -> Iterable[tuple[str, Path]]:
    if path.is_file():
        yield path.name, path
        return
    for file in sorted(p for p in path.rglob("*") if p.is_file()):
        yield file.relative_to(path).as_posix(), file


def options_digest(options: Mapping[str, Any], option_files: Iterable[Path] = ()) -> str:
    """SHA-256 of the options and of the bytes of the files they name (a model, a guess, an
    extension)."""
    digest = hashlib.sha256(f"dream-batch {HASH_FORMAT}\n".encode())
    digest.update(json.dumps(options, sort_keys=True, default=str).encode())
    for file in option_files:
        digest.update(f"\noption file {file.name}\n".encode())
        _hash_file(digest, file)
    return digest.hexdigest()


def recording_stat(recording: Path) -> str:
    """SHA-256 of the names, sizes and modification times of a recording's files: cheap, and
    unchanged only while the files are (`recording_digest` is then not read again)."""
    digest = hashlib.sha256()
    try:
        for name, file in _files(recording):
            info = file.stat()
            digest.update(f"{name}\0{info.st_size}\0{info.st_mtime_ns}\n".encode())
    except OSError as exc:
        return f"unreadable: {exc.strerror or exc}"
    return digest.hexdigest()


def recording_digest(recording: Path) -> str:
    """SHA-256 of the names and bytes of a recording's files (a recording that cannot be read
    gets a digest naming why: it fails alone when it runs)."""
    digest = hashlib.sha256()
    try:
        for name, file in _files(recording):
            digest.update(f"\nfile {name}\n".encode())
            _hash_file(digest, file)
    except OSError as exc:
        return f"unreadable: {exc.strerror or exc}"
    return digest.hexdigest()


def input_hash(options: str, recording: str) -> str:
    """The content hash of a result's inputs: the options' digest and the recording's. The
    same hash means the result would be the same; any change means it is redone."""
    return hashlib.sha256(f"{options}\n{recording}".encode()).hexdigest()
