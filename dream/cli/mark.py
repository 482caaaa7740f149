"""`dream mark`: a local web page that shows the recording's frames and records one click per
frame on a point of the end effector, for `dream calibrate --mark` (`dream.mark_page`)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import TextIO

from dream.cli.options import DataOptions, add_command, add_data_args, read_data, request_from
from dream.errors import InputError

ANY_PORT = 0                  # --port 0: the system picks a free port
MIN_PORT, MAX_PORT = 1024, 65535   # below 1024 only a system service may listen


@dataclass(frozen=True)
class MarkRequest(DataOptions):
    """What `dream mark` does: the options of its command line."""

    data: str
    out: str
    port: int = 0

    def __post_init__(self) -> None:
        if not (self.port == ANY_PORT or MIN_PORT <= self.port <= MAX_PORT):
            raise InputError(f"--port {self.port} is not a port a user's server may take",
                             fix=f"give {MIN_PORT}-{MAX_PORT}, or {ANY_PORT} for any free port")


def run_mark(request: MarkRequest, out: TextIO | None = None,
             ready: Callable[[str], None] | None = None) -> int:
    """Serve the page on 127.0.0.1 until its Done button (or Ctrl-C, the same); the clicks go
    to `request.out` after every change, below a comment line naming the recording's marked
    frames (`dream.io.marks`; an existing marks file of the recording is read first, to go
    on marking; one of another recording is refused). `ready(url)` is called once the page
    can be opened. Returns the number of marks written."""
    from pathlib import Path

    from dream.coarse.mark import read_mark_rows
    from dream.io import check_output_file, load_image
    from dream.io.images import encode_png
    from dream.io.marks import marks_comment, read_shared_files, shared_files
    from dream.io.recording_files import check_spares_recording
    from dream.mark_page.server import HOST, MarkBook, make_server

    out = out or sys.stdout
    target = check_output_file(request.out)
    seq = read_data(request)
    check_spares_recording([target], seq, request.data)
    camera = seq.fixed_camera("mark one point in the frames of one camera")
    if any(f.image_path is None for f in seq.frames):
        raise InputError("some frames have no image, and the page shows the images",
                         request.data, "give a recording with an image in every frame")
    names = [f.name for f in seq.frames]
    digests: dict = {}            # image file -> its SHA-256, read once
    shared = shared_files(seq)
    if shared:
        print(f"reading {', '.join(map(str, shared))} once (the marks file names the frames "
              "by their content)", file=out, flush=True)
        read_shared_files(shared, digests)
    marks = {}
    if target.exists():
        frames, uv = read_mark_rows(target, seq, digests)
        marks = {names[int(i)]: (float(u), float(v)) for i, (u, v) in zip(frames, uv,
                                                                          strict=True)}
    source = str(Path(request.data).resolve())
    book = MarkBook(names, camera, target, marks,
                    lambda indices: marks_comment(source, seq, indices, digests))

    def image_png(i: int) -> bytes:
        return encode_png(load_image(seq.frames[i], camera), seq.frames[i].image_path)

    server = make_server(book, image_png, request.port)
    url = f"http://{HOST}:{server.server_address[1]}/"
    print(f"dream mark: {len(names)} frames{f', {len(marks)} marked in {target}' if marks else ''}"
          f"; open {url} in a browser (on this machine), click the same point of the end "
          "effector in five or more frames (two at least), then Done (or Ctrl-C here)",
          file=out, flush=True)
    if ready is not None:
        ready(url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:     # Ctrl-C finishes as Done does: every click is written
        print("", file=out)
    finally:
        server.server_close()
    count = len(book.marks())
    print(f"{count} marks in {target}" if count else f"no marks in {target}" if
          target.exists() else "no marks clicked; nothing written", file=out)
    return count


def cmd_mark(args: argparse.Namespace) -> int:
    run_mark(request_from(MarkRequest, args))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """The `dream mark` parser."""
    p = add_command(sub, "mark", cmd_mark, "click one point of the end effector in some frames "
                    "(a local web page) for dream calibrate --mark")
    add_data_args(p)
    p.add_argument("--out", required=True, help="MARKS.csv to write (frame,u,v rows, below a "
                   "'#' line naming the recording's marked frames); an existing one of this "
                   "recording is read first, to go on marking, one of another is refused")
    p.add_argument("--port", type=int, default=0, help="port on 127.0.0.1 (default: any free "
                   "one, printed)")
