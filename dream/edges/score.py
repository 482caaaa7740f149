"""How well a pose's outline agrees with the images, in all and per link.

At full resolution, every outline point of the scored frames (`dream.edges.search`) either
faces an edge within `agree_px` or not; the share that does is the pose's agreement. The keep
rule compares it before and after the alignment, and a link whose outline agrees less than
`mismatch_ratio` times the whole outline at the kept pose is named: its visible shape differs
from its model (a tool, a gripper or a held object the URDF lacks), or something hides it in
most frames.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dream.edges.search import ScaleImages, outline_edges
from dream.edges.settings import EdgeSettings
from dream.silhouette import RobotMeshes


@dataclass(frozen=True)
class LinkAgreement:
    """One link's outline at a pose: its outline points, the share of them that face an
    edge within `agree_px`, and the median distance to the edges found (px, NaN: none)."""

    link: str
    points: int
    agreement: float
    median_px: float


@dataclass(frozen=True)
class EdgeScore:
    """A pose's agreement with the images: outline points, the share that agree, per link."""

    points: int
    agreement: float
    links: tuple[LinkAgreement, ...]

    def mismatched(self, settings: EdgeSettings) -> tuple[str, ...]:
        """Links whose outline agrees less than `mismatch_ratio` x the whole outline's
        agreement (with at least `min_outline_points` points)."""
        return tuple(a.link for a in self.links if a.points >= settings.min_outline_points
                     and a.agreement < settings.mismatch_ratio * self.agreement)


def edge_score(meshes: RobotMeshes, P_frames: np.ndarray, T: np.ndarray, images: ScaleImages,
               settings: EdgeSettings, usable: np.ndarray | None = None) -> EdgeScore:
    """The agreement of the outline at T (of the vertices `usable`) with `images` (module
    doc)."""
    outline, d, found = outline_edges(P_frames, meshes.faces, T, images, settings, usable)
    agree = found & (np.abs(np.nan_to_num(d, nan=np.inf)) <= settings.agree_px)
    link = meshes.vertex_link[outline.vertex]
    per_link = []
    for i, name in enumerate(meshes.links):
        mine = link == i
        if not mine.any():
            continue
        hits = np.abs(d[mine & found])
        per_link.append(LinkAgreement(name, int(mine.sum()), float(agree[mine].mean()),
                                      float(np.median(hits)) if len(hits) else float("nan")))
    return EdgeScore(len(d), float(agree.mean()) if len(d) else 0.0, tuple(per_link))
