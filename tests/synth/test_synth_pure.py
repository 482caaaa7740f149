"""Synth recipe, per-frame randomness and labels: the parts that need no rendering."""

import colorsys
import io

import numpy as np
import pytest

from dream.errors import InputError
from dream.robot import load_robot
from dream.transforms import transform_points
from synth.config import config_from_dict, load_config
from synth.labels import OCCLUDED_DISTRACTOR, OCCLUDED_SELF, OUT_OF_FRAME, VISIBLE, keypoint_labels
from synth.randomize import _jitter_color, sample_frame, trajectory_joints

PANDA = load_robot("panda")
RGBA = np.tile([0.9, 0.9, 0.9, 1.0], (5, 1))


def frame(seed, index, config):
    return sample_frame(seed, index, PANDA, config, RGBA, 4, 6, 4)


@pytest.mark.parametrize("values, words", [
    ({"camera": {"radius": [1, 2]}}, "unknown config key .camera.radius."),
    ({"camera": {"radius_m": [2, 1]}}, "low <= high"),
    ({"lights": {"count": [0, 2]}}, "lights.count"),
    ({"intrinsics": {"fx": 100}}, "all of fx, fy, cx, cy"),
    ({"sequence": {"mode": "loop"}}, "sequence.mode"),
    ({"sensor": {"gain_sigma": -0.1}}, "sensor.gain_sigma"),
    ({"sensor": {"noise_std": -1}}, "sensor.noise_std"),
    ({"sensor": {"blur_px": -0.5}}, "sensor.blur_px"),
    ({"background": {"kinds": {"plaid": 1}}}, "unknown kinds"),
    ({"nonsense": {}}, "unknown config key .nonsense."),
    ({"lights": {"intensity": "bright"}}, "lights.intensity"),
    ({"distractors": {"held_prob": 1.5}}, "distractors.held_prob"),
    ({"distractors": {"held_offset_m": [0.2, 0.1]}}, "distractors.held_offset_m"),
    ({"distractors": {"held_parts": [0, 2]}}, "distractors.held_parts"),
    ({"distractors": {"robot_prob": 2}}, "distractors.robot_prob"),
    ({"distractors": {"robot_moves": "yes"}}, "distractors.robot_moves"),
    ({"distractors": {"loose_prob": -0.5}}, "distractors.loose_prob"),
    ({"distractors": {"loose_keypoints": 0}}, "distractors.loose_keypoints"),
    ({"distractors": {"loose_keypoints": 1.5}}, "distractors.loose_keypoints"),
    ({"distractors": {"loose_height_m": [0.5, 0.1]}}, "distractors.loose_height_m"),
    ({"distractors": {"robot_distance_m": [2.0, 1.0]}}, "distractors.robot_distance_m"),
    ({"camera": {"closeup_prob": -0.1}}, "camera.closeup_prob"),
    ({"camera": {"closeup_radius_m": [0.0, 0.5]}}, "camera.closeup_radius_m"),
    ({"appearance": {"white_plastic_prob": 0.7, "metal_prob": 0.5}}, "at most 1"),
    ({"lights": {"elevation_rad": [20, 80]}}, "lights.elevation_rad"),   # degrees by mistake
    ({"lights": {"count": [1, 40]}}, "lights.count"),
    ({"lights": {"intensity": [1.0, 0.2]}}, "lights.intensity"),
    ({"distractors": {"size_m": [-0.2, -0.1]}}, "distractors.size_m"),
    ({"appearance": {"saturation": [0, 5]}}, "appearance.saturation"),
    ({"appearance": {"hue_jitter": -0.1}}, "appearance.hue_jitter"),
    ({"appearance": {"reflectance": [0, 1]}}, "unknown config key .appearance.reflectance."),
    ({"output": {"jpeg_quality": 500}}, "output.jpeg_quality"),
    ({"camera": {"target_jitter_m": -0.1}}, "camera.target_jitter_m"),
    ({"camera": {"target_m": [0.0, float("nan"), 0.4]}},
     r"camera.target_m\[1\] must be a finite number.*Fix: give camera.target_m"),
    ({"background": {"photos": "photos/"}}, "kinds.photo is 0"),
    ({"background": {"kinds": {"photo": 1.0}}}, "needs background.photos"),
    ({"intrinsics": {"fx": -5, "fy": 300, "cx": 160, "cy": 120}},
     r"intrinsics.fx must be a focal length > 0 .*Fix: set intrinsics.fx"),
    ({"intrinsics": {"fx": 300, "fy": float("inf"), "cx": 160, "cy": 120}},
     "intrinsics.fy must be a finite number"),
    ({"intrinsics": {"fx": 300, "fy": 300, "cx": float("nan"), "cy": 120}},
     "intrinsics.cx must be a finite number"),
    ({"intrinsics": {"width": 20000}},
     r"intrinsics.width must be a whole number of pixels from 1 to 4096, got 20000"),
    ({"intrinsics": {"height": 0}}, "intrinsics.height must be a whole number of pixels"),
    ({"intrinsics": {"distortion": [float("nan"), 0, 0, 0, 0]}},
     "intrinsics.distortion must be 5 finite plumb_bob coefficients"),
])
def test_bad_recipes_are_refused_with_the_reason(values, words):
    with pytest.raises(InputError, match=words):
        config_from_dict(values)


