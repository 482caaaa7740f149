"""An independent check of a time offset between joint readings and images, without keypoints.

With a fixed camera the arm is what moves in the image, so the mean absolute difference of
consecutive frames follows the arm's speed. This script cross-correlates that image-motion
signal with the joint speed (from the distinct joint readings, interpolated at the image times
shifted by a candidate lag) and prints the correlation against the lag: the lag of the peak is
how much the joint readings trail the images (the `time_offset` convention of docs/data_format.md).

    python benchmarks/image_motion_lag.py ../shared/realdata/panda_teleop [--max-lag-s 1.0]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from dream.extended import distinct_readings, interpolate_joints
from dream.io import load_image, read_sequence

LAG_STEP_S = 0.01


def image_motion(sequence) -> np.ndarray:
    """(F,) mean absolute grey-level change to the previous frame (first: the second's)."""
    grey = [load_image(f, sequence.camera).astype(np.float32).mean(axis=2)
            for f in sequence.frames]
    d = np.array([np.mean(np.abs(b - a)) for a, b in zip(grey[:-1], grey[1:], strict=True)])
    return np.concatenate([[d[0]], d])


def joint_speed(times_s: np.ndarray, joints: np.ndarray, query_s: np.ndarray) -> np.ndarray:
    """(Q,) norm of the joint velocity at the query times (distinct readings, interpolated)."""
    t, q = distinct_readings(times_s, joints)
    h = 0.5 * float(np.median(np.diff(t)))
    dq = (interpolate_joints(t, q, query_s + h) - interpolate_joints(t, q, query_s - h)) / (2 * h)
    return np.linalg.norm(dq, axis=1)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", type=Path)
    parser.add_argument("--max-lag-s", type=float, default=1.0)
    args = parser.parse_args()
    seq = read_sequence(args.data)
    times = np.array([f.timestamp for f in seq.frames], dtype=float)
    motion = image_motion(seq)
    lags = np.arange(-args.max_lag_s, args.max_lag_s + 1e-9, LAG_STEP_S)
    inside = (times > times[0] + args.max_lag_s) & (times < times[-1] - args.max_lag_s)
    corr = []
    for lag in lags:
        speed = joint_speed(times, seq.joints, times + lag)
        corr.append(np.corrcoef(motion[inside], speed[inside])[0, 1])
    corr = np.array(corr)
    best = int(np.argmax(corr))
    print(f"{args.data}: {len(seq)} frames, {len(distinct_readings(times, seq.joints)[0])} "
          f"distinct joint readings")
    for lag, c in zip(lags[::10], corr[::10], strict=True):
        print(f"  lag {lag:+.2f} s: correlation {c:+.3f}")
    print(f"peak correlation {corr[best]:.3f} at lag {lags[best]:+.2f} s (joint readings trail "
          f"the images by this much); at lag 0: {corr[np.argmin(np.abs(lags))]:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
