"""Joint fit of the extrinsic and a set of model effects over all frames.

The model predicts every observed keypoint of every frame:

    uv[f, k] = project(camera(theta), T_f(xi, theta) @ P_base[f, k](theta))

with `xi` the extrinsic's increment on a starting pose (the same convention as `dream.pnp`) and
`theta` the parameters of the effects (`dream.extension`). `fit_model` minimises a Huber cost
of the pixel residuals with scipy's trust-region least squares and finite-difference Jacobians
(the keypoint positions are recomputed only for kinematic parameters), and returns the
parameters, their covariance and the residuals. `identifiable_params` drops parameters the data
cannot tell apart from the extrinsic (or from each other); `prune_groups` removes parameter
groups that do not differ significantly from zero.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy import stats

from dream.camera import CameraIntrinsics, project
from dream.errors import InputError
from dream.extension import CameraMove, ModelExtension, extended_camera, extended_points
from dream.pnp import apply_increment
from dream.robot import Robot
from dream.transforms import transform_points

log = logging.getLogger(__name__)

POINT_EFFECTS = ("joint_offset", "link_length", "keypoint_bias", "time_offset")
VIEW_EFFECTS = ("lens_distortion", "intrinsics_error", "camera_moved")
_FD_STEP_FRACTION = 1e-3    # finite-difference step = this x the parameter's typical magnitude
_MIN_DEPTH_M = 1e-3         # points closer to the camera plane are clamped (keeps FD finite)


@dataclass(frozen=True)
class Problem:
    """Measured data of one fixed camera: what every fit of a diagnosis is made from.

    Attributes:
        robot, camera: the nominal robot and camera.
        joints: (F, J) joint readings in the robot's joint order.
        times_s: (F,) image times, s, increasing; None when the data has none.
        uv: (F, K, 2) observed keypoints, px, NaN where not observed.
        frame_names: F names.
    """

    robot: Robot
    camera: CameraIntrinsics
    joints: np.ndarray
    times_s: np.ndarray | None
    uv: np.ndarray
    frame_names: tuple[str, ...]

    def __post_init__(self) -> None:
        F, K, J = len(self.frame_names), self.robot.num_keypoints, self.robot.num_joints
        joints = np.asarray(self.joints, dtype=float)
        uv = np.asarray(self.uv, dtype=float)
        if joints.shape != (F, J):
            raise InputError(f"joints have shape {joints.shape}, expected ({F}, {J})")
        if uv.shape != (F, K, 2):
            raise InputError(f"observations have shape {uv.shape}, expected ({F}, {K}, 2)")
        object.__setattr__(self, "joints", joints)
        object.__setattr__(self, "uv", uv)
        if self.times_s is not None:
            t = np.asarray(self.times_s, dtype=float)
            if t.shape != (F,) or not np.all(np.isfinite(t)) or np.any(np.diff(t) <= 0):
                raise InputError("frame timestamps must be F finite, strictly increasing "
                                 "seconds", fix="sort the frames by time or drop timestamps")
            object.__setattr__(self, "times_s", t)

    @property
    def observed(self) -> np.ndarray:
        """(F, K) True where a keypoint was observed."""
        return np.all(np.isfinite(self.uv), axis=-1)

    @property
    def num_frames(self) -> int:
        return len(self.frame_names)


@dataclass(frozen=True)
class Param:
    """One scalar parameter of an effect.

    Attributes:
        effect: effect name (`dream.extension.EFFECT_NAMES`).
        group: parameters tested for significance together (a joint, a keypoint, ...).
        name: its label, e.g. "panda_joint2", "panda_hand.x", "k1".
        typical: a realistic magnitude (rad, m, s, or a fraction): sets the finite-difference
            step and the scale of the identifiability test.
    """

    effect: str
    group: str
    name: str
    typical: float


def candidate_params(effect: str, problem: Problem) -> list[Param]:
    """Every parameter of `effect` for this robot and data (before identifiability checks)."""
    robot = problem.robot
    if effect == "joint_offset":
        return [Param(effect, j, j, np.deg2rad(1.0)) for j in robot.joint_names]
    if effect == "link_length":
        return [Param(effect, j, j, 0.01) for j in stretchable_joints(robot)]
    if effect == "keypoint_bias":
        return [Param(effect, k, f"{k}.{axis}", 0.01) for k in robot.keypoint_names
                for axis in "xyz"]
    if effect == "lens_distortion":
        return [Param(effect, "k1", "k1", 0.05), Param(effect, "k2", "k2", 0.05),
                Param(effect, "tangential", "p1", 0.005),
                Param(effect, "tangential", "p2", 0.005)]
    if effect == "intrinsics_error":  # relative corrections: fx(1+a), cx + c fx
        return [Param(effect, "fx", "fx", 0.01), Param(effect, "fy", "fy", 0.01),
                Param(effect, "principal_point", "cx", 0.005),
                Param(effect, "principal_point", "cy", 0.005)]
    if effect == "time_offset":
        return [Param(effect, "seconds", "seconds", 0.05)]
    if effect == "camera_moved":
        return [Param(effect, "move", f"move.{n}", s) for n, s in
                (("rx", 0.01), ("ry", 0.01), ("rz", 0.01), ("tx", 0.01), ("ty", 0.01),
                 ("tz", 0.01))]
    raise InputError(f"unknown effect '{effect}'")


def stretchable_joints(robot: Robot) -> tuple[str, ...]:
    """Joints on the chains from the base to the keypoints whose origin has a length."""
    return tuple(j.name for j in robot.chain_joints if np.linalg.norm(j.origin[:3, 3]) > 1e-9)


def build_extension(params: tuple[Param, ...], values: np.ndarray, problem: Problem,
                    change_index: int | None) -> ModelExtension:
    """The `ModelExtension` of parameter values (inactive effects: nominal)."""
    joint_offset: dict[str, float] = {}
    link_length: dict[str, float] = {}
    bias: dict[str, list[float]] = {}
    distortion = {"k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0}
    intrinsics = {"fx": 0.0, "fy": 0.0, "cx": 0.0, "cy": 0.0}
    move = np.zeros(6)
    has = set()
    time_offset = None
    for p, v in zip(params, values, strict=True):
        has.add(p.effect)
        if p.effect == "joint_offset":
            joint_offset[p.name] = float(v)
        elif p.effect == "link_length":
            link_length[p.name] = float(v)
        elif p.effect == "keypoint_bias":
            bias.setdefault(p.group, [0.0, 0.0, 0.0])["xyz".index(p.name[-1])] = float(v)
        elif p.effect == "lens_distortion":
            distortion[p.name] = float(v)
        elif p.effect == "intrinsics_error":
            intrinsics[p.name] = float(v)
        elif p.effect == "time_offset":
            time_offset = float(v)
        elif p.effect == "camera_moved":
            move["rx ry rz tx ty tz".split().index(p.name.split(".")[1])] = float(v)
    cam = problem.camera
    if "lens_distortion" in has:  # the parameters are changes of the data's own coefficients
        nominal = cam.distortion or (0.0,) * 5
        for i, k in enumerate(("k1", "k2", "p1", "p2")):
            distortion[k] += nominal[i]
    corrected = None
    if "intrinsics_error" in has:
        corrected = (cam.fx * (1 + intrinsics["fx"]), cam.fy * (1 + intrinsics["fy"]),
                     cam.cx + cam.fx * intrinsics["cx"], cam.cy + cam.fy * intrinsics["cy"])
    camera_moved = None
    if "camera_moved" in has:
        if change_index is None:
            raise InputError("camera_moved needs the frame of the move")
        camera_moved = CameraMove(problem.frame_names[change_index], tuple(move[:3]),
                                  tuple(move[3:]))
    return ModelExtension(
        joint_offset_rad=joint_offset, link_length_m=link_length, keypoint_bias_m=bias,
        distortion=tuple(distortion[k] for k in ("k1", "k2", "p1", "p2"))
        if "lens_distortion" in has else None,
        intrinsics=corrected, time_offset_s=time_offset, camera_moved=camera_moved,
        robot=problem.robot.name)


@dataclass
class Model:
    """A parametrised prediction of the observations: starting pose `T0`, parameters `params`
    (after the 6 extrinsic increments) and, with `camera_moved`, the first frame after the move.
    Caches the keypoint positions of the last kinematic parameter values."""

    problem: Problem
    params: tuple[Param, ...]
    T0: np.ndarray
    change_index: int | None = None
    _cache: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        self.params = tuple(self.params)
        self.point_columns = np.array([p.effect in POINT_EFFECTS for p in self.params], bool)
        if any(p.effect == "camera_moved" for p in self.params) and self.change_index is None:
            raise InputError("a camera_moved model needs its change frame")

    @property
    def size(self) -> int:
        return 6 + len(self.params)

    def extension(self, x: np.ndarray) -> ModelExtension:
        return build_extension(self.params, np.asarray(x[6:], dtype=float), self.problem,
                               self.change_index)

    def points(self, x: np.ndarray) -> np.ndarray:
        """(F, K, 3) keypoints in the base frame for the kinematic part of x."""
        key = tuple(np.asarray(x[6:], dtype=float)[self.point_columns])
        if key not in self._cache:
            if len(self._cache) > 64:
                self._cache.clear()
            point_params = tuple(p for p in self.params if p.effect in POINT_EFFECTS)
            ext = build_extension(point_params, np.array(key), self.problem, None)
            self._cache[key] = extended_points(self.problem.robot, self.problem.joints,
                                               self.problem.times_s, ext)
        return self._cache[key]

    def poses(self, x: np.ndarray) -> np.ndarray:
        """(F, 4, 4) T_cam_base of every frame."""
        T = apply_increment(self.T0, np.asarray(x[:6], dtype=float))
        out = np.broadcast_to(T, (self.problem.num_frames, 4, 4)).copy()
        if self.change_index is not None:
            move = self.extension(x).camera_moved
            if move is not None:
                out[self.change_index:] = move.T_after_before @ T
        return out

    def predict(self, x: np.ndarray) -> np.ndarray:
        """(F, K, 2) predicted pixels."""
        P_cam = transform_points(self.poses(x)[:, None], self.points(x))
        P_cam[..., 2] = np.maximum(P_cam[..., 2], _MIN_DEPTH_M)
        camera = extended_camera(self.problem.camera, self.extension(x))
        F, K = P_cam.shape[:2]
        return project(camera, P_cam.reshape(-1, 3)).reshape(F, K, 2)

    def jacobian(self, x: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """d residual / dx over the `mask` (F, K) points: (2 M, n) by forward differences."""
        base = self.predict(x)[mask].ravel()
        steps = np.concatenate([np.full(3, 1e-6), np.full(3, 1e-6),
                                [_FD_STEP_FRACTION * p.typical for p in self.params]])
        J = np.empty((base.size, self.size))
        for j in range(self.size):
            xp = np.array(x, dtype=float)
            xp[j] += steps[j]
            J[:, j] = (self.predict(xp)[mask].ravel() - base) / steps[j]
        return J


def huber_rho(r: np.ndarray, scale: float) -> np.ndarray:
    """Huber cost of residual components (px): r^2/2 inside `scale`, linear outside."""
    a = np.abs(r)
    return np.where(a <= scale, 0.5 * r * r, scale * a - 0.5 * scale * scale)


@dataclass(frozen=True)
class FitResult:
    """A fitted model.

    Attributes:
        x: (6 + P,) extrinsic increment and parameter values.
        covariance: (6 + P, 6 + P), NaN when singular.
        residual: (F, K, 2) observed - predicted, px (every frame, NaN where not observed).
        cost: Huber cost over the fitted points.
        num_points: fitted keypoint observations.
    """

    model: Model
    x: np.ndarray
    covariance: np.ndarray
    residual: np.ndarray
    cost: float
    num_points: int

    @property
    def sigma(self) -> np.ndarray:
        """1-sigma of x; NaN where the covariance is singular or not positive."""
        d = np.diag(self.covariance)
        return np.where(np.isfinite(d) & (d > 0), np.sqrt(np.abs(d)), np.nan)

    @property
    def T_cam_base(self) -> np.ndarray:
        """The extrinsic of the first frame (before any camera move)."""
        return self.model.poses(self.x)[0]

    def bic(self, mask: np.ndarray, scale: float) -> float:
        """Bayesian information criterion over `mask`, Gaussian-equivalent Huber cost."""
        r = self.residual[mask].ravel()
        n = r.size
        rss = 2.0 * float(huber_rho(r, scale).sum())
        k = self.model.size + (1 if self.model.change_index is not None else 0)
        return n * np.log(max(rss, 1e-12) / n) + k * np.log(n)


def fit_model(model: Model, mask: np.ndarray, scale_px: float, x0: np.ndarray | None = None,
              max_evaluations: int = 60) -> FitResult:
    """Minimise the Huber cost of the `mask` (F, K) residuals over x (from x0 or zeros)."""
    mask = np.asarray(mask, bool) & model.problem.observed
    if mask.sum() * 2 < model.size:
        raise InputError(f"{int(mask.sum())} observations cannot fit {model.size} parameters")
    uv_obs = model.problem.uv[mask].ravel()
    x0 = np.zeros(model.size) if x0 is None else np.asarray(x0, dtype=float)

    def fun(x: np.ndarray) -> np.ndarray:
        return model.predict(x)[mask].ravel() - uv_obs

    def jac(x: np.ndarray) -> np.ndarray:
        return model.jacobian(x, mask)

    x = _levenberg_marquardt(fun, jac, x0, scale_px, max_evaluations)
    residual = model.problem.uv - model.predict(x)
    r = residual[mask].ravel()
    J = jac(x)
    w = np.minimum(1.0, scale_px / np.maximum(np.abs(r), 1e-12))
    dof = max(r.size - model.size, 1)
    sigma2 = float(np.sum(w * r * r) / dof)
    JtWJ = J.T @ (w[:, None] * J)
    try:
        cov = sigma2 * np.linalg.inv(JtWJ)
    except np.linalg.LinAlgError:
        cov = np.full((model.size, model.size), np.nan)
    return FitResult(model, x, cov, residual, float(huber_rho(r, scale_px).sum()),
                     int(mask.sum()))


_LM_INITIAL_DAMPING = 1e-3
_LM_DAMPING_DOWN = 3.0
_LM_DAMPING_UP = 4.0
_LM_RELATIVE_COST_TOL = 1e-10


def _levenberg_marquardt(fun, jac, x0: np.ndarray, scale_px: float,
                         max_evaluations: int) -> np.ndarray:
    """Minimise the Huber cost of fun(x) (IRLS weights inside Levenberg-Marquardt with
    Marquardt's diagonal scaling); at most `max_evaluations` residual evaluations."""
    x = np.array(x0, dtype=float)
    r = fun(x)
    cost = float(huber_rho(r, scale_px).sum())
    damping = _LM_INITIAL_DAMPING
    evaluations = 1
    while evaluations < max_evaluations:
        J = jac(x)
        w = np.minimum(1.0, scale_px / np.maximum(np.abs(r), 1e-12))
        A = J.T @ (w[:, None] * J)
        g = J.T @ (w * r)
        diag = np.maximum(np.diag(A), 1e-12)
        improved = False
        while evaluations < max_evaluations:
            try:
                dx = -np.linalg.solve(A + damping * np.diag(diag), g)
            except np.linalg.LinAlgError:
                damping *= _LM_DAMPING_UP
                continue
            x_new = x + dx
            r_new = fun(x_new)
            evaluations += 1
            cost_new = float(huber_rho(r_new, scale_px).sum())
            if np.isfinite(cost_new) and cost_new <= cost:
                converged = cost - cost_new <= _LM_RELATIVE_COST_TOL * max(cost, 1e-12)
                x, r, cost = x_new, r_new, cost_new
                damping = max(damping / _LM_DAMPING_DOWN, 1e-12)
                improved = True
                break
            damping *= _LM_DAMPING_UP
            if damping > 1e12:
                break
        if not improved or converged:
            break
    return x


# ----- identifiability --------------------------------------------------------------------------

@dataclass(frozen=True)
class Identifiability:
    """Which candidate parameters the data can determine, and why the others cannot be.

    Attributes:
        kept: identifiable parameters.
        dropped: parameter name -> reason.
        effect_px: parameter name -> RMS pixel change at its typical magnitude.
    """

    kept: tuple[Param, ...]
    dropped: dict[str, str]
    effect_px: dict[str, float]


def identifiable_params(problem: Problem, base: FitResult, candidates: list[Param],
                        mask: np.ndarray, min_effect_px: float, collinearity_tol: float,
                        against_each_other: bool = True) -> Identifiability:
    """Greedy column selection on the Jacobian at the current solution.

    A candidate is dropped when moving it by its typical magnitude changes the prediction by
    less than `min_effect_px` RMS ("moves no observed keypoint"), or when less than
    `collinearity_tol` of that change remains after the extrinsic and the parameters already
    kept can absorb it ("absorbed by the extrinsic" / "confounded with ...").
    """
    change = base.model.change_index
    if change is None and any(p.effect == "camera_moved" for p in candidates):
        change = problem.num_frames // 2  # a provisional move for the test of its parameters
    model = Model(problem, base.model.params + tuple(candidates), base.model.T0, change)
    x = np.concatenate([base.x, np.zeros(len(candidates))])
    J = model.jacobian(x, mask & problem.observed)
    n_points = max(int((mask & problem.observed).sum()), 1)
    n_fixed = base.model.size
    scales = np.array([p.typical for p in candidates])
    fixed = J[:, :n_fixed] * np.concatenate([np.full(6, 0.01), [p.typical for p in
                                                               base.model.params]])
    kept: list[Param] = []
    kept_cols: list[np.ndarray] = []
    dropped: dict[str, str] = {}
    effect: dict[str, float] = {}
    for j, p in enumerate(candidates):
        col = J[:, n_fixed + j] * scales[j]
        size = float(np.linalg.norm(col) / np.sqrt(n_points))
        effect[p.name] = size
        if size < min_effect_px:
            dropped[p.name] = (f"moves no observed keypoint ({size:.2g} px RMS at "
                               f"{p.typical:g})")
            continue
        extrinsic_only = _orthogonal_fraction(col, J[:, :6])
        basis = np.column_stack([fixed] + kept_cols) if kept_cols and against_each_other \
            else fixed
        remaining = _orthogonal_fraction(col, basis)
        if remaining < collinearity_tol:
            if extrinsic_only < collinearity_tol:
                dropped[p.name] = "absorbed by the extrinsic (same image motion as a camera move)"
            else:
                others = [q.name for q in base.model.params] + [q.name for q in kept]
                dropped[p.name] = "confounded with " + ", ".join(others[-4:])
            continue
        kept.append(p)
        kept_cols.append(col[:, None])
    return Identifiability(tuple(kept), dropped, effect)


def _orthogonal_fraction(col: np.ndarray, basis: np.ndarray) -> float:
    """|col - projection of col on span(basis)| / |col|."""
    norm = np.linalg.norm(col)
    if norm == 0:
        return 0.0
    coef, *_ = np.linalg.lstsq(basis, col, rcond=None)
    return float(np.linalg.norm(col - basis @ coef) / norm)


def group_p_values(fit: FitResult, effect: str) -> dict[str, float]:
    """p-value of "all parameters of the group are zero" for each group of `effect`."""
    out = {}
    params = fit.model.params
    groups: dict[str, list[int]] = {}
    for i, p in enumerate(params):
        if p.effect == effect:
            groups.setdefault(p.group, []).append(6 + i)
    for g, idx in groups.items():
        theta = fit.x[idx]
        cov = fit.covariance[np.ix_(idx, idx)]
        try:
            chi2 = float(theta @ np.linalg.solve(cov, theta))
        except np.linalg.LinAlgError:
            chi2 = 0.0
        out[g] = float(stats.chi2.sf(chi2, len(idx))) if np.isfinite(chi2) else 1.0
    return out