def test_shipped_recipes_load():
    for name in ("default", "panda_teleop_like"):
        load_config(f"configs/synth/{name}.yaml")
    with pytest.raises(InputError, match="No such file"):
        load_config("configs/synth/missing.yaml")
    recipe = load_config("configs/synth/default.yaml", ["camera.radius_m=[1.5, 1.6]"])
    assert recipe.camera.radius_m == (1.5, 1.6) and recipe.lights.count == (1, 4)


def test_default_recipe_file_is_the_built_in_recipe():
    """`dream synth` without --config renders `configs/synth/default.yaml` (its help says so)."""
    assert load_config("configs/synth/default.yaml") == load_config(None)


@pytest.mark.parametrize("jitter", [0.05, 0.2])
def test_hue_jitter_moves_the_hue_by_at_most_its_fraction(jitter):
    config = config_from_dict({"appearance": {"hue_jitter": jitter, "saturation": [0.9, 0.9]}})
    rng = np.random.default_rng(0)
    red = np.array([1.0, 0.0, 0.0, 1.0])
    hues = np.array([colorsys.rgb_to_hsv(*_jitter_color(rng, red, config)[:3])[0]
                     for _ in range(2000)])
    moved = np.minimum(hues, 1.0 - hues)               # circular distance from red (hue 0)
    assert moved.max() <= jitter + 1e-9 and moved.max() > 0.9 * jitter
    full = config_from_dict({})                         # the default 0.5: any hue
    hues = [colorsys.rgb_to_hsv(*_jitter_color(rng, red, full)[:3])[0] for _ in range(2000)]
    assert np.histogram(hues, bins=10, range=(0, 1))[0].min() > 150


def test_each_frame_depends_only_on_seed_and_index():
    config = config_from_dict({})
    a, b = frame(5, 17, config), frame(5, 17, config)
    assert np.array_equal(a.joints, b.joints)
    assert np.array_equal(a.scene.T_cam_base, b.scene.T_cam_base)
    assert a.scene.background_seed == b.scene.background_seed
    c = frame(5, 18, config)
    assert not np.array_equal(a.joints, c.joints)
    assert not np.array_equal(a.scene.T_cam_base, c.scene.T_cam_base)
    assert not np.array_equal(frame(6, 17, config).joints, a.joints)


