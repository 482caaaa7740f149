"""`dream mark`'s page, used as a person uses it (headless Chromium: clicks, keys, the Done
button, a screenshot), and its server's limits: 127.0.0.1 only, nothing but the data's frames,
JSON posts from its own address."""

from __future__ import annotations

import csv
import http.client
import json
import socket
import threading

import pytest

from dream.cli.mark import MarkRequest, run_mark
from dream.errors import InputError
from tests.browser import Browser
from tests.dream.test_edges import HEIGHT, WIDTH, image_dataset

CLICK_TOLERANCE_PX = 0.2   # a third of a screen pixel at the page's 3x scale


class Served:
    """`dream mark` running in a thread; `url` once the page is up."""

    def __init__(self, data, out) -> None:
        self.ready = threading.Event()
        self.url = ""
        self.count: int | None = None
        self.error: BaseException | None = None

        def run() -> None:
            try:
                self.count = run_mark(MarkRequest(data=str(data), out=str(out)), ready=self.up)
            except BaseException as exc:   # surfaced by the test
                self.error = exc
                self.ready.set()

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        assert self.ready.wait(60), "the page never came up"
        if self.error:
            raise self.error

    def up(self, url: str) -> None:
        self.url = url
        self.ready.set()

    def request(self, method: str, path: str, body: bytes | None = None,
                headers: dict | None = None) -> tuple[int, dict]:
        host, port = self.url.split("//")[1].rstrip("/").split(":")
        connection = http.client.HTTPConnection(host, int(port), timeout=10)
        connection.request(method, path, body=body, headers=headers or {})
        response = connection.getresponse()
        data = response.read()
        connection.close()
        kind = response.getheader("Content-Type", "")
        return response.status, json.loads(data) if kind.startswith("application/json") else {}

    def stop(self) -> None:
        self.request("POST", "/api/quit", b"{}", {"Content-Type": "application/json"})
        self.thread.join(30)


def rows(path) -> dict[str, tuple[float, float]]:
    with open(path) as f:
        lines = [line for line in f if not line.startswith("#")]   # the recording's line
    return {r["frame"]: (float(r["u"]), float(r["v"])) for r in csv.DictReader(lines)}


def click_pixel(browser: Browser, u: float, v: float) -> None:
    """Click image pixel (u, v) (origin at the top-left pixel's centre) on the shown frame."""
    left, top, width, height = browser.evaluate(   # the image: inside the canvas's border
        "(() => { const f = document.getElementById('frame'); "
        "const r = f.getBoundingClientRect(); return [r.left + f.clientLeft, "
        "r.top + f.clientTop, f.clientWidth, f.clientHeight]; })()")
    browser.click(left + (u + 0.5) * width / WIDTH, top + (v + 0.5) * height / HEIGHT)


def test_clicks_in_the_page_become_marks_and_done_stops_it(panda, meshes, tmp_path):
    image_dataset(panda, meshes, tmp_path)
    out = tmp_path / "marks.csv"
    served = Served(tmp_path / "data", out)
    with Browser() as browser:
        browser.open(served.url)
        browser.wait_for("document.body.dataset.shown === '0'")
        click_pixel(browser, 100.0, 50.0)
        browser.wait_for("document.getElementById('marked').children.length === 1")
        browser.key("ArrowRight", "ArrowRight", 39)
        browser.wait_for("document.body.dataset.shown === '1'")
        click_pixel(browser, 10.0, 200.0)               # a wrong click, then moved
        click_pixel(browser, 210.0, 120.0)
        browser.click_element("#next")
        browser.wait_for("document.body.dataset.shown === '2'")
        click_pixel(browser, 300.0, 20.0)
        browser.key("Delete", "Delete", 46)             # removed again
        browser.wait_for("document.getElementById('marked').children.length === 2")
        browser.click_element("#next")
        browser.wait_for("document.body.dataset.shown === '3'")
        click_pixel(browser, 160.0, 100.0)
        browser.wait_for("document.getElementById('marked').children.length === 3")
        shot = browser.screenshot(tmp_path / "mark_page.png")
        status = browser.evaluate("document.getElementById('status').textContent")
        refused = browser.evaluate(      # a click before the next frame's image shows
            "(() => { document.getElementById('next').click(); document.getElementById('frame')"
            ".dispatchEvent(new MouseEvent('click', {clientX: 5, clientY: 5})); "
            "return document.getElementById('status').textContent; })()")
        browser.wait_for("document.body.dataset.shown === '4'")
        browser.click_element("#done")
        browser.wait_for("document.body.dataset.done === '1'")
        after = browser.evaluate(        # nothing left to press, no click goes out
            "(() => { document.getElementById('frame').dispatchEvent(new MouseEvent('click', "
            "{clientX: 5, clientY: 5})); return [Array.from(document.querySelectorAll("
            "'button, input')).every(c => c.disabled), "
            "document.getElementById('status').textContent]; })()")
        done_shot = browser.screenshot(tmp_path / "mark_page_done.png")
    served.thread.join(30)
    assert after[0] and "the server has stopped" in after[1], after
    assert done_shot.stat().st_size > 10_000
    assert not served.thread.is_alive() and served.count == 3
    assert "3 frames marked, saved to marks.csv" in status and "still loading" in refused
    assert shot.stat().st_size > 10_000
    marks = rows(out)
    assert set(marks) == {"000000", "000001", "000003"}
    for name, (u, v) in (("000000", (100.0, 50.0)), ("000001", (210.0, 120.0)),
                         ("000003", (160.0, 100.0))):
        assert abs(marks[name][0] - u) < CLICK_TOLERANCE_PX, (name, marks[name])
        assert abs(marks[name][1] - v) < CLICK_TOLERANCE_PX, (name, marks[name])


