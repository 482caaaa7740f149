"""Belief maps -> 2D keypoints: smoothing, threshold, local maxima, ambiguity, sub-pixel peak.

Shared by training (validation metrics) and inference; numpy and OpenCV only.

Coordinate spaces (pixels, u right, v down, the centre of the top-left pixel at (0, 0)):
- map: a belief map of `h` x `w` pixels, one map pixel = `stride` input pixels;
- input: the network input (`dream.preprocess`): `u_input = (u_map + 0.5) * stride - 0.5`;
- image: the camera image, through `dream.preprocess.InputTransform.input_to_image`.

The records are named after their space: `PeaksInMap` (`uv_map`), `PeaksInInput` (`uv_input`),
`PeaksInImage` (`uv_image`); a keypoint not found has NaN coordinates, `found` False and a
`reason` from `REASONS`.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from functools import lru_cache

import numpy as np

from dream.errors import InputError
from dream.preprocess import InputTransform

FOUND = "found"
BELOW_THRESHOLD = "below_threshold"  # no local maximum reaches the threshold
AMBIGUOUS = "ambiguous"              # a distant second peak is nearly as high as the best
OUT_OF_FRAME = "out_of_frame"        # the refined centre lies outside the map
REASONS = (FOUND, BELOW_THRESHOLD, AMBIGUOUS, OUT_OF_FRAME)
_GAUSS_TRUNCATE_SIGMAS = 4.0  # the smoothing kernel's half size, in sigmas
_MIN_FIT_PIXELS = 6         # unknowns of the 2D quadratic fit
_MIN_FIT_FRACTION = 1e-6    # the fit leaves out pixels below this fraction of the peak (at
                            # weight z^2 they would carry < 1e-12 of its weight)
_VALID_STRIDES = (1, 2, 4)
_NEIGHBOURS_VU = np.array([(dv, du) for dv in (-1, 0, 1) for du in (-1, 0, 1) if dv or du])


@dataclass(frozen=True)
class PeakSettings:
    """Every constant of the peak finder. Distances in map pixels; values on the belief scale
    (a perfect peak is 1).

    Attributes:
        smoothing_sigma: Gaussian smoothing before the local-maximum search (0: none).
        threshold: a peak counts only when its value on the smoothed map reaches this.
        ambiguity_ratio: not found when the second-highest peak farther than
            `ambiguity_min_distance` from the best is higher than this fraction of the best.
        ambiguity_min_distance: peaks closer than this to the best are the same peak.
        refine_radius: half size of the window of the sub-pixel fit ((2r+1)^2 pixels).
        refine_floor: pixels of the window below this fraction of the peak value are left
            out of the fit (they carry the noise and the tails, not the peak's shape).
    """

    smoothing_sigma: float = 1.0
    threshold: float = 0.1
    ambiguity_ratio: float = 0.5
    ambiguity_min_distance: float = 4.0
    refine_radius: int = 2
    refine_floor: float = 0.05

    def __post_init__(self) -> None:
        for name in ("smoothing_sigma", "threshold", "ambiguity_ratio", "ambiguity_min_distance",
                     "refine_floor"):
            value = getattr(self, name)
            if isinstance(value, bool) or not np.isfinite(float(value)) or float(value) < 0:
                raise InputError(f"peak parameter {name} must be a finite number >= 0, got "
                                 f"{value!r}")
            object.__setattr__(self, name, float(value))
        if self.threshold <= 0:
            raise InputError(f"peak threshold must be > 0, got {self.threshold}")
        if self.ambiguity_ratio > 1:
            raise InputError(f"ambiguity_ratio must be in [0, 1], got {self.ambiguity_ratio}")
        if self.refine_floor >= 1:
            raise InputError(f"refine_floor must be in [0, 1), got {self.refine_floor}")
        if isinstance(self.refine_radius, bool) or int(self.refine_radius) != self.refine_radius \
                or self.refine_radius < 1:
            raise InputError(f"refine_radius must be an integer >= 1, got {self.refine_radius!r}")
        object.__setattr__(self, "refine_radius", int(self.refine_radius))


def peak_params_from_overrides(items: list[str] | tuple[str, ...], option: str = "peaks",
                               base: PeakSettings | None = None) -> PeakSettings:
    """`base` (default `PeakSettings()`) with `NAME=VALUE` items applied, e.g.
    `["ambiguity_ratio=1.0"]`; errors name `option` (the command-line flag)."""
    base = PeakSettings() if base is None else base
    names = [f.name for f in fields(PeakSettings)]
    values = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key not in names:
            raise InputError(f"{option} {item}: expected NAME=VALUE with NAME one of "
                             f"{', '.join(names)}")
        try:
            values[key] = type(getattr(base, key))(value)
        except ValueError:
            raise InputError(f"{option} {item}: {value!r} is not a number") from None
    return replace(base, **values)


@dataclass(frozen=True)
class PeaksInMap:
    """Peaks of K belief maps, in map pixels.

    Attributes:
        uv_map: (K, 2) sub-pixel peak, map pixels; NaN where not found.
        confidence: (K,) the belief map's value at the peak pixel (the local maximum of the
            smoothed map; 0 where there is none, the best peak's for ambiguous and
            out-of-frame keypoints). The threshold applies to the smoothed map, whose peaks
            are lower: sigma^2 / (sigma^2 + smoothing_sigma^2) for a Gaussian of sigma.
        found: (K,) bool.
        reason: K strings from `REASONS`.
        map_width, map_height: size of the belief maps, px.
    """

    uv_map: np.ndarray
    confidence: np.ndarray
    found: np.ndarray
    reason: tuple[str, ...]
    map_width: int
    map_height: int

    def to_input(self, stride: int) -> PeaksInInput:
        """The same peaks in input pixels (the map is `stride` times smaller than the input)."""
        return PeaksInInput(map_to_input(self.uv_map, stride), self.confidence, self.found,
                            self.reason)


@dataclass(frozen=True)
class PeaksInInput:
    """Peaks in network-input pixels; fields as `PeaksInMap`, `uv_input` (K, 2)."""

    uv_input: np.ndarray
    confidence: np.ndarray
    found: np.ndarray
    reason: tuple[str, ...]

    def to_image(self, transform: InputTransform) -> PeaksInImage:
        """The same peaks in camera-image pixels."""
        return PeaksInImage(transform.input_to_image(self.uv_input), self.confidence, self.found,
                            self.reason)


@dataclass(frozen=True)
class PeaksInImage:
    """Peaks in camera-image pixels; fields as `PeaksInMap`, `uv_image` (K, 2)."""

    uv_image: np.ndarray
    confidence: np.ndarray
    found: np.ndarray
    reason: tuple[str, ...]


def _check_stride(stride: int) -> int:
    if isinstance(stride, bool) or stride not in _VALID_STRIDES:
        raise InputError(f"output stride must be one of {_VALID_STRIDES}, got {stride!r}")
    return int(stride)


def map_to_input(uv_map: np.ndarray, stride: int) -> np.ndarray:
    """Map pixels (..., 2) -> input pixels (..., 2): `(uv_map + 0.5) * stride - 0.5`."""
    uv = np.asarray(uv_map, dtype=float)
    return (uv + 0.5) * _check_stride(stride) - 0.5


def input_to_map(uv_input: np.ndarray, stride: int) -> np.ndarray:
    """Input pixels (..., 2) -> map pixels (..., 2): `(uv_input + 0.5) / stride - 0.5`."""
    uv = np.asarray(uv_input, dtype=float)
    return (uv + 0.5) / _check_stride(stride) - 0.5


def _windows(maps: np.ndarray, ks: np.ndarray, us: np.ndarray, vs: np.ndarray,
             r: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, m) float64 values and (n, m) inside-the-map flags of the (2r+1)^2 = m pixels around
    each (u, v) of map k (outside pixels read 0), row-major from offset (-r, -r)."""
    _, h, w = maps.shape
    offsets = np.arange(-r, r + 1)
    rows, cols = vs[:, None] + offsets, us[:, None] + offsets          # (n, 2r+1)
    n = len(ks)
    if n and r <= min(vs.min(), us.min()) and vs.max() < h - r and us.max() < w - r:
        # every window lies inside its map (the usual case): no clipping, no masking
        values = maps[ks[:, None, None], rows[:, :, None], cols[:, None, :]].astype(float)
        return values.reshape(n, -1), np.ones((n, (2 * r + 1) ** 2), bool)
    inside = ((rows >= 0) & (rows < h))[:, :, None] & ((cols >= 0) & (cols < w))[:, None, :]
    values = maps[ks[:, None, None], np.clip(rows, 0, h - 1)[:, :, None],
                  np.clip(cols, 0, w - 1)[:, None, :]].astype(float)
    return np.where(inside, values, 0.0).reshape(n, -1), inside.reshape(n, -1)


