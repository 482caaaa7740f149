"""The human diagnosis report (`dream.diagnosis.report`) from small synthetic inputs."""

from __future__ import annotations

import re
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from dream.camera import CameraIntrinsics
from dream.diagnosis.report import (
    FIELD_PNG,
    GAINS_PNG,
    SILHOUETTES_PNG,
    TIME_PNG,
    SilhouettePanel,
    report_markdown,
    silhouette_overlay,
    write_report,
)
from dream.diagnosis.residuals import ResidualSet, analyse
from dream.errors import InputError

CAMERA = CameraIntrinsics(fx=300.0, fy=300.0, cx=160.0, cy=120.0, width=320, height=240)
F, K, J = 24, 5, 3
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def _residuals(seed: int, noise_px: float, times: bool) -> ResidualSet:
    rng = np.random.default_rng(seed)
    t = np.arange(F) / 10.0
    centre = rng.uniform([20, 20], [300, 220], size=(K, 2))
    uv = centre + 15 * np.sin(t[:, None, None] + rng.uniform(0, 6, (K, 2)))
    observed = uv + rng.normal(0, noise_px, uv.shape)
    used = np.ones((F, K), bool)
    used[3, 1] = False                      # an outlier
    observed[5, 2] = np.nan                 # not observed
    used[5, 2] = False
    return ResidualSet(tuple(f"{i:06d}" for i in range(F)), tuple(f"kp{k}" for k in range(K)),
                       tuple(f"joint{j}" for j in range(J)), observed, uv, used,
                       rng.uniform(-1, 1, (F, J)), t if times else None, CAMERA)


def _diagnosis(full: bool) -> dict:
    if not full:   # only the required keys of docs/data_format.md, verdict empty
        return {"baseline": {"rmse_px": 2.0, "heldout_rmse_px": 2.2},
                "effects": [{"name": "joint_offset", "params": {"joint0": 0.0},
                             "heldout_rmse_px": 2.21, "significant": False,
                             "evidence": "no gain"}],
                "verdict": [], "extended_model": None,
                "gain": {"heldout_rmse_px_before": 2.2, "heldout_rmse_px_after": 2.2}}
    return {"baseline": {"rmse_px": 2.0, "heldout_rmse_px": 2.2},
            "effects": [
                {"name": "joint_offset", "params": {"joint0": 0.012, "joint2": -0.004},
                 "sigma": {"joint0": 0.001, "joint2": 0.002}, "heldout_rmse_px": 0.9,
                 "significant": True, "evidence": "held-out RMSE 2.2 -> 0.9 px | 5 folds",
                 "bic_delta": -140.2, "p_value": 1e-20,
                 "identifiability": {"condition_number": 35.0, "correlated_with": "camera"}},
                {"name": "camera_moved", "params": {"frame": "000012",
                                                     "rotation_rad": [0.01, 0.0, 0.0],
                                                     "translation_m": [0.0, 0.02, 0.0]},
                 "sigma": {"rotation_rad": [0.001, 0.001, 0.001],
                           "translation_m": [0.002, 0.002, 0.002]},
                 "heldout_rmse_px": 1.5, "significant": True, "evidence": "step at 000012",
                 "identifiability": "well determined"},
                {"name": "lens_distortion", "params": {"k1": 0.0, "k2": 0.0, "p1": 0.0,
                                                        "p2": 0.0},
                 "heldout_rmse_px": None, "significant": False, "evidence": "fit failed"}],
            "verdict": ["joint_offset", "camera_moved"],
            "extended_model": "extended_model.yaml",
            "gain": {"heldout_rmse_px_before": 2.2, "heldout_rmse_px_after": 0.8},
            "truth": {"joint_offset": {"joint0": 0.0125}},
            "notes": ["synthetic test data"]}


def _panel(name: str, after: bool) -> SilhouettePanel:
    h, w = 60, 80
    image = np.full((h, w, 3), 128, np.uint8)
    observed = np.zeros((h, w), bool)
    observed[10:40, 20:50] = True
    before = np.roll(observed, 6, axis=1)
    return SilhouettePanel(name, image, observed, before, observed if after else None,
                           iou_before=0.6, iou_after=1.0 if after else None)


def _linked_pngs(report: Path) -> list[str]:
    return re.findall(r"\]\(([^)]+\.png)\)", report.read_text())


