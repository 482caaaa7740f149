"""Which recording a marks file (`frame,u,v`, `dream mark`) was clicked on: the comment line
`dream mark` writes above the header gives each marked frame's name with a short SHA-256 of
its image, so that marks clicked on another recording whose frames share their names (000000,
000001...) are refused instead of used. Rows the line does not name (added by hand) and a file
without the line are taken as they are.

    # dream mark: /data/rec1; frames sha256 000004=3f2a9c01d2e4b5a6 000019=...
    frame,u,v
    000004,312.50,201.00

>>> stated_digests(["# dream mark: /d; frames sha256 000004=" + "ab" * 8])
{'000004': 'abababababababab'}
>>> stated_digests(["# notes"])
{}
"""

from __future__ import annotations

import hashlib
import re
from collections import Counter
from collections.abc import Iterable
from pathlib import Path

from dream.errors import InputError
from dream.provenance import file_digest

COMMENT = "#"
DIGEST_HEX = 16               # hex digits kept of each frame's SHA-256
_FRAMES = re.compile(r"frames sha256 (.*)$")
_PAIR = re.compile(rf"(\S+)=([0-9a-f]{{{DIGEST_HEX}}})")


def frame_sha256(sequence, index: int, cache: dict[Path, bytes] | None = None) -> str:
    """The first `DIGEST_HEX` hex digits of the SHA-256 of frame `index`'s name, image file
    content and index in that file (a video or bag)."""
    frame = sequence.frames[int(index)]
    digest = hashlib.sha256(frame.name.encode())
    digest.update(b"-" if frame.image_path is None
                  else file_digest(Path(frame.image_path), {} if cache is None else cache))
    digest.update(str(frame.image_index).encode())
    return digest.hexdigest()[:DIGEST_HEX]


def shared_files(sequence) -> list[Path]:
    """The image files that several frames share (a bag, a video, an image stack)."""
    counts = Counter(Path(f.image_path) for f in sequence.frames if f.image_path is not None)
    return sorted(path for path, count in counts.items() if count > 1)


def read_shared_files(shared: Iterable[Path], cache: dict[Path, bytes]) -> None:
    """Hash into `cache` every file of `shared` (`shared_files`), so that the first click of
    `dream mark` does not wait for a whole recording to be read."""
    for path in shared:
        file_digest(path, cache)


def marks_comment(source: str, sequence, indices: Iterable[int],
                  cache: dict[Path, bytes] | None = None) -> str:
    """The comment line above a marks file's header for the marked frames `indices`."""
    pairs = " ".join(f"{sequence.frames[i].name}={frame_sha256(sequence, i, cache)}"
                     for i in sorted(int(i) for i in indices))
    return f"{COMMENT} dream mark: {source}; frames sha256 {pairs}"


def stated_digests(lines: Iterable[str]) -> dict[str, str]:
    """Frame name -> digest, as a marks file's comment lines state them (none: {})."""
    for line in lines:
        found = _FRAMES.search(line)
        if found:
            return dict(_PAIR.findall(found.group(1)))
    return {}


def check_marked_frames(path: Path, stated: dict[str, str], sequence,
                        indices: Iterable[int], cache: dict[Path, bytes] | None = None) -> None:
    """Refuse marks whose frames `indices` (of `sequence`) have other images than the comment
    line states for those names (the marks of another recording). `cache`: file digests
    already read (`read_shared_files`), filled with those read here."""
    cache = {} if cache is None else cache     # a video or bag holds every frame: read it once
    other = [sequence.frames[i].name for i in indices
             if sequence.frames[i].name in stated
             and stated[sequence.frames[i].name] != frame_sha256(sequence, i, cache)]
    if other:
        raise InputError(f"the marks of frames {', '.join(other[:3])} were clicked on other "
                         f"images than {sequence.source}'s frames of those names (another "
                         "recording)", path, "give the marks clicked on this recording, or "
                         "mark it anew: dream mark --data THIS_RECORDING --out NEW_MARKS.csv")
