"""Which recording a marks file (`frame,u,v`, `dream mark`) was clicked on: the comment line
`dream mark` writes above the header holds a SHA-256 of the marked frames' names and image
files, so that marks clicked on another recording whose frames share their names (000000,
000001...) are refused instead of used. A file without the line (written by hand) is taken as
it is.

    # dream mark: /data/rec1; marked frames sha256 3f2a...
    frame,u,v
    000004,312.50,201.00

>>> comment_sha256(["# dream mark: /d; marked frames sha256 " + "ab" * 32]) == "ab" * 32
True
>>> comment_sha256(["# notes"]) is None
True
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Iterable
from pathlib import Path

from dream.errors import InputError
from dream.provenance import file_digest

COMMENT = "#"
_SHA256 = re.compile(r"marked frames sha256 ([0-9a-f]{64})")


def marked_frames_sha256(sequence, indices: Iterable[int],
                         cache: dict[Path, bytes] | None = None) -> str:
    """SHA-256 (hex) of the frames `indices` of `sequence` in time order: each one's name,
    image file content and index in that file (a video or bag)."""
    digest, cache = hashlib.sha256(), {} if cache is None else cache
    for i in sorted(int(i) for i in indices):
        frame = sequence.frames[i]
        digest.update(frame.name.encode())
        digest.update(b"-" if frame.image_path is None
                      else file_digest(Path(frame.image_path), cache))
        digest.update(str(frame.image_index).encode())
    return digest.hexdigest()


def marks_comment(source: str, sha256: str) -> str:
    """The comment line above a marks file's header."""
    return f"{COMMENT} dream mark: {source}; marked frames sha256 {sha256}"


def comment_sha256(lines: Iterable[str]) -> str | None:
    """The marked frames' SHA-256 a marks file's comment lines state, None without one."""
    for line in lines:
        found = _SHA256.search(line)
        if found:
            return found.group(1)
    return None


def check_marked_frames(path: Path, stated: str | None, sequence, indices: Iterable[int]) -> None:
    """Refuse marks whose comment states other marked frames than `sequence`'s of those names
    (the marks of another recording)."""
    if stated is None or stated == marked_frames_sha256(sequence, indices):
        return
    raise InputError(f"the marks were clicked on another recording's frames (other images "
                     f"under the same frame names) than {sequence.source}'s", path,
                     "give the marks clicked on this recording, or mark it anew: dream mark "
                     "--data THIS_RECORDING --out NEW_MARKS.csv")
