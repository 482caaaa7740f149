"""Edge alignment of one extrinsic: coarse to fine, the model's outline onto the image edges.

At each scale (`scale_widths_px`, coarsest first) the grey images are shrunk by area averaging,
the camera scaled to match (`dream.polish.scaled_camera`), and rounds run until the outline
stops moving: render each frame's silhouette at the current pose, select its outline points,
find the image edge facing each (`dream.edges.search`), then a few Levenberg-Marquardt steps
(`dream.optim`) on the point-to-edge residuals

    r_i(T) = n_i . (uv_i(T) - uv_i(T0)) - d_i,

the distance along the outline's normal n_i between where the outline point goes and the edge
found for it, Huber-weighted and cut at `max_residual_px`. The edges are searched again in the
next round (as in ICP). A coarse scale sees a start several centimetres off within its search
range; the fine scales place the outline to a fraction of a pixel.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from dream.camera import CameraIntrinsics
from dream.edges.search import Outline, ScaleImages, outline_edges, scale_images
from dream.edges.settings import EdgeSettings
from dream.optim import levenberg_marquardt
from dream.optim.robust import huber_rho, huber_weight
from dream.pnp import apply_increment, linearise
from dream.polish.refine import inner_lm_settings, rms_motion_px

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Matched:
    """Outline points with an edge found: the points, and each edge's offset d (px)."""

    outline: Outline
    d: np.ndarray


class _EdgeProblem:
    """`dream.optim.lm`'s view of the point-to-edge residuals over T_cam_base, each point's
    robust weight times its link's (`link_weights`)."""

    def __init__(self, matched: Matched, camera: CameraIntrinsics, settings: EdgeSettings,
                 point_weight: np.ndarray | None = None):
        self.m, self.camera, self.settings = matched, camera, settings
        self.point_weight = np.ones(len(matched.d)) if point_weight is None else point_weight

    def residuals(self, T: np.ndarray, jacobian: bool) -> tuple[np.ndarray, Any] | None:
        o = self.m.outline
        lin = linearise(o.P_base, o.uv, self.camera, T)
        if lin is None:
            return None
        duv, J_uv = lin
        r = np.einsum("nk,nk->n", o.normal, duv) - self.m.d
        return r, (np.einsum("nk,nkj->nj", o.normal, J_uv) if jacobian else None)

    def rho(self, r: np.ndarray) -> np.ndarray:
        cut = self.settings.max_residual_px
        return self.point_weight * huber_rho(np.minimum(np.abs(r), cut),
                                             self.settings.huber_scale_px)

    def weight(self, r: np.ndarray) -> np.ndarray:
        return self.point_weight * np.where(np.abs(r) > self.settings.max_residual_px, 0.0,
                                            huber_weight(r, self.settings.huber_scale_px))

    def evaluate(self, T: np.ndarray) -> tuple[float, Any]:
        out = self.residuals(T, jacobian=True)
        return (float("inf"), None) if out is None else (float(np.sum(self.rho(out[0]))), out)

    def normal_equations(self, T: np.ndarray, state: Any) -> tuple[np.ndarray, np.ndarray]:
        r, J = state
        w = self.weight(r)
        return J.T @ (w[:, None] * J), J.T @ (w * r)

    def retract(self, T: np.ndarray, xi: np.ndarray) -> np.ndarray:
        return apply_increment(T, xi)


def match_outline(P_frames: np.ndarray, faces: np.ndarray, T: np.ndarray,
                  images: ScaleImages, settings: EdgeSettings,
                  usable: np.ndarray | None = None) -> Matched:
    """The outline points at T (of the vertices `usable`, default all) that face an image
    edge, with the edge's offset."""
    outline, d, found = outline_edges(P_frames, faces, T, images, settings, usable)
    return Matched(outline.subset(found), d[found])


def link_weights(d: np.ndarray, link: np.ndarray, scale: float) -> np.ndarray:
    """(N,) each matched point's link weight: min(1, scale x the median |d| of all points / the
    median |d| of its link's points); all 1 when `scale` is 0 (pure).

    >>> d = np.array([0.5, -0.5, 0.4, 3.0, -3.0])
    >>> link_weights(d, np.array([0, 0, 0, 1, 1]), 2.0).round(2).tolist()
    [1.0, 1.0, 1.0, 0.33, 0.33]
    """
    out = np.ones(len(d))
    if scale <= 0 or not len(d):
        return out
    overall = float(np.median(np.abs(d)))
    for value in np.unique(link):
        mine = link == value
        own = float(np.median(np.abs(d[mine])))
        if own > 0:
            out[mine] = min(1.0, scale * overall / own)
    return out


def _lm_steps(problem: _EdgeProblem, T: np.ndarray, settings: EdgeSettings) -> np.ndarray:
    lm = inner_lm_settings(settings.initial_damping, settings.inner_iterations)
    return levenberg_marquardt(problem, T, lm).x


@dataclass(frozen=True)
class EdgeTrace:
    """What the alignment did: rounds per scale and the matched points of the last round."""

    rounds: tuple[int, ...]
    matched_points: int


def align_edges(P_frames: np.ndarray, faces: np.ndarray, gray: np.ndarray,
                camera: CameraIntrinsics, T_cam_base: np.ndarray,
                settings: EdgeSettings, background: np.ndarray | None = None,
                usable: np.ndarray | None = None,
                vertex_link: np.ndarray | None = None) -> tuple[np.ndarray, EdgeTrace]:
    """The pose whose rendered outline lies on the images' edges, searched from `T_cam_base`.

    Args:
        P_frames: (F, V, 3) mesh vertices of each frame in the base frame, m.
        faces: (T, 3) triangles. gray: (F, H, W) grey images in [0, 1] at `camera`'s size.
        T_cam_base: (4, 4) the start.
        background: (H, W) the background model (`dream.edges.background`), or None.
        usable: (V,) bool, the vertices whose outline is matched (default all).
        vertex_link: (V,) each vertex's link, for the links' weights (`link_weights`,
            `link_weight_scale`); None: no link weights.
    Returns:
        (T (4, 4), what was done).
    """
    T = np.array(T_cam_base, dtype=float)
    rounds: list[int] = []
    matched = 0
    for width in dict.fromkeys(min(w, camera.width) for w in settings.scale_widths_px):
        level = scale_images(gray, camera, width, settings, background)
        done = 0
        for done in range(1, settings.rounds_per_scale + 1):
            m = match_outline(P_frames, faces, T, level, settings, usable)
            matched = len(m.d)
            if matched < settings.min_outline_points:
                log.info("edge alignment: only %d outline points face an edge", matched)
                return T, EdgeTrace(tuple(rounds + [done]), matched)
            weights = (None if vertex_link is None else link_weights(
                m.d, vertex_link[m.outline.vertex], settings.link_weight_scale))
            T_new = _lm_steps(_EdgeProblem(m, level.camera, settings, weights), T, settings)
            moved = rms_motion_px(m.outline.P_base, T, T_new, level.camera)
            T = T_new
            log.debug("edges at width %d, round %d: %d points, moved %.3g px", width, done,
                      matched, moved)
            if moved < settings.step_tolerance_px:
                break
        rounds.append(done)
    return T, EdgeTrace(tuple(rounds), matched)