def raw_status(served: Served, request_line: bytes) -> int:
    """The status of a request sent byte for byte (http.client refuses non-ASCII paths)."""
    host, port = served.url.split("//")[1].rstrip("/").split(":")
    with socket.create_connection((host, int(port)), timeout=10) as conn:
        conn.sendall(request_line + f"\r\nHost: {host}:{port}\r\n\r\n".encode())
        return int(conn.recv(64).split()[1])


def test_server_serves_only_the_data_to_its_own_address(panda, meshes, tmp_path):
    image_dataset(panda, meshes, tmp_path)
    out = tmp_path / "marks.csv"
    out.write_text("frame,u,v\n000004,12.5,13.0\n")      # an earlier run's marks go on
    served = Served(tmp_path / "data", out)
    try:
        assert served.url.startswith("http://127.0.0.1:")
        status, doc = served.request("GET", "/api/frames")
        assert status == 200 and doc["marks"] == {"000004": [12.5, 13.0]}
        assert len(doc["frames"]) == 10 and (doc["width"], doc["height"]) == (WIDTH, HEIGHT)
        assert served.request("GET", "/image/3.png")[0] == 200
        for path in ("/image/10.png", "/image/../../etc/passwd", "/image/-1.png",
                     "/../data/images/0.png", "/etc/passwd", "/image/%2e%2e%2fx.png"):
            assert served.request("GET", path)[0] == 404, path
        assert served.request("GET", "/", headers={"Host": "evil.example:80"})[0] == 403
        assert raw_status(served, b"GET /image/\xb2.png HTTP/1.1") == 404   # a digit, no int
        json_type = {"Content-Type": "application/json"}
        assert served.request("POST", "/api/mark", b"frame=000001&u=1&v=2",
                              {"Content-Type": "application/x-www-form-urlencoded"})[0] == 415
        for body in ({"frame": "nope", "u": 1, "v": 2}, {"frame": "000001", "u": 1e6, "v": 2},
                     {"frame": "000001", "u": "x", "v": 2}, {"frame": "000001"},
                     {"frame": "000001", "u": float("nan"), "v": 2},
                     {"frame": "000001", "u": 10 ** 400, "v": 2},       # beyond a float
                     {"frame": "000001", "u": True, "v": 2}, {"frame": "000001", "u": "12",
                                                              "v": 2}):
            status, doc = served.request("POST", "/api/mark", json.dumps(body).encode(),
                                         json_type)
            assert status == 400 and doc["error"], body
        assert served.request("POST", "/api/mark", b"x" * 5000, json_type)[0] == 413
        assert served.request("POST", "/api/mark", b"[" * 3000, json_type)[0] == 400  # nested
        assert served.request("POST", "/api/unmark", b'{"frame": "nope"}', json_type)[0] == 400
        assert raw_status(served, b"POST /api/mark HTTP/1.1\r\nContent-Type: application/json"
                                  b"\r\nContent-Length: -5") == 400
        assert rows(out) == {"000004": (12.5, 13.0)}   # nothing bad was written
    finally:
        served.stop()
    assert not served.thread.is_alive()


