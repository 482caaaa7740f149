"""Per-frame work over threads: same results, same order, the user's thread count."""

import threading

import numpy as np
import pytest

from dream.errors import InputError
from dream.silhouette import render_frames, render_points
from dream.threads import THREADS_ENV, map_frames, thread_count


def test_map_frames_keeps_the_order_and_runs_in_workers(monkeypatch):
    monkeypatch.setenv(THREADS_ENV, "3")
    names = map_frames(lambda k: (k, threading.current_thread().name), range(20))
    assert [k for k, _ in names] == list(range(20))
    assert any(name.startswith("dream-frames") for _, name in names)


def test_one_thread_runs_in_the_caller(monkeypatch):
    monkeypatch.setenv(THREADS_ENV, "1")
    caller = threading.current_thread().name
    assert map_frames(lambda k: threading.current_thread().name, range(5)) == [caller] * 5


def test_work_started_in_a_worker_stays_in_that_worker(monkeypatch):
    monkeypatch.setenv(THREADS_ENV, "2")

    def outer(k: int) -> list[str]:
        return map_frames(lambda j: threading.current_thread().name, range(4))

    for inner in map_frames(outer, range(6)):    # would deadlock on a shared pool
        assert len(set(inner)) == 1


@pytest.mark.parametrize("text", ["0", "two", "-1", "1.5"])
def test_a_bad_thread_count_says_how_to_set_it(monkeypatch, text):
    monkeypatch.setenv(THREADS_ENV, text)
    with pytest.raises(InputError, match=THREADS_ENV):
        thread_count()


def test_the_default_uses_the_cores(monkeypatch):
    monkeypatch.delenv(THREADS_ENV, raising=False)
    assert thread_count() >= 1


def test_rendered_frames_are_the_same_in_parallel(monkeypatch, panda, meshes):
    from dream.camera import CameraIntrinsics
    from dream.silhouette import vertices_in_base

    camera = CameraIntrinsics(200.0, 200.0, 79.5, 59.5, 160, 120)
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [0, 0, -1], [1, 0, 0]]   # looking along +x of the base
    T[:3, 3] = [0.0, 0.4, 1.6]
    rng = np.random.default_rng(0)
    P = np.stack([vertices_in_base(meshes, rng.uniform(-0.5, 0.5, panda.num_joints))
                  for _ in range(5)])
    monkeypatch.setenv(THREADS_ENV, "2")
    parallel = render_frames(P, meshes.faces, T, camera)
    assert parallel.shape == (5, 120, 160) and parallel.any(axis=(1, 2)).all()
    assert all(np.array_equal(parallel[k], render_points(P[k], meshes.faces, T, camera))
               for k in range(5))
    assert render_frames(P[:0], meshes.faces, T, camera).shape == (0, 120, 160)
