"""`benchmarks/shadow_masks.py`: the motion masks of a scene with cast shadows, against its
rendered robot masks, with and without the shadow test."""

from __future__ import annotations

from tests.benchmark_scripts import load_benchmark


def test_the_shadow_test_raises_the_masks_precision_in_a_scene_with_shadows(tmp_path):
    bench = load_benchmark("shadow_masks")
    data = bench.render("panda", 1000, 8, True, tmp_path / "scene")
    found = bench.counts(data, {"without": None, "with": bench.ShadowSettings()})
    without, with_test = found["without"], found["with"]
    precision = [tp / (tp + fp) for tp, fp, _ in (without, with_test)]
    assert precision[1] > precision[0] + 0.1, precision
    recall = [tp / (tp + fn) for tp, _, fn in (without, with_test)]
    assert recall[1] > recall[0] - 0.1, recall
    assert "precision 0.500 recall 0.250" in bench.shares((1, 1, 3))
