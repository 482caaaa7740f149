"""Motion blur (`sensor.exposure_s`): a frame is the arm's path over the shutter's exposure."""

from __future__ import annotations

import numpy as np
import pytest

from dream.errors import InputError
from dream.robot import load_robot
from synth.config import config_from_dict
from synth.exposure import mean_exposure
from synth.frames import FrameMaker

SMALL = {"width": 160, "height": 120, "fx": 165.0, "fy": 160.0, "cx": 80.0, "cy": 60.0}
MOVING_FRAME = 20          # 0.67 s into the first waypoint blend: the arm at its fastest


def _frames(robot, config: dict, indices) -> list:
    maker = FrameMaker(robot, config_from_dict(config), seed=3)
    try:
        return [maker.make(i) for i in indices]
    finally:
        maker.close()


def test_an_exposed_frame_is_the_mean_light_of_the_arm_along_its_path():
    """At 30 frames/s with an exposure of 1/30 s drawn by 3 renders, frame i is the mean in
    linear light of frames 2i-1, 2i, 2i+1 of the same trajectory at 60 frames/s without one;
    its labels, segmentation and joint readings are those at the middle of the exposure."""
    robot = load_robot("panda")
    base = {"intrinsics": SMALL, "camera": {"closeup_prob": 0.0}}
    exposed = _frames(robot, base | {"sequence": {"mode": "trajectory", "fps": 30.0},
                                     "sensor": {"exposure_s": 1 / 30, "exposure_samples": 3}},
                      [MOVING_FRAME])[0]
    steps = _frames(robot, base | {"sequence": {"mode": "trajectory", "fps": 60.0}},
                    [2 * MOVING_FRAME - 1, 2 * MOVING_FRAME, 2 * MOVING_FRAME + 1])
    middle = steps[1]
    assert not np.array_equal(steps[0].link_ids, steps[2].link_ids)     # the arm moved
    assert np.array_equal(exposed.rgb, mean_exposure([s.rgb for s in steps]))
    assert not np.array_equal(exposed.rgb, middle.rgb)
    assert np.array_equal(exposed.link_ids, middle.link_ids)
    assert np.array_equal(exposed.uv, middle.uv, equal_nan=True)
    assert np.array_equal(exposed.joints, middle.joints)
    assert exposed.timestamp == pytest.approx(middle.timestamp)


@pytest.mark.parametrize(("values", "message"), [
    ({"sensor": {"exposure_s": 0.01}}, "needs sequence.mode trajectory"),
    ({"sensor": {"exposure_s": 0.01}, "sequence": {"mode": "fixed_camera"}},
     "needs sequence.mode trajectory"),
    ({"sensor": {"exposure_s": 10.0}, "sequence": {"mode": "trajectory"}},   # milliseconds
     "longer than a frame"),
    ({"sensor": {"exposure_s": 0.01, "exposure_samples": 0}, "sequence": {"mode": "trajectory"}},
     "exposure_samples"),
])
def test_an_exposure_the_recipe_cannot_draw_is_refused(values, message):
    with pytest.raises(InputError, match=message):
        config_from_dict(values)