def test_the_page_goes_on_from_any_file_it_wrote(panda, meshes, tmp_path):
    """Every mark taken back leaves the header alone; one click at the image's corner (which
    calibrating refuses as normalised coordinates) is still a mark to go on from."""
    image_dataset(panda, meshes, tmp_path)
    json_type = {"Content-Type": "application/json"}
    out = tmp_path / "marks.csv"
    for body, remaining in ((b'{"frame": "000002"}', {}),
                            (b'{"frame": "000003", "u": 0.3, "v": 0.2}', {"000003": [0.3, 0.2]})):
        served = Served(tmp_path / "data", out)
        try:
            assert served.request("GET", "/api/frames")[1]["marks"] == {}
            served.request("POST", "/api/mark", b'{"frame": "000002", "u": 5, "v": 6}', json_type)
            route = "/api/unmark" if b'"u"' not in body else "/api/mark"
            if route == "/api/mark":
                served.request("POST", "/api/unmark", b'{"frame": "000002"}', json_type)
            assert served.request("POST", route, body, json_type)[1]["marks"] == remaining
        finally:
            served.stop()
        again = Served(tmp_path / "data", out)       # the file it wrote is read back
        try:
            assert again.request("GET", "/api/frames")[1]["marks"] == remaining
            again.request("POST", "/api/unmark", b'{"frame": "000003"}', json_type)
        finally:
            again.stop()
        assert again.error is None and rows(out) == {}


def test_marks_of_another_recording_are_refused(panda, meshes, tmp_path):
    """Recordings share frame names (000000...): the marks clicked on one were shown on, and
    calibrated, another."""
    from dream.coarse.mark import read_mark_rows
    from dream.io import read_sequence

    image_dataset(panda, meshes, tmp_path / "one")
    image_dataset(panda, meshes, tmp_path / "two", blank=True)   # other images
    out = tmp_path / "marks.csv"
    served = Served(tmp_path / "one" / "data", out)
    try:
        served.request("POST", "/api/mark", b'{"frame": "000002", "u": 5, "v": 6}',
                       {"Content-Type": "application/json"})
    finally:
        served.stop()
    assert out.read_text().startswith(f"# dream mark: {(tmp_path / 'one' / 'data').resolve()}")
    assert rows(out) == {"000002": (5.0, 6.0)}
    frames, _ = read_mark_rows(out, read_sequence(tmp_path / "one" / "data"))
    assert list(frames) == [2]
    edited = tmp_path / "edited.csv"                 # a row added by hand: still its marks
    edited.write_text(out.read_text() + "000005,7,8\n")
    assert list(read_mark_rows(edited, read_sequence(tmp_path / "one" / "data"))[0]) == [2, 5]
    with pytest.raises(InputError, match="other images than .*another recording"):
        read_mark_rows(out, read_sequence(tmp_path / "two" / "data"))
    with pytest.raises(InputError, match="other images than .*another recording"):
        run_mark(MarkRequest(data=str(tmp_path / "two" / "data"), out=str(out)))
    out.write_text("frame,u,v\n000002,5,6\n")        # written by hand: taken as it is
    assert list(read_mark_rows(out, read_sequence(tmp_path / "two" / "data"))[0]) == [2]


def test_ctrl_c_finishes_as_done_does(panda, meshes, tmp_path):
    """The command offers Ctrl-C as a way to finish: it said "interrupted" and exited 130."""
    import signal
    import subprocess
    import sys

    image_dataset(panda, meshes, tmp_path)
    out = tmp_path / "marks.csv"
    proc = subprocess.Popen([sys.executable, "-m", "dream.cli", "mark", "--data",
                             str(tmp_path / "data"), "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        url = line.split("open ")[1].split(" ")[0]
        host, port = url.split("//")[1].rstrip("/").split(":")
        connection = http.client.HTTPConnection(host, int(port), timeout=10)
        connection.request("POST", "/api/mark", b'{"frame": "000002", "u": 5, "v": 6}',
                           {"Content-Type": "application/json"})
        assert connection.getresponse().status == 200
        connection.close()
        proc.send_signal(signal.SIGINT)
        printed, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert f"1 marks in {out}" in printed and "interrupted" not in err
    assert rows(out) == {"000002": (5.0, 6.0)}


def test_mark_options_and_files_fail_with_one_line(panda, meshes, tmp_path):
    image_dataset(panda, meshes, tmp_path)
    for port in (70000, 80, -1):
        with pytest.raises(InputError, match="port"):
            MarkRequest(data=str(tmp_path / "data"), out=str(tmp_path / "m.csv"), port=port)
    bad = tmp_path / "bad.csv"
    bad.write_text("not,a,marks\n")
    with pytest.raises(InputError, match="header"):
        run_mark(MarkRequest(data=str(tmp_path / "data"), out=str(bad)))
    with pytest.raises(InputError, match="does not exist"):
        run_mark(MarkRequest(data=str(tmp_path / "data"), out=str(tmp_path / "no" / "m.csv")))
