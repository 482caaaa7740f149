"""The camera's intrinsics at the search's winner: the lens's radial distortion, the principal
point and the focal length the robot's outlines ask for (`dream.coarse.distortion`,
`dream.coarse.principal`, `dream.coarse.focal`), each adopted where the outlines tell it, and
the search run again through the camera with it.

The distortion goes first, alone (`with_asked_distortion`): left out of the given intrinsics,
it bends the outlines in a way a principal point and a focal length partly make up for (on
rendered scenes given raw images of a lens with k1 -0.2 as rectified, principal points 3-6 deg
off were adopted). Then, at the winner through it, the focal length is fitted through that
camera, then the principal point through the focal length where the outlines ask for it (the
search's pose moved to each), and
(`with_asked_intrinsics`, the rule of `dream.cli.keypoint_pass.asked_intrinsics` on the
keypoint path):
- where the principal point is unresolved (a turn beyond the limit within the noise, or not
  judged beside something carried), nothing is adopted: the outlines do not tell the
  intrinsics apart, and a focal length they ask for may only make up for a principal point
  given wrong;
- where the principal point is a finding, it is adopted alone: the focal length beside it was
  fitted through the wrong one (on the keypoint path's rendered scenes given cx, cy 24, -16 px
  off, the outlines asked for fx, fy x1.092 through them, and adopted together the pose lay
  142 mm off); the focal length is fitted again through it;
- otherwise a focal length asked for (`dream.coarse.focal`'s rule) is adopted.
Each adoption runs the search again from the fit's pose and the winner's rival through the
camera with it, and the fits not yet adopted run again at the new winner, at most
`MAX_ADOPTIONS` times; nothing is adopted twice. The principal point goes after the focal
length, not before: through a focal length 5 % short, ten grey test frames' outlines left the
principal point unresolved (a turn of 2.2 deg within 3 sigma), and through the asked one they
did not.

Neither runs where the robot was found only with the pixels its silhouettes cover in most
frames kept (`SearchSettings.robot_found`): the fits score the silhouettes without them, as the
held-out test does, and a winner found only the other way can still lie far off (on a rendered
close-up of a UR5 holding an object, the winner before the fit lay 852 mm off at IoU 0.26
without them and 0.48 with them; the focal fit adopted fx, fy x1.043 there and the pose written
ended 19.5 mm off; without the fit the edge alignment's optimum, competing on the masks, won
at 1.6 mm).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from dream.camera import CameraIntrinsics
from dream.coarse.distortion import DistortionSettings, fit_distortion
from dream.coarse.focal import FocalEstimate, FocalSettings, fit_focal
from dream.coarse.principal import PrincipalEstimate, PrincipalSettings, fit_principal
from dream.coarse.search import SearchOutcome, Winner, searched_again
from dream.coarse.settings import SearchSettings
from dream.silhouette import vertices_in_base

if TYPE_CHECKING:
    from dream.coarse.calibration import SearchMasks

FOCAL, PRINCIPAL = "focal", "principal"     # the hypotheses' sources of the searches again
DISTORTION = "distortion"
MAX_ADOPTIONS = 2       # a principal point and a focal length
NAMES = {FOCAL: "focal length", PRINCIPAL: "principal point", DISTORTION: "lens distortion"}


def with_asked_distortion(camera: CameraIntrinsics, inputs: SearchMasks, winner: Winner,
                          settings: SearchSettings, distortion: DistortionSettings | None = None,
                          progress: Callable[[str], None] | None = None,
                          P: np.ndarray | None = None
                          ) -> tuple[Winner, SearchMasks, CameraIntrinsics]:
    """The radial distortion the outlines ask for at the winner through `camera`, adopted where
    they tell it (`dream.coarse.distortion`): the winner searched again through the camera
    with it, the inputs with the estimate (`SearchMasks.distortion`), and the camera the rest
    goes on with. Not fitted where `distortion.fit` is False or the robot was found only with
    the held pixels kept (as the focal length). P (F, V, 3): the inputs' vertices in the base
    frame (computed where not given)."""
    distortion = distortion or DistortionSettings()
    if not (distortion.fit and settings.robot_found(winner.best.iou)):
        return winner, inputs, camera
    say = progress or (lambda line: None)
    P = vertices_in_base(inputs.meshes, inputs.joints) if P is None else P
    start = time.perf_counter()
    estimate = fit_distortion(P, inputs.meshes, inputs.masks, camera, winner.best.T_cam_base,
                              settings, distortion, inputs.held, inputs.region)
    say(f"lens distortion ({time.perf_counter() - start:.1f} s): {estimate.reason}")
    inputs = replace(inputs, distortion=estimate)
    if not estimate.adopted:
        return winner, inputs, camera
    say(f"{NAMES[DISTORTION]}: adopted, searching again with it")
    winner = searched_again(estimate.camera, inputs, winner, estimate.T_cam_base, DISTORTION,
                            settings, progress)
    return winner, inputs, estimate.camera


def with_asked_intrinsics(camera: CameraIntrinsics, inputs: SearchMasks, winner: Winner,
                          settings: SearchSettings, focal: FocalSettings | None = None,
                          principal: PrincipalSettings | None = None,
                          progress: Callable[[str], None] | None = None,
                          distortion: DistortionSettings | None = None
                          ) -> tuple[SearchOutcome, SearchMasks]:
    """The radial distortion, then the focal length and the principal point the outlines ask
    for at the winner through `camera`, adopted where they tell them (module doc); the outcome
    checked, and the inputs with the estimates (`SearchMasks.distortion`, `focal`,
    `principal`: the adopted ones, else the last fitted). `distortion.fit`, `focal.fit`,
    `principal.fit` False: not fitted; `principal.adopt` False: a finding is reported and kept
    as given."""
    focal, principal = focal or FocalSettings(), principal or PrincipalSettings()
    distortion = distortion or DistortionSettings()
    P = (vertices_in_base(inputs.meshes, inputs.joints)
         if focal.fit or principal.fit or distortion.fit else None)
    winner, inputs, camera = with_asked_distortion(camera, inputs, winner, settings,
                                                   distortion, progress, P)
    say = progress or (lambda line: None)
    kept: dict[str, FocalEstimate | PrincipalEstimate] = {}
    adopted: dict[str, FocalEstimate | PrincipalEstimate] = {}
    for _ in range(MAX_ADOPTIONS + 1):
        if not settings.robot_found(winner.best.iou):
            if focal.fit or principal.fit:
                say(f"intrinsics: not fitted, the robot found only with the pixels its "
                    f"silhouettes cover in most frames kept (IoU {winner.best.iou:.2f} "
                    "without them)")
            break
        f, p = _fitted(camera, inputs, P, winner, settings,
                       focal if FOCAL not in adopted else replace(focal, fit=False),
                       principal if PRINCIPAL not in adopted else replace(principal, fit=False),
                       say)
        kept.update({k: e for k, e in ((FOCAL, f), (PRINCIPAL, p)) if e is not None})
        asked_focal = f is not None and f.adopted
        if p is not None and p.unresolved:
            if asked_focal:
                kept[FOCAL] = _refused(f, "the principal point is unresolved, and the focal "
                                          "length may only make up for it")
            break
        if p is not None and p.flagged and principal.adopt:
            estimate = replace(p, given=camera).adopted_with(principal)
            start, source = estimate.T_cam_base, PRINCIPAL
            if asked_focal:
                kept[FOCAL] = _refused(f, "fitted through the principal point given")
        elif asked_focal:
            estimate, start, source = f, f.T_cam_base, FOCAL
        else:
            break
        adopted[source] = estimate
        camera = estimate.camera
        say(f"{NAMES[source]}: adopted, searching again with it")
        winner = searched_again(camera, inputs, winner, start, source, settings, progress)
    inputs = replace(inputs, **{k: adopted.get(k, kept.get(k)) for k in (FOCAL, PRINCIPAL)})
    return winner.checked(), inputs


def _refused(estimate: FocalEstimate, why: str) -> FocalEstimate:
    """A focal length asked for, not adopted because of `why`."""
    return replace(estimate, adopted=False, reason=f"{estimate.reason}; not adopted: {why}")


def _fitted(camera: CameraIntrinsics, inputs: SearchMasks, P: np.ndarray | None,
            winner: Winner, settings: SearchSettings, focal: FocalSettings,
            principal: PrincipalSettings, say: Callable[[str], None]
            ) -> tuple[FocalEstimate | None, PrincipalEstimate | None]:
    """The focal length the outlines ask for at the winner through `camera`, then the
    principal point through the asked focal length where it is asked for (each None where
    its settings say not to fit it); P (F, V, 3): the inputs' vertices in the base frame."""
    if not (focal.fit or principal.fit):
        return None, None
    T = winner.best.T_cam_base
    f = None
    if focal.fit:
        f = fit_focal(P, inputs.meshes, inputs.masks, camera, T, settings, focal, inputs.held,
                      inputs.region)
        say(f"focal length: {f.reason}")
        if f.adopted:
            camera, T = f.camera, f.T_cam_base
    if not principal.fit:
        return f, None
    p = fit_principal(P, inputs.meshes, inputs.masks, camera, T, settings, principal,
                      inputs.held, inputs.region)
    say(f"principal point ({p.seconds:.1f} s): {p.reason}")
    return f, p


