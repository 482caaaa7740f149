"""Belief map -> peak finder -> keypoint: sub-pixel accuracy, ambiguity, borders, coordinates."""

from __future__ import annotations

import numpy as np
import pytest

from dream.errors import InputError
from dream.peaks import (
    AMBIGUOUS,
    BELOW_THRESHOLD,
    FOUND,
    OUT_OF_FRAME,
    PeakSettings,
    find_peaks,
    find_peaks_batch,
    find_peaks_in_image,
    input_to_map,
    map_to_input,
)
from dream.preprocess import Preprocess
from train.targets import belief_maps

MAP_W, MAP_H = 48, 40
SIGMA = 2.0
TOLERANCE_PX = 0.05


def gaussian_map(uv_map: np.ndarray, sigma: float = SIGMA, width: int = MAP_W,
                 height: int = MAP_H) -> np.ndarray:
    """(K, h, w) Gaussians with peak 1 at (K, 2) map pixels (stride 1: map = input)."""
    return belief_maps(np.atleast_2d(uv_map), width, height, 1, sigma)


def test_subpixel_peak_recovered_at_random_positions(rng):
    uv = np.column_stack([rng.uniform(3, MAP_W - 4, 400), rng.uniform(3, MAP_H - 4, 400)])
    for sigma in (1.0, 2.0, 3.0):
        peaks = find_peaks(gaussian_map(uv, sigma))
        assert peaks.found.all() and set(peaks.reason) == {FOUND}
        err = np.linalg.norm(peaks.uv_map - uv, axis=1)
        assert err.max() < TOLERANCE_PX, (sigma, err.max())
        assert np.all(peaks.confidence > 0.5)


def test_subpixel_peak_with_noise_stays_close(rng):
    uv = np.column_stack([rng.uniform(5, MAP_W - 6, 100), rng.uniform(5, MAP_H - 6, 100)])
    maps = gaussian_map(uv) + rng.normal(0, 0.02, (100, MAP_H, MAP_W)).astype(np.float32)
    peaks = find_peaks(maps)
    assert peaks.found.all()
    assert np.median(np.linalg.norm(peaks.uv_map - uv, axis=1)) < 0.15


def test_belief_target_peak_sits_on_the_stride_mapped_keypoint():
    uv_input = np.array([[17.3, 9.8], [np.nan, np.nan]])
    maps = belief_maps(uv_input, 64, 48, 4, 1.5)
    assert maps.shape == (2, 12, 16) and maps.dtype == np.float32
    assert not maps[1].any()  # absent keypoint: all zero
    peaks = find_peaks(maps, PeakSettings(smoothing_sigma=0))
    assert peaks.found.tolist() == [True, False] and peaks.reason[1] == BELOW_THRESHOLD
    np.testing.assert_allclose(peaks.uv_map[0], input_to_map(uv_input[0], 4), atol=1e-6)
    np.testing.assert_allclose(peaks.to_input(4).uv_input[0], uv_input[0], atol=1e-5)
    # peak value 1 at an integer map position
    exact = belief_maps(np.array([map_to_input([5.0, 7.0], 2)]), 32, 32, 2, 2.0)
    assert exact[0, 7, 5] == pytest.approx(1.0) and exact.max() == pytest.approx(1.0)


def test_two_equal_peaks_are_ambiguous_but_a_weak_second_peak_is_not():
    two = gaussian_map(np.array([[10.2, 12.0]])) + gaussian_map(np.array([[35.0, 25.5]])) * 0.9
    peaks = find_peaks(two)
    assert not peaks.found[0] and peaks.reason[0] == AMBIGUOUS
    assert np.isnan(peaks.uv_map[0]).all()
    weak = gaussian_map(np.array([[10.2, 12.0]])) + gaussian_map(np.array([[35.0, 25.5]])) * 0.3
    peaks = find_peaks(weak)
    assert peaks.found[0]
    np.testing.assert_allclose(peaks.uv_map[0], [10.2, 12.0], atol=0.1)
    # the ratio is a parameter
    assert find_peaks(weak, PeakSettings(ambiguity_ratio=0.2)).reason[0] == AMBIGUOUS


def test_out_of_frame_keypoint_is_not_found():
    outside = np.array([[-1.5, 20.0], [MAP_W + 0.5, 3.0], [20.0, -30.0], [np.nan, np.nan]])
    peaks = find_peaks(gaussian_map(outside))
    assert not peaks.found.any()
    assert peaks.reason[0] == OUT_OF_FRAME and peaks.reason[1] == OUT_OF_FRAME
    assert peaks.reason[2] == BELOW_THRESHOLD and peaks.reason[3] == BELOW_THRESHOLD