def _check_pngs(report: Path) -> list[str]:
    names = _linked_pngs(report)
    for name in names:
        data = (report.parent / name).read_bytes()
        assert data.startswith(PNG_SIGNATURE), name
        assert mpimg.imread(report.parent / name).ndim == 3
    return names


@pytest.mark.parametrize("times,extended,silhouettes,full", [
    (True, True, True, True),
    (False, False, False, False),
])
def test_report_written_with_valid_linked_pngs(tmp_path, times, extended, silhouettes, full):
    base = _residuals(0, 2.0, times)
    ext = _residuals(0, 0.8, times) if extended else None
    panels = [_panel("000003", True), _panel("000010", False)] if silhouettes else ()
    report = write_report(tmp_path / "rep", _diagnosis(full), base, ext, analyse(base), panels)
    assert report == tmp_path / "rep" / "report.md"
    names = _check_pngs(report)
    assert FIELD_PNG in names and GAINS_PNG in names
    assert (TIME_PNG in names) == times
    assert (SILHOUETTES_PNG in names) == silhouettes
    text = report.read_text()
    assert text.startswith("# ")
    for section in ("## Data", "## Effects", "## Verdict", "## Gain", "## Residual analysis"):
        assert section in text
    if full:
        assert "**joint_offset**" in text and "0.012" in text and "0.0125" in text
        assert "rotation_rad[0]" in text and "\\|" in text  # pipes in evidence escaped
        assert "| camera_moved | frame | 000012 |" in text   # a frame name stays text
        assert "condition_number" in text and "synthetic test data" in text
    else:
        assert "No effect accepted" in text
    # no temporary files left behind
    assert not [p for p in report.parent.iterdir() if p.name.startswith(".")]


def test_running_twice_overwrites_cleanly(tmp_path):
    out = tmp_path / "rep"
    out.mkdir()
    (out / "diagnosis.json").write_text("{}")          # someone else's file: kept
    base = _residuals(1, 1.0, True)
    write_report(out, _diagnosis(True), base, None, analyse(base), [_panel("000001", True)])
    assert (out / TIME_PNG).exists() and (out / SILHOUETTES_PNG).exists()
    base = _residuals(1, 1.0, False)
    report = write_report(out, _diagnosis(False), base, None, analyse(base))
    names = set(_check_pngs(report))
    pngs = {p.name for p in out.glob("*.png")}
    assert pngs == names                                 # stale plots removed
    assert (out / "diagnosis.json").read_text() == "{}"
    assert sorted(p.name for p in out.iterdir()) == sorted(names | {"report.md",
                                                                    "diagnosis.json"})


def test_markdown_tolerates_missing_optional_keys():
    base = _residuals(2, 1.0, False)
    text = report_markdown({}, base, None, {}, [])
    assert "No effect was tested" in text and "n/a" in text


def test_silhouette_overlay_and_panel_validation():
    p = _panel("000000", True)
    over = silhouette_overlay(p.image, p.observed_mask, p.rendered_before)
    assert over.shape == p.image.shape and over.dtype == np.uint8
    assert over[20, 22, 0] > over[20, 22, 2]            # photo only: red
    assert over[20, 52, 2] > over[20, 52, 0]            # model only: blue
    assert over[0, 0].tolist() == [77, 77, 77]          # background dimmed
    computed = SilhouettePanel("x", p.image, p.observed_mask, p.rendered_before,
                               p.rendered_after, 0.6)
    assert computed.iou_after == 1.0
    with pytest.raises(InputError):
        SilhouettePanel("x", p.image[..., 0], p.observed_mask, p.rendered_before, None, 0.5)
    with pytest.raises(InputError):
        SilhouettePanel("x", p.image, p.observed_mask[:-1], p.rendered_before, None, 0.5)
    with pytest.raises(InputError):
        SilhouettePanel("x", p.image, p.observed_mask, p.rendered_before, None, 1.5)


def test_bad_arguments_raise_input_error(tmp_path):
    base = _residuals(3, 1.0, False)
    with pytest.raises(InputError):
        write_report(tmp_path, "not a dict", base, None, {})
    with pytest.raises(InputError):
        write_report(tmp_path, _diagnosis(False), "not residuals", None, {})
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(InputError):
        write_report(blocker / "rep", _diagnosis(False), base, None, {})