def test_sequence_modes_fix_the_camera_and_scene():
    for mode in ("fixed_camera", "trajectory"):
        config = config_from_dict({"sequence": {"mode": mode, "fps": 30}})
        f0, f9 = frame(1, 0, config), frame(1, 9, config)
        assert np.array_equal(f0.scene.T_cam_base, f9.scene.T_cam_base)
        assert f0.scene.background_seed == f9.scene.background_seed
        assert f0.scene is not f9.scene and len(f0.scene.lights) == len(f9.scene.lights)
        assert f9.timestamp == pytest.approx(9 / 30)
        assert not np.array_equal(f0.joints, f9.joints)


def test_held_object_is_drawn_apart_from_everything_else():
    """held_prob = 0 draws exactly what older recipes drew; with it, an object at the last
    keypoint link within the recipe's size and offset, fixed along a sequence."""
    recipe = {"distractors": {"held_prob": 1.0, "held_board_prob": 1.0,
                              "held_size_m": [0.1, 0.2], "held_offset_m": [0.05, 0.08]}}
    for i in range(5):
        plain, held = frame(3, i, config_from_dict({})), frame(3, i, config_from_dict(recipe))
        assert plain.scene.held is None and held.scene.held is not None
        assert np.array_equal(plain.joints, held.joints)
        assert np.array_equal(plain.scene.T_cam_base, held.scene.T_cam_base)
        assert [d.position_m.tolist() for d in plain.scene.distractors] == \
            [d.position_m.tolist() for d in held.scene.distractors]
        h = held.scene.held
        assert h.link == PANDA.keypoint_names[-1] and h.parts[0].kind == "box"
        assert 0.05 <= h.parts[0].size_m[0] <= 0.1            # half of the largest side
        assert np.all(h.parts[0].size_m[1] <= h.parts[0].size_m[0])
        assert h.parts[0].size_m[2] <= 0.01                   # a thin plate
        assert 0.05 <= np.linalg.norm(h.parts[0].position_m) <= 0.08
        assert np.linalg.norm(h.parts[0].quaternion_wxyz) == pytest.approx(1.0)
    sequence = config_from_dict({**recipe, "sequence": {"mode": "trajectory"}})
    first, later = frame(3, 0, sequence).scene.held, frame(3, 9, sequence).scene.held
    assert np.array_equal(first.parts[0].position_m, later.parts[0].position_m)
    assert np.array_equal(first.parts[0].size_m, later.parts[0].size_m)
    some = config_from_dict({"distractors": {"held_prob": 0.5}})
    count = sum(frame(8, i, some).scene.held is not None for i in range(200))
    assert 70 < count < 130


def test_trajectory_is_smooth_and_within_limits():
    config = config_from_dict({"sequence": {"mode": "trajectory", "fps": 30,
                                            "waypoint_period_s": 1.0}})
    q = np.array([trajectory_joints(2, i, PANDA, config, None) for i in range(120)])
    assert np.all(q >= PANDA.joint_lower - 1e-12) and np.all(q <= PANDA.joint_upper + 1e-12)
    step = np.abs(np.diff(q, axis=0)).max()
    span = (PANDA.joint_upper - PANDA.joint_lower).max()
    assert step < span * np.pi / 2 / 30  # max speed of the cosine blend, per frame