def test_keypoint_near_the_border_is_found(rng):
    near = np.array([[0.3, 20.0], [MAP_W - 1.2, 5.0], [10.0, 0.0], [MAP_W - 1.0, MAP_H - 1.0],
                     [-0.4, 15.0]])
    peaks = find_peaks(gaussian_map(near))
    assert peaks.found.all(), peaks.reason
    np.testing.assert_allclose(peaks.uv_map, near, atol=TOLERANCE_PX)
    # a mostly outside Gaussian is found only when it reaches the threshold
    faint = gaussian_map(np.array([[-0.45, 20.0]])) * 0.08
    assert find_peaks(faint, PeakSettings(threshold=0.1)).reason[0] == BELOW_THRESHOLD
    assert find_peaks(faint, PeakSettings(threshold=0.01)).found[0]


def test_maps_refined_together_match_maps_refined_alone(rng):
    """The sub-pixel fits of all maps are solved as one batch: a map whose fit fails (a flat
    plateau: its centroid is used), a border peak and interior peaks give the same result as
    each map alone."""
    uv = np.array([[0.3, 17.2], [20.4, 11.7], [MAP_W - 1.2, MAP_H - 0.8], [33.6, 5.1]])
    maps = gaussian_map(uv)
    maps[1] = 0.0
    maps[1, 10:13, 20:23] = 0.9                 # plateau 3 x 3 centred on (21, 11)
    together = find_peaks(maps)
    assert together.found.all()
    assert np.allclose(together.uv_map[1], [21.0, 11.0])
    for k in range(len(maps)):
        alone = find_peaks(maps[k:k + 1])
        assert alone.reason[0] == together.reason[k]
        # equal up to the rounding of a batched BLAS product (no cross-talk between maps)
        np.testing.assert_allclose(alone.uv_map[0], together.uv_map[k], rtol=0, atol=1e-9)
    assert np.linalg.norm(together.uv_map[[0, 2, 3]] - uv[[0, 2, 3]], axis=1).max() < \
        TOLERANCE_PX


def test_map_input_image_conversions_round_trip(rng):
    uv_map = rng.uniform(-1, 40, (20, 2))
    for stride in (1, 2, 4):
        uv_input = map_to_input(uv_map, stride)
        np.testing.assert_allclose(input_to_map(uv_input, stride), uv_map, atol=1e-12)
    # centre of map pixel 0 = centre of input pixels 0..s-1
    assert map_to_input(np.zeros(2), 4).tolist() == [1.5, 1.5]
    pre = Preprocess(64, 48, mode="letterbox")
    t = pre.transform_for(640, 400)
    uv_image = np.array([[100.0, 200.0], [639.0, 0.0]])
    uv_in = t.image_to_input(uv_image)
    maps = belief_maps(uv_in, 64, 48, 2, 1.5)
    peaks = find_peaks_in_image(maps, 2, t)
    np.testing.assert_allclose(peaks.uv_image, uv_image, atol=TOLERANCE_PX * 2 * 10)
    assert peaks.found.all()


def test_bad_inputs_are_input_errors():
    with pytest.raises(InputError):
        find_peaks(np.zeros((4, 4)))
    with pytest.raises(InputError):
        find_peaks(np.full((1, 4, 4), np.nan))
    with pytest.raises(InputError, match="K, h, w >= 1"):
        find_peaks(np.zeros((0, 4, 4)))                  # no maps
    assert find_peaks_batch(np.zeros((0, 7, 4, 4))) == []  # no images
    with pytest.raises(InputError):
        PeakSettings(threshold=0)
    with pytest.raises(InputError):
        PeakSettings(ambiguity_ratio=1.5)
    with pytest.raises(InputError):
        map_to_input(np.zeros(2), 3)


