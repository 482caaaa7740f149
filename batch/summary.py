"""The summary of `dream batch calibrate`: one row per recording, in `summary.csv` (for a
spreadsheet) and `summary.json` (the full extrinsic), both replaced atomically as the batch
runs (`batch.calibrate.run_batch`: every few seconds and at the end).

A row: `recording` (its path), `name` (its folder), `options` (a list line's own `dream
calibrate` options, as written; empty for none), `status` (`ok` or `failed`), `frames`
(used), the camera in the robot base frame (`camera_x_m`... and its orientation `qx`... `qw`,
of `T_base_cam`), `sigma_position_mm` and `sigma_rotation_deg` (root-sum-square of the
1-sigma per axis), `verdict` (`good`, `check`, `unreliable`), `seconds`, and `error` (the
one-line reason of a failure). summary.json adds `T_cam_base`.
"""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Any

import numpy as np

from dream.io import write_bytes_atomic, write_json_atomic

OK, FAILED = "ok", "failed"
SUMMARY_CSV, SUMMARY_JSON = "summary.csv", "summary.json"
M_TO_MM = 1e3
COLUMNS = ("recording", "name", "options", "status", "frames", "camera_x_m", "camera_y_m",
           "camera_z_m", "qx", "qy", "qz", "qw", "sigma_position_mm", "sigma_rotation_deg",
           "verdict", "seconds", "error")


def result_row(recording: str, name: str, doc: dict, seconds: float,
               options: str = "") -> dict[str, Any]:
    """The row of a RESULT.json document."""
    from dream.transforms import quaternion_xyzw_from_R

    T_base_cam = np.asarray(doc["T_base_cam"], dtype=float)
    q = quaternion_xyzw_from_R(T_base_cam[:3, :3])
    frames = doc.get("frames_used")
    return {
        "recording": recording, "name": name, "options": options, "status": OK,
        "frames": len(frames) if isinstance(frames, list) else frames,
        **{f"camera_{axis}_m": float(v) for axis, v in zip("xyz", T_base_cam[:3, 3],
                                                             strict=True)},
        **{axis: float(v) for axis, v in zip(("qx", "qy", "qz", "qw"), q, strict=True)},
        "sigma_position_mm": _rss(doc.get("sigma_camera_position_base_m")) * M_TO_MM,
        "sigma_rotation_deg": float(np.rad2deg(_rss(doc.get("sigma_rotation_rad")))),
        "verdict": doc.get("quality", {}).get("verdict"),
        "seconds": round(seconds, 3), "error": None,
        "T_cam_base": doc["T_cam_base"],
    }


def failed_row(recording: str, name: str, error: str, seconds: float,
               options: str = "") -> dict[str, Any]:
    """The row of a recording that failed: its one-line error."""
    row: dict[str, Any] = dict.fromkeys(COLUMNS)
    row.update(recording=recording, name=name, options=options, status=FAILED,
               seconds=round(seconds, 3), error=" ".join(error.split()))
    return row


def _rss(values) -> float:
    return float(np.sqrt(np.sum(np.square(values)))) if values is not None else float("nan")


def write_summary(out_dir: Path, rows: list[dict[str, Any]]) -> None:
    """summary.csv and summary.json of `rows`, each replaced atomically."""
    text = io.StringIO()
    writer = csv.DictWriter(text, fieldnames=COLUMNS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: "" if row.get(k) is None else row.get(k) for k in COLUMNS})
    write_bytes_atomic(out_dir / SUMMARY_CSV, text.getvalue().encode("utf-8"))
    ok, failed = summary_counts(rows)
    write_json_atomic(out_dir / SUMMARY_JSON, {"recordings": len(rows), "ok": ok,
                                               "failed": failed, "rows": rows})


def summary_counts(rows: list[dict[str, Any]]) -> tuple[int, int]:
    """(ok, failed) rows."""
    ok = sum(r.get("status") == OK for r in rows)
    return ok, sum(r.get("status") == FAILED for r in rows)