def test_occlusion_rule():
    config = config_from_dict({})
    f = frame(0, 3, config)
    K = len(PANDA.keypoint_names)
    P_cam = transform_points(f.scene.T_cam_base, PANDA.forward_kinematics(f.joints))
    kw = dict(robot=PANDA, P_cam=P_cam, camera=f.scene.camera)
    labels = keypoint_labels(**kw)
    assert all(o in (VISIBLE, OUT_OF_FRAME) for o in labels.occlusion)
    assert [o == OUT_OF_FRAME for o in labels.occlusion] == list(~labels.in_frame)
    dist = np.linalg.norm(labels.P_cam, axis=1)
    inside = labels.in_frame
    # a distractor just in front of every keypoint
    occ = keypoint_labels(**kw, hit_link=[None] * K, hit_distractor=np.ones(K, bool),
                          hit_distance_m=dist - 0.01)
    assert all(o == OCCLUDED_DISTRACTOR for o, i in zip(occ.occlusion, inside, strict=True) if i)
    # the base link far in front of the hand: self-occlusion; the hand's own link: visible
    hand = PANDA.keypoint_names.index("panda_hand")
    links = [None] * K
    links[hand] = "panda_link0"
    occ = keypoint_labels(**kw, hit_link=links, hit_distractor=np.zeros(K, bool),
                          hit_distance_m=np.where(np.arange(K) == hand, dist - 0.3, np.inf))
    assert occ.occlusion[hand] == (OCCLUDED_SELF if inside[hand] else OUT_OF_FRAME)
    links[hand] = "panda_link7"
    occ = keypoint_labels(**kw, hit_link=links, hit_distractor=np.zeros(K, bool),
                          hit_distance_m=np.where(np.arange(K) == hand, dist - 0.3, np.inf))
    assert occ.occlusion[hand] in (VISIBLE, OUT_OF_FRAME)


def test_joints_drawn_around_a_joint_log(tmp_path):
    from synth.randomize import load_joint_log, sample_joints

    log_q = np.array([[0.1, -0.5, 0.2, -2.0, 0.3, 1.5, 0.7], [0.0, 0.2, 0.0, -1.0, 0.0, 1.0, 0.0]])
    path = tmp_path / "log.txt"
    path.write_text("# joints, rad\n" + "\n".join(" ".join(map(str, q)) for q in log_q))
    q_log = load_joint_log(path, PANDA)
    config = config_from_dict({"joints": {"log": str(path), "log_noise_rad": 0.01}})
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = sample_joints(rng, PANDA, config, q_log)
        assert np.min(np.abs(q - log_q).max(axis=1)) < 0.06
    path.write_text("1 2 3\n")
    with pytest.raises(InputError, match="rows of 7"):
        load_joint_log(path, PANDA)


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


@pytest.mark.parametrize("stream_type", [io.StringIO, _Terminal])
def test_progress_rewrites_a_line_only_on_a_terminal(stream_type, monkeypatch):
    """Piped to a file, progress is whole lines (no carriage returns piling up in one line);
    on a terminal, one line rewritten in place and ended when the work is done."""
    from synth import cli

    clock = iter(range(0, 1000, 4))                  # 4 s between readings
    monkeypatch.setattr(cli.time, "perf_counter", lambda: float(next(clock)))
    stream = stream_type()
    progress = cli.Progress(stream)
    progress.begin(10, 0)
    for _ in range(10):
        progress.update(1)
    progress.close()
    text = stream.getvalue()
    assert text.endswith("synth: 10/10 frames, 0.2 frames/s, 0 s left" +
                         (" \n" if stream_type is _Terminal else "\n"))
    if stream_type is _Terminal:
        assert text.count("\r") == 10 and text.count("\n") == 1       # every 1 s: each update
    else:
        assert "\r" not in text and text.count("\n") == 4              # every 10 s, and the end


def test_the_sensor_s_blur_turns_a_sharp_edge_into_a_ramp_centred_on_it():
    """`sensor.blur_px`: a Gaussian of that many pixels, alone (no gain, no noise): the pixels
    either side of a step keep their sum and lie half a pixel either side of its middle."""
    from scipy.stats import norm

    from synth.realism import sensor_effects

    rgb = np.zeros((21, 20, 3), np.uint8)
    rgb[:, 10:] = 200
    out = sensor_effects(rgb, 0, 0, config_from_dict({"sensor": {"blur_px": 1.0}}))
    row = out[10, :, 0].astype(float)
    assert row[0] == 0 and row[-1] == 200 and np.all(np.diff(row) >= 0)
    assert row[9] == pytest.approx(200 * norm.cdf(-0.5), abs=2)
    assert row[9] + row[10] == pytest.approx(200, abs=1)
    assert np.array_equal(sensor_effects(rgb, 0, 0, config_from_dict({})), rgb)