def intrinsics_change(before: CameraIntrinsics, after: CameraIntrinsics) -> str:
    """How the intrinsics went from `before` to `after`, for the user.

    >>> from dream.coarse.focal import with_focal_scale
    >>> camera = CameraIntrinsics(300.0, 300.0, 160.0, 120.0, 320, 240)
    >>> intrinsics_change(camera, with_focal_scale(camera, 1.1))
    'fx, fy, cx, cy 300.00, 300.00, 160.00, 120.00 -> 330.00, 330.00, 160.00, 120.00'
    >>> intrinsics_change(camera, replace(camera, distortion=(-0.1, 0.02, 0, 0, 0)))[-49:]
    '; distortion k1, k2 0.000, 0.000 -> -0.100, 0.020'
    """
    def values(c: CameraIntrinsics) -> str:
        return ", ".join(f"{v:.2f}" for v in (c.fx, c.fy, c.cx, c.cy))

    change = f"fx, fy, cx, cy {values(before)} -> {values(after)}"
    if before.distortion != after.distortion:
        k_before, k_after = before.dist_coeffs[:2], after.dist_coeffs[:2]
        change += (f"; distortion k1, k2 {k_before[0]:.3f}, {k_before[1]:.3f} -> "
                   f"{k_after[0]:.3f}, {k_after[1]:.3f}")
    return change


def adopted_camera(camera: CameraIntrinsics, inputs: SearchMasks) -> CameraIntrinsics:
    """`camera` with the distortion of an adopted radial distortion, fx, fy of an adopted focal
    length and cx, cy of an adopted principal point (`SearchMasks.distortion`, `focal`,
    `principal`), each where adopted."""
    d, f, p = inputs.distortion, inputs.focal, inputs.principal
    if d is not None and d.adopted:
        camera = replace(camera, distortion=d.camera.distortion)
    if f is not None and f.adopted:
        camera = replace(camera, fx=f.camera.fx, fy=f.camera.fy)
    if p is not None and p.adopted:
        camera = replace(camera, cx=p.camera.cx, cy=p.camera.cy)
    return camera