@lru_cache(maxsize=8)
def _window_design(r: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """du (m,), dv (m,) of the (2r+1)^2 = m window pixels in `_windows`' row-major order, the
    (m, 6) design matrix A of the 2D quadratic (1, du, dv, du^2, dv^2, du dv) and the (m, 36)
    outer products of its rows (so that weights (n, m) @ them are the normal matrices);
    read-only."""
    offsets = np.arange(-r, r + 1, dtype=float)
    du, dv = np.tile(offsets, 2 * r + 1), np.repeat(offsets, 2 * r + 1)
    A = np.stack([np.ones_like(du), du, dv, du * du, dv * dv, du * dv], axis=1)
    outer = (A[:, :, None] * A[:, None, :]).reshape(len(A), 36)
    for a in (du, dv, A, outer):
        a.setflags(write=False)
    return du, dv, A, outer


def _fit_quadratic_log(z: np.ndarray, keep: np.ndarray, r: int) -> np.ndarray:
    """(n, 2) offset (du, dv) of the maximum of a 2D quadratic fitted to log(values) of each
    window (`_windows`) over its `keep` pixels, weighted by the squared values (Guo's
    weighting); exact for a sampled Gaussian. NaN where a fit has no maximum."""
    _, _, A, outer = _window_design(r)
    full = keep.all()                            # every window whole (the usual case)
    zk = z if full else np.where(keep, z, 0.0)   # rows scaled by z -> weighted by z^2
    weight = zk * zk
    normal = (weight @ outer).reshape(-1, 6, 6)
    rhs = (weight * np.log(z if full else np.where(keep, z, 1.0))) @ A
    # normal equations: 6 unknowns on <= (2 r + 1)^2 pixels; with positive weights they are
    # singular exactly when the kept pixels do not fix a quadratic, a property of the pattern
    # (kept pixels weigh z^2 >= _MIN_FIT_FRACTION^2 of the peak's: far from rounding)
    i = np.arange(len(keep)) if full else _solvable(keep, r)   # whole windows fix a quadratic
    if not full:
        normal, rhs = normal[i], rhs[i]
    _, b, c, d, e, f = np.linalg.solve(normal, rhs[:, :, None])[:, :, 0].T
    # maximum where the gradient (b + 2 d x + f y, c + f x + 2 e y) vanishes; the Hessian
    # [[2d, f], [f, 2e]] must be negative definite
    det = 4 * d * e - f * f
    ok = (d < 0) & (det > 0)
    numerator = np.empty((len(i), 2))
    numerator[:, 0], numerator[:, 1] = f * c - 2 * e * b, f * b - 2 * d * c
    if full and ok.all():
        return numerator / det[:, None]
    out = np.full((len(z), 2), np.nan)
    out[i[ok]] = numerator[ok] / det[ok, None]
    return out


def _solvable(keep: np.ndarray, r: int) -> np.ndarray:
    """Indices of the (n, m) window patterns `keep` whose pixels fix a 2D quadratic (the design
    matrix of `_window_design(r)` has rank 6 on them); each pattern's rank is computed once."""
    return np.flatnonzero([_pattern_fixes_quadratic(r, row.tobytes()) for row in keep])


@lru_cache(maxsize=4096)
def _pattern_fixes_quadratic(r: int, keep_bytes: bytes) -> bool:
    keep = np.frombuffer(keep_bytes, dtype=bool)
    return bool(np.linalg.matrix_rank(_window_design(r)[2][keep]) == 6)


def _refine(maps: np.ndarray, ks: np.ndarray, us: np.ndarray, vs: np.ndarray,
            params: PeakSettings) -> np.ndarray:
    """(n, 2) sub-pixel peaks (u, v), map pixels, near the integer maxima (us, vs) of maps
    `ks` of (K, h, w) `maps`: the quadratic fit, or the window's centroid where the fit fails
    or lands farther than the window's radius."""
    r = params.refine_radius
    z, inside = _windows(maps, ks, us, vs, r)
    floor = max(params.refine_floor, _MIN_FIT_FRACTION)
    keep = inside & (z > floor * z.max(axis=1, keepdims=True))
    fit = keep.sum(axis=1) >= _MIN_FIT_PIXELS
    if fit.all():
        offset = _fit_quadratic_log(z, keep, r)
    else:
        offset = np.full((len(ks), 2), np.nan)
        if fit.any():
            offset[fit] = _fit_quadratic_log(z[fit], keep[fit], r)
    bad = ~(np.abs(offset) <= r).all(axis=1)               # NaN (no fit) or too far
    if bad.any():
        du, dv, _, _ = _window_design(r)
        weights = np.clip(z[bad], 0.0, None)
        total = weights.sum(axis=1)
        safe = np.where(total > 0, total, 1.0)
        centroid = np.stack([weights @ du, weights @ dv], axis=1) / safe[:, None]
        offset[bad] = np.where((total > 0)[:, None], centroid, 0.0)
    offset[:, 0] += us
    offset[:, 1] += vs
    return offset


@dataclass(frozen=True)
class _Smoothed:
    """Smoothed maps in a padded layout (`_smooth`): map k's pixel (v, u) is
    `values[k, v + row0, u + col0]`; the padding reads -inf."""

    values: np.ndarray   # (K, H, W) float32
    row0: int
    col0: int

    def at(self, ks: np.ndarray, vs: np.ndarray, us: np.ndarray) -> np.ndarray:
        return self.values[ks, vs + self.row0, us + self.col0]

    def to_map(self, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(vs, us) in map pixels of layout positions (rows, cols)."""
        return rows - self.row0, cols - self.col0


def _smooth(maps: np.ndarray, sigma: float) -> _Smoothed:
    """Each of the (K, h, w) maps smoothed by a Gaussian of `sigma` px (zero outside the map,
    kernel truncated at 4 sigma as scipy's; `sigma` 0: no smoothing), in a (K, h + 2 g, w + 2)
    float32 layout: rows g..g+h-1 and columns 1..w, surrounded by -inf, which keeps the maps
    apart in the local-maximum search (`_local_maxima`). The maps are filtered as one tall
    image whose zero gap rows (2 g >= the kernel's half size) keep them apart."""
    import cv2

    K, h, w = maps.shape
    r = int(np.ceil(_GAUSS_TRUNCATE_SIGMAS * sigma)) if sigma > 0 else 0
    g = max((r + 1) // 2, 1)
    padded = np.zeros((K, h + 2 * g, w + 2), np.float32)
    padded[:, g:g + h, 1:w + 1] = maps
    if r > 0:
        flat = padded.reshape(-1, w + 2)
        cv2.GaussianBlur(flat, (2 * r + 1, 2 * r + 1), sigma, dst=flat,
                         borderType=cv2.BORDER_CONSTANT)
    padded[:, :g] = -np.inf
    padded[:, g + h:] = -np.inf
    padded[:, :, 0] = -np.inf
    padded[:, :, -1] = -np.inf
    return _Smoothed(padded, g, 1)


def _local_maxima(smoothed: _Smoothed, floor: np.ndarray) -> tuple[np.ndarray, ...]:
    """(ks, vs, us) of the map pixels that reach their map's `floor` (K,) (all > 0) and are
    not lower than any of their 8 neighbours in their own map (the outside does not count),
    sorted by map. Only pixels above the floor are compared, so a high floor makes the search
    cheap."""
    padded = smoothed.values
    _, rows, wp = padded.shape
    flat = padded.reshape(-1)
    idx = np.flatnonzero(padded >= np.asarray(floor, np.float32).reshape(-1, 1, 1))
    # the -inf surround is below every floor, so each candidate's 8 neighbours exist
    neighbours = flat[idx[:, None] + _NEIGHBOURS_VU @ np.array([wp, 1])]      # (n, 8)
    idx = idx[flat[idx] >= neighbours.max(axis=1, initial=-np.inf)]
    ks, rest = np.divmod(idx, rows * wp)
    return (ks,) + smoothed.to_map(*np.divmod(rest, wp))


def find_peaks(belief: np.ndarray, params: PeakSettings | None = None) -> PeaksInMap:
    """The peak of each of K belief maps.

    Args:
        belief: (K, h, w) belief maps (float; a perfect peak is 1 on a 0 background).
        params: the peak finder's constants (default `PeakSettings()`).

    Returns:
        `PeaksInMap` with (K, 2) `uv_map` in map pixels, NaN where not found.
    """
    params = PeakSettings() if params is None else params
    belief = np.asarray(belief)
    if belief.ndim != 3 or min(belief.shape) < 1:
        raise InputError(f"belief maps have shape {belief.shape}, expected (K, h, w) with K, h, "
                         f"w >= 1")
    if not np.isfinite(belief).all():
        raise InputError("belief maps contain NaN or infinity")
    K, h, w = belief.shape
    # smoothing and the maximum search in float32 (the network's precision; several times
    # faster than float64), the sub-pixel fit in float64 (`_refine`)
    belief32 = belief.astype(np.float32, copy=False)
    smoothed = _smooth(belief32, params.smoothing_sigma)
    # the best peak is the map's (first) maximum, a local maximum; only maxima above
    # ambiguity_ratio times it can make the map ambiguous, so none below are searched for
    flat = smoothed.values.reshape(K, -1)
    best = flat.argmax(axis=1)
    best_value = flat[np.arange(K), best]
    best_v, best_u = smoothed.to_map(*np.divmod(best, smoothed.values.shape[2]))
    above = best_value >= params.threshold
    ambiguous = np.zeros(K, bool)
    if params.ambiguity_ratio < 1:                 # at 1 no peak is higher than the best
        # maps below the threshold have no maxima above it, whatever their floor
        floor = np.maximum(params.threshold,
                           params.ambiguity_ratio * np.where(above, best_value, 0.0))
        ks, vs, us = _local_maxima(smoothed, floor)
        rival = (np.hypot(us - best_u[ks], vs - best_v[ks]) > params.ambiguity_min_distance) \
            & (smoothed.at(ks, vs, us) > params.ambiguity_ratio * best_value[ks])
        ambiguous[ks[rival]] = True
    confidence = np.where(above, belief32[np.arange(K), best_v, best_u], 0.0).astype(float)
    uv = np.full((K, 2), np.nan)
    ks = (above & ~ambiguous).nonzero()[0]
    inside = np.zeros(K, bool)
    if len(ks):
        refined = _refine(belief32, ks, best_u[ks], best_v[ks], params)
        inside[ks] = ((refined >= -0.5) & (refined <= np.array([w, h]) - 0.5)).all(axis=1)
        uv[ks[inside[ks]]] = refined[inside[ks]]
    found = above & ~ambiguous & inside
    reasons = tuple(FOUND if f else BELOW_THRESHOLD if not a else AMBIGUOUS if m else OUT_OF_FRAME
                    for f, a, m in zip(found.tolist(), above.tolist(), ambiguous.tolist(),
                                       strict=True))
    for a in (uv, confidence, found):
        a.setflags(write=False)
    return PeaksInMap(uv, confidence, found, reasons, w, h)


def find_peaks_batch(belief: np.ndarray, params: PeakSettings | None = None) -> list[PeaksInMap]:
    """`find_peaks` of each of B images' (B, K, h, w) belief maps, found as one set of B * K
    maps (each map is searched alone, so the results are those of `find_peaks` per image; the
    fixed cost of a call is paid once per batch)."""
    belief = np.asarray(belief)
    if belief.ndim != 4:
        raise InputError(f"belief maps have shape {belief.shape}, expected (B, K, h, w)")
    B, K, h, w = belief.shape
    if B == 0:
        return []
    every = find_peaks(belief.reshape(B * K, h, w), params)
    if B == 1:
        return [every]
    return [PeaksInMap(every.uv_map[b * K:(b + 1) * K], every.confidence[b * K:(b + 1) * K],
                       every.found[b * K:(b + 1) * K], every.reason[b * K:(b + 1) * K], w, h)
            for b in range(B)]


def peak_candidates(belief: np.ndarray, params: PeakSettings | None = None,
                    max_per_map: int = 3) -> list[tuple[np.ndarray, np.ndarray]]:
    """The highest local maxima of each of K belief maps, best first (integer map pixels of the
    smoothed maps, no sub-pixel fit): K pairs of (n, 2) `uv_map` and (n,) smoothed values,
    n <= `max_per_map`. For diagnostics and for solvers that weigh alternative peaks."""
    params = PeakSettings() if params is None else params
    maps = np.asarray(belief, dtype=np.float32)
    if maps.ndim != 3:
        raise InputError(f"belief maps have shape {maps.shape}, expected (K, h, w)")
    smoothed = _smooth(maps, params.smoothing_sigma)
    ks, vs, us = _local_maxima(smoothed, np.full(len(maps), params.threshold))
    values = smoothed.at(ks, vs, us)
    bounds = np.searchsorted(ks, np.arange(len(maps) + 1))  # ks is sorted by map
    out = []
    for k in range(len(maps)):
        mine = np.arange(bounds[k], bounds[k + 1])
        best = mine[np.argsort(-values[mine], kind="stable")[:max_per_map]]
        out.append((np.stack([us[best], vs[best]], 1).astype(float), values[best].astype(float)))
    return out


def find_peaks_in_image(belief: np.ndarray, stride: int, transform: InputTransform,
                        params: PeakSettings | None = None) -> PeaksInImage:
    """`find_peaks` on (K, h, w) maps of one image, converted to camera-image pixels."""
    return find_peaks(belief, params).to_input(stride).to_image(transform)
