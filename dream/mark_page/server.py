"""The local web page of `dream mark`: the recording's frames, one click per frame on the
marked point, the clicks written as `frame,u,v` rows (`dream.coarse.mark`) after every change.

The server binds to 127.0.0.1 only and serves the page, the frames' images by index and the
marks, nothing else: no file path reaches it from a request, so nothing outside the data can be
read. Requests whose Host is not this address are refused (a web site cannot reach the page
through a name of its own), changes must be JSON posts (a form on another site cannot send
them), and `POST /api/quit` (the page's Done button) or Ctrl-C stops it.

Routes: `GET /` the page; `GET /api/frames` names, image size and marks; `GET /image/N.png`
frame N's image; `POST /api/mark` {"frame", "u", "v"}; `POST /api/unmark` {"frame"};
`POST /api/quit`.
"""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Callable
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib.resources import files
from pathlib import Path

import numpy as np

from dream.camera import CameraIntrinsics
from dream.coarse.mark import MARK_COLUMNS
from dream.errors import InputError
from dream.io.atomic import write_bytes_atomic

log = logging.getLogger(__name__)

HOST = "127.0.0.1"
MAX_BODY_BYTES = 4096       # a mark is a few dozen bytes
JSON_TYPE = "application/json"
IMAGE_PREFIX, IMAGE_SUFFIX = "/image/", ".png"


class MarkBook:
    """The clicks of one recording (frame name -> (u, v)), written to `out` as a CSV after
    every change (atomically: a killed server leaves the old file or the new one)."""

    def __init__(self, names: list[str], camera: CameraIntrinsics, out: Path,
                 marks: dict[str, tuple[float, float]] | None = None,
                 comment: Callable[[list[int]], str] | None = None) -> None:
        """`comment(indices)`: the line written above the header for the marked frames'
        indices (`dream.io.marks.marks_comment`), None: none."""
        self.names, self.camera, self.out = names, camera, out
        self._marks: dict[str, tuple[float, float]] = dict(marks or {})
        self._comment = comment
        self._lock = threading.Lock()

    def marks(self) -> dict[str, list[float]]:
        with self._lock:
            return {k: list(v) for k, v in self._marks.items()}

    def mark(self, name: str, u: float, v: float) -> None:
        """Record the click of frame `name` (pixels, origin at the top-left pixel's centre)."""
        if name not in self.names:
            raise InputError(f"no frame {name!r}")
        if not self.camera.in_image(np.array([u, v])):
            raise InputError(f"pixel ({u}, {v}) is outside the {self.camera.width}x"
                             f"{self.camera.height} image")
        with self._lock:
            self._marks[name] = (u, v)
            self._write()

    def unmark(self, name: str) -> None:
        if name not in self.names:
            raise InputError(f"no frame {name!r}")
        with self._lock:
            self._marks.pop(name, None)
            self._write()

    def _write(self) -> None:
        order = {n: i for i, n in enumerate(self.names)}
        head = [] if self._comment is None else [
            self._comment(sorted(order[name] for name in self._marks))]
        rows = head + [",".join(MARK_COLUMNS)] + [
            f"{name},{u:.2f},{v:.2f}" for name, (u, v) in
            sorted(self._marks.items(), key=lambda item: order[item[0]])]
        write_bytes_atomic(self.out, ("\n".join(rows) + "\n").encode(), durable=False)