def test_peak_overrides_apply_on_a_base_and_name_the_option():
    from dataclasses import replace

    from dream.errors import InputError
    from dream.peaks import PeakSettings, peak_params_from_overrides

    base = replace(PeakSettings(), threshold=0.2)
    params = peak_params_from_overrides(["ambiguity_ratio=1.0", "refine_radius=3"], "--peaks", base)
    assert (params.ambiguity_ratio, params.refine_radius, params.threshold) == (1.0, 3, 0.2)
    with pytest.raises(InputError, match="--peaks colour=1: expected NAME=VALUE"):
        peak_params_from_overrides(["colour=1"], "--peaks")
    with pytest.raises(InputError, match="'high' is not a number"):
        peak_params_from_overrides(["threshold=high"], "--peaks")
    with pytest.raises(InputError, match="ambiguity_ratio must be in"):
        peak_params_from_overrides(["ambiguity_ratio=2"], "--peaks")


def test_local_maxima_match_a_brute_force_search_borders_included(rng):
    from dream.peaks import _local_maxima, _smooth

    maps = rng.random((3, 9, 11)).astype(np.float32)
    maps[1, 4:6, 4:6] = 2.0  # a plateau: every pixel of it counts
    expected = set()
    for k, v, u in zip(*np.nonzero(maps >= 0.5), strict=True):
        window = maps[k, max(v - 1, 0):v + 2, max(u - 1, 0):u + 2]
        if maps[k, v, u] >= window.max():
            expected.add((int(k), int(v), int(u)))
    ks, vs, us = _local_maxima(_smooth(maps, 0.0), np.full(3, 0.5))
    assert set(zip(ks.tolist(), vs.tolist(), us.tolist(), strict=True)) == expected
    assert list(ks) == sorted(ks)
    assert {(1, 4, 4), (1, 5, 5)} <= expected


def test_smoothing_keeps_maps_apart_and_matches_scipy(rng):
    from scipy.ndimage import gaussian_filter

    from dream.peaks import _smooth

    maps = rng.random((4, 12, 10)).astype(np.float32)
    for sigma in (0.0, 0.7, 1.0, 2.0):
        expected = np.stack([gaussian_filter(m.astype(float), sigma, mode="constant", truncate=4.0)
                             for m in maps])
        smoothed = _smooth(maps, sigma)
        padded, top = smoothed.values, smoothed.row0
        assert padded.shape == (4, 12 + 2 * top, 12) and top >= 1 and smoothed.col0 == 1
        assert np.allclose(padded[:, top:top + 12, 1:-1], expected, atol=1e-5)
        outside = np.ones(padded.shape[1:], bool)
        outside[top:top + 12, 1:-1] = False
        assert np.all(padded[:, outside] == -np.inf)


def test_peak_candidates_list_the_highest_maxima_best_first():
    from dream.peaks import peak_candidates

    maps = np.zeros((2, 30, 40), np.float32)
    for (u, v), height in (((5, 6), 0.5), ((20, 15), 1.0), ((33, 25), 0.8)):
        maps[0] += height * np.exp(-((np.arange(40) - u) ** 2)[None, :] / 4
                                   - ((np.arange(30) - v) ** 2)[:, None] / 4)
    (uv0, value0), (uv1, value1) = peak_candidates(maps, max_per_map=2)
    assert np.array_equal(uv0, [[20, 15], [33, 25]])
    assert value0[0] > value0[1] > 0.5
    assert uv1.shape == (0, 2) and value1.shape == (0,)


def test_batch_of_images_gives_the_peaks_of_each_image(rng):
    """`find_peaks_batch` searches B images' maps as one set: the same peaks, confidences and
    reasons as `find_peaks` per image (a missing and an ambiguous keypoint included)."""
    images = []
    for _ in range(3):
        maps = gaussian_map(rng.uniform(2, [MAP_W - 3, MAP_H - 3], (4, 2)))
        maps[1] = 0.0                                     # not found
        maps[2] += gaussian_map(np.array([[2.0, 2.0]]))[0]  # a second, distant peak
        images.append(maps)
    batch = find_peaks_batch(np.stack(images))
    assert len(batch) == 3
    for maps, peaks in zip(images, batch, strict=True):
        alone = find_peaks(maps)
        assert peaks.reason == alone.reason and peaks.reason[1] == BELOW_THRESHOLD
        np.testing.assert_allclose(peaks.uv_map, alone.uv_map, rtol=0, atol=1e-9)
        assert np.array_equal(peaks.confidence, alone.confidence)
        assert (peaks.map_width, peaks.map_height) == (MAP_W, MAP_H)
    assert AMBIGUOUS in {batch[k].reason[2] for k in range(3)}
    with pytest.raises(InputError, match=r"expected \(B, K, h, w\)"):
        find_peaks_batch(images[0])