def _number(value) -> float:
    """A JSON number as a float (not a string, a boolean or null)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"u and v must be numbers, got {value!r}")
    return float(value)       # OverflowError for an integer beyond a float's range


def page_html() -> bytes:
    return files("dream.mark_page").joinpath("page.html").read_bytes()


def make_server(book: MarkBook, image_png: Callable[[int], bytes], port: int = 0
                ) -> ThreadingHTTPServer:
    """The page's server on 127.0.0.1:`port` (0: any free port); `image_png(i)`: frame i's
    image as PNG bytes. Run it with `serve_forever()`; `POST /api/quit` shuts it down."""
    handler = type("MarkHandler", (_Handler,), {"book": book, "image_png": staticmethod(
        image_png)})
    try:
        server = ThreadingHTTPServer((HOST, port), handler)
    except OSError as exc:
        raise InputError(f"cannot listen on {HOST}:{port} ({exc.strerror})",
                         fix="give another --port, or 0 for any free one") from None
    server.daemon_threads = True
    return server


class _Handler(BaseHTTPRequestHandler):
    book: MarkBook
    image_png: Callable[[int], bytes]
    server_version = "dream-mark"

    def log_message(self, format: str, *args) -> None:   # noqa: A002 (the base's name)
        log.debug("%s " + format, self.address_string(), *args)

    def do_GET(self) -> None:   # noqa: N802 (http.server's name)
        if not self._host_ok():
            return
        if self.path == "/":
            self._send(HTTPStatus.OK, page_html(), "text/html; charset=utf-8")
        elif self.path == "/api/frames":
            book = self.book
            self._json({"frames": book.names, "width": book.camera.width,
                        "height": book.camera.height, "out": book.out.name,
                        "marks": book.marks()})
        elif self.path.startswith(IMAGE_PREFIX) and self.path.endswith(IMAGE_SUFFIX):
            index = self.path[len(IMAGE_PREFIX):-len(IMAGE_SUFFIX)]
            if not (index.isascii() and index.isdigit()) or int(index) >= len(
                    self.book.names):                   # '²' is a digit, not an int
                self._error(HTTPStatus.NOT_FOUND, "no such frame")
                return
            self._send(HTTPStatus.OK, self.image_png(int(index)), "image/png")
        else:
            self._error(HTTPStatus.NOT_FOUND, "not found")

    def do_POST(self) -> None:   # noqa: N802 (http.server's name)
        if not self._host_ok():
            return
        body = self._body()
        if body is None:
            return
        try:
            if self.path == "/api/mark":
                self.book.mark(str(body.get("frame")), _number(body.get("u")),
                               _number(body.get("v")))
            elif self.path == "/api/unmark":
                self.book.unmark(str(body.get("frame")))
            elif self.path == "/api/quit":
                self._json({"stopped": True})
                threading.Thread(target=self.server.shutdown, daemon=True).start()
                return
            else:
                self._error(HTTPStatus.NOT_FOUND, "not found")
                return
        except (InputError, TypeError, ValueError, OverflowError) as exc:
            self._error(HTTPStatus.BAD_REQUEST, str(exc))
            return
        self._json({"marks": self.book.marks()})

    def _host_ok(self) -> bool:
        port = self.server.server_address[1]
        if self.headers.get("Host") in (f"{HOST}:{port}", f"localhost:{port}"):
            return True
        self._error(HTTPStatus.FORBIDDEN, "open the page at the address dream mark printed")
        return False

    def _body(self) -> dict | None:
        if self.headers.get("Content-Type", "").split(";")[0].strip() != JSON_TYPE:
            self._error(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, "send JSON")
            return None
        text = self.headers.get("Content-Length", "0").strip()
        if not (text.isascii() and text.isdigit()):
            self._error(HTTPStatus.BAD_REQUEST, "Content-Length must be a byte count")
            return None
        length = int(text)
        if length > MAX_BODY_BYTES:
            self._error(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, "body too large")
            return None
        try:
            body = json.loads(self.rfile.read(length) or b"{}")
        except (ValueError, RecursionError):       # not JSON, not UTF-8, nested too deep
            body = None
        if not isinstance(body, dict):
            self._error(HTTPStatus.BAD_REQUEST, "send a JSON object")
            return None
        return body

    def _json(self, obj: dict) -> None:
        self._send(HTTPStatus.OK, json.dumps(obj).encode(), JSON_TYPE)

    def _error(self, status: HTTPStatus, message: str) -> None:
        self._send(status, json.dumps({"error": message}).encode(), JSON_TYPE)

    def _send(self, status: HTTPStatus, data: bytes, content_type: str) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        self.end_headers()
        self.wfile.write(data)

