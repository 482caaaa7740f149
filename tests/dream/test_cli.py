"""End to end through the command line: sample -> calibrate -> eval, real data, bad input."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from dream.camera import project
from dream.cli import CalibrateRequest, SampleRequest, build_parser, main, run_calibrate
from dream.errors import InputError
from dream.io import read_sequence, write_dream
from dream.metrics import pose_errors
from dream.robot import load_robot
from dream.transforms import transform_points


def run(argv: list[str], capsys) -> tuple[int, str, str]:
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def sample_dir(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("sample") / "data"
    assert main(["sample", "--out", str(out), "--num", "15", "--outliers", "0.1",
                 "--seed", "3"]) == 0
    return out


def test_sample_calibrate_eval_end_to_end(sample_dir, tmp_path, capsys):
    result = tmp_path / "result.json"
    code, out, err = run(["calibrate", "--data", sample_dir, "--use-labels", "--out", result],
                         capsys)
    assert code == 0, err
    assert "error vs ground truth" in out
    doc = json.loads(result.read_text())
    for key in ("T_cam_base", "translation_m", "quaternion_xyzw", "rmse_px", "frames_used",
                "keypoints_used", "sigma_translation_m", "sigma_rotation_rad", "per_frame"):
        assert key in doc
    assert doc["frames_used"] == 15 and len(doc["per_frame"]) == 15
    kp = doc["per_frame"][0]["keypoints"][0]
    assert set(kp) == {"name", "uv", "confidence", "inlier"}
    truth = read_sequence(sample_dir).T_cam_base_reference
    t_err, r_err = pose_errors(np.array(doc["T_cam_base"]), truth)
    assert t_err < 3 * np.linalg.norm(doc["sigma_camera_position_base_m"]) + 1e-4
    # the reported sigma: the fit's covariance plus the keypoint jackknife's, plus the move
    # through the focal length the keypoints ask for (nothing else checked it)
    unc = doc["uncertainty"]
    assert unc["method"] == ("fit + keypoint jackknife + the move through the focal length "
                             "the keypoints ask for")
    assert len(unc["keypoint_jackknife_left_out"]) >= 3
    xi = np.array(doc["keypoint_focal"]["xi_asked"])
    total = np.array(unc["covariance_xi_fit"]) \
        + np.array(unc["covariance_xi_keypoint_jackknife"]) + np.outer(xi, xi)
    np.testing.assert_allclose(doc["covariance_xi"], total)
    np.testing.assert_allclose(doc["sigma_translation_m"], np.sqrt(np.diag(total)[3:]))
    np.testing.assert_allclose(doc["sigma_rotation_rad"], np.sqrt(np.diag(total)[:3]))
    assert "keypoint left out" in out
    metrics_path = tmp_path / "metrics.json"
    code, out, err = run(["eval", "--data", sample_dir, "--result", result, "--out",
                          metrics_path], capsys)
    assert code == 0, err
    metrics = json.loads(metrics_path.read_text())
    assert metrics["add_auc"] > 0.9
    assert metrics["translation_error_m"]["median"] == pytest.approx(t_err)
    assert 0.5 < metrics["keypoint_l2_px"]["median"] < 2.0  # 1 px noise per axis
    # each mode: every frame alone
    code, out, err = run(["calibrate", "--data", sample_dir, "--use-labels", "--frames", "each",
                          "--out", tmp_path / "each.json"], capsys)
    assert code == 0, err
    each = json.loads((tmp_path / "each.json").read_text())
    assert each["frames_mode"] == "each"
    # the reported frame's fit plus its own keypoint jackknife
    unc = each["uncertainty"]
    assert unc["method"] == "fit + keypoint jackknife"
    assert len(unc["keypoint_jackknife_left_out"]) >= 3
    total = np.array(unc["covariance_xi_fit"]) + np.array(unc["covariance_xi_keypoint_jackknife"])
    np.testing.assert_allclose(each["covariance_xi"], total)
    assert "of the frame with one keypoint left out" in out
    solved = [np.array(f["T_cam_base"]) for f in each["per_frame"] if f["T_cam_base"]]
    unsolved = [f for f in each["per_frame"] if not f["T_cam_base"]]
    assert len(solved) >= 8 and all("no_solution_reason" in f for f in unsolved)
    assert np.median([pose_errors(T, truth)[0] for T in solved]) < 0.05


def test_overlays_are_written_for_keypoint_only_data(sample_dir, tmp_path, capsys):
    code, _, err = run(["calibrate", "--data", sample_dir, "--use-labels", "--out",
                        tmp_path / "r.json", "--overlays", tmp_path / "ov"], capsys)
    assert code == 0, err
    assert (tmp_path / "ov" / "summary.png").is_file()
    assert len(list((tmp_path / "ov").glob("*.result.png"))) == 15


def test_panda_teleop_recovers_its_reference_from_projected_labels(realdata, tmp_path, capsys):
    seq = read_sequence(realdata / "panda_teleop")
    robot = load_robot("panda")
    q = robot.joints_from_named(list(seq.joint_names), seq.joints)
    T_ref = seq.T_cam_base_reference
    uv = project(seq.camera, transform_points(T_ref, robot.forward_kinematics(q)))
    # Every keypoint of every frame lies inside the image with the reference extrinsic.
    assert seq.camera.in_image(uv).all()
    labelled = replace(seq, keypoint_names=robot.keypoint_names, frames=tuple(
        replace(f, uv_labels=uv[i], image_path=None, mask_path=None)
        for i, f in enumerate(seq.frames)))
    data = tmp_path / "teleop_labels"
    write_dream(labelled, data)
    # the labels are the logged readings' projections: keep them as logged (5 Hz beside 30 Hz)
    code, out, err = run(["calibrate", "--data", data, "--use-labels", "--joint-readings",
                          "as-logged", "--out", tmp_path / "r.json"], capsys)
    assert code == 0, err
    assert "error vs the reference: camera position" in out      # a reference, not truth
    T = np.array(json.loads((tmp_path / "r.json").read_text())["T_cam_base"])
    t_err, r_err = pose_errors(T, T_ref)
    assert t_err < 1e-9 and r_err < 1e-9


def test_overlay_on_panda_teleop(realdata, tmp_path, capsys):
    code, out, err = run(["overlay", realdata / "panda_teleop", "--out", tmp_path, "--limit",
                          "3"], capsys)
    assert code == 0, err
    assert len(list(tmp_path.glob("*.png"))) == 3


def test_overlay_takes_data_and_result_as_calibrate_and_eval_name_them(realdata, tmp_path,
                                                                      capsys):
    """`dream overlay --data D --result R.json`, as `dream eval` is called, was refused with
    a hint about the shell expanding a pattern."""
    T_ref = read_sequence(realdata / "panda_teleop").T_cam_base_reference
    result = tmp_path / "r.json"
    result.write_text(json.dumps({"T_cam_base": np.asarray(T_ref).tolist(), "robot": "panda",
                                  "frames_mode": "all"}))
    code, out, err = run(["overlay", "--data", realdata / "panda_teleop", "--result", result,
                          "--out", tmp_path / "ov", "--limit", "2"], capsys)
    assert code == 0, err
    assert len(list((tmp_path / "ov").glob("*.png"))) == 2


def test_info_takes_the_recording_first_or_as_data(sample_dir, tmp_path, capsys):
    code, first, err = run(["info", sample_dir], capsys)
    assert code == 0, err
    code, option, err = run(["info", "--data", sample_dir], capsys)
    assert code == 0, err
    assert option == first
    code, _, err = run(["info"], capsys)
    assert code == 2 and "no recording given" in err and "--data DATA" in err
    code, _, err = run(["info", sample_dir, "--data", tmp_path], capsys)
    assert code == 2 and "two recordings given" in err
    assert not list(tmp_path.iterdir())


def test_an_option_the_command_lacks_is_named(sample_dir, capsys):
    with pytest.raises(SystemExit) as stop:
        main(["info", str(sample_dir), "--result", str(sample_dir)])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert "options this command does not take: --result; its --help lists them" in err
    assert "quote it" not in err                # the path is the unknown option's value


def test_info_warns_of_joints_in_degrees(tmp_path, capsys):
    """`dream info` listed readings in degrees without a word; calibrate refuses them."""
    import dataclasses

    from dream.inject import InjectionSettings, make_injected_sequence
    from dream.io import write_dream

    seq = make_injected_sequence(InjectionSettings(num_frames=5, seed=3))
    write_dream(seq, tmp_path / "right")
    write_dream(dataclasses.replace(seq, frames=tuple(dataclasses.replace(
        f, joints=np.degrees(f.joints)) for f in seq.frames)), tmp_path / "degrees")
    assert main(["info", str(tmp_path / "right")]) == 0
    assert "warning" not in capsys.readouterr().out
    assert main(["info", str(tmp_path / "degrees")]) == 0
    printed = capsys.readouterr().out
    assert "warning:" in printed and "are these degrees?" in printed


def test_info_and_robots(realdata, capsys):
    code, out, _ = run(["info", realdata / "panda_teleop"], capsys)
    assert code == 0 and "275 frames" in out and "reference extrinsic: yes" in out
    code, out, _ = run(["info", realdata / "panda_teleop", "--robot", "ur5"], capsys)
    assert code == 0 and "ur5, but the data has no joint shoulder_pan_joint" in out
    code, out, _ = run(["info", realdata / "panda_teleop", "--robot", "no_such_arm.urdf"],
                       capsys)
    assert code == 0 and "no_such_arm.urdf (cannot be loaded: " in out
    assert "warning:" not in out
    code, out, _ = run(["robots"], capsys)
    assert code == 0 and all(name in out for name in ("panda", "ur5", "xarm7"))
    assert out.count("  why: ") == 3 and "link5 = link6" in out       # the rationale of each


def _one_error_line(code: int, err: str) -> str:
    assert code != 0
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


def test_bad_input_gives_one_line_and_no_output(sample_dir, tmp_path, capsys):
    result = tmp_path / "r.json"
    line = _one_error_line(*run(["calibrate", "--data", tmp_path / "missing", "--use-labels",
                                 "--out", result], capsys)[::2])
    assert "missing" in line
    # NaN joints in one frame file
    bad = tmp_path / "bad"
    bad.mkdir()
    for f in sample_dir.iterdir():
        (bad / f.name).write_bytes(f.read_bytes())
    doc = json.loads((bad / "000004.json").read_text())
    doc["sim_state"]["joints"][2]["position"] = "nan"
    (bad / "000004.json").write_text(json.dumps(doc))
    line = _one_error_line(*run(["calibrate", "--data", bad, "--use-labels", "--out", result],
                                capsys)[::2])
    assert "000004.json" in line
    line = _one_error_line(*run(["calibrate", "--data", sample_dir, "--use-labels", "--robot",
                                 "nosuchbot", "--out", result], capsys)[::2])
    assert "nosuchbot" in line
    assert not result.exists()


def test_console_script_runs_as_a_process(sample_dir, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "dream.cli", "calibrate", "--data",
                           str(sample_dir), "--use-labels", "--robot", "ur5", "--out",
                           str(tmp_path / "r.json")], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr


def test_output_cut_off_by_its_reader_ends_quietly(tmp_path):
    """`dream info DATA | head -1`: the reader closes the pipe first; no traceback follows."""
    rng = np.random.default_rng(0)
    npz = tmp_path / "episode.npz"
    np.savez(npz, rgb_images=rng.integers(0, 255, (3, 24, 32, 3), dtype=np.uint8),
             captured_joint_values=rng.uniform(-1, 1, (3, 8)),
             target_joint_values=rng.uniform(-1, 1, (3, 8)))
    with subprocess.Popen([sys.executable, "-m", "dream.cli", "info", str(npz),
                           "--intrinsics", "30,31,16,12"], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE, text=True) as proc:
        proc.stdout.close()           # before the command has written anything
        err = proc.stderr.read()
        code = proc.wait()
    assert code == 141, err
    assert err == ""


def test_demo(tmp_path, capsys):
    code, out, err = run(["demo", "--keypoints-only", "--seed", "0", "--out", tmp_path], capsys)
    assert code == 0, err
    assert "error vs ground truth" in out and "1-sigma" in out


def test_maniunicon_npz_with_intrinsics_on_the_command_line(tmp_path, capsys):
    rng = np.random.default_rng(0)
    npz = tmp_path / "episode.npz"
    np.savez(npz, rgb_images=rng.integers(0, 255, (3, 24, 32, 3), dtype=np.uint8),
             captured_joint_values=rng.uniform(-1, 1, (3, 8)),
             target_joint_values=rng.uniform(-1, 1, (3, 8)))
    line = _one_error_line(*run(["info", npz], capsys)[::2])
    assert "--intrinsics" in line
    code, out, err = run(["info", npz, "--intrinsics", "30,31,16,12"], capsys)
    assert code == 0, err
    assert "32x24 fx=30.00 fy=31.00" in out and "3 frames" in out
    code, out, err = run(["info", npz, "--intrinsics", "30,31,16,12,32,24"], capsys)
    assert code == 0, err
    line = _one_error_line(*run(["info", npz, "--intrinsics", "30,31,16,12,64,48"], capsys)[::2])
    assert "32x24" in line


def test_requests_check_their_options_and_run_without_a_command_line(sample_dir, tmp_path,
                                                                      capsys):
    out = str(tmp_path / "r.json")
    with pytest.raises(InputError, match="--seed must be a whole number >= 0"):
        CalibrateRequest(data=str(sample_dir), out=out, use_labels=True, seed=-1)
    with pytest.raises(InputError, match="--polish was not given"):
        CalibrateRequest(data=str(sample_dir), out=out, use_labels=True, mask_head=True)
    with pytest.raises(InputError, match="--outliers must be a fraction"):
        SampleRequest(out=str(tmp_path / "s"), outliers=2.0)
    args = build_parser().parse_args(["calibrate", "--data", str(sample_dir), "--use-labels",
                                      "--out", out])
    defaults = CalibrateRequest(data=str(sample_dir), out=out, use_labels=True)
    assert {k: getattr(defaults, k) for k in vars(args) if hasattr(defaults, k)} == \
        {k: v for k, v in vars(args).items() if hasattr(defaults, k)}
    doc = run_calibrate(defaults)
    assert "reprojection RMSE" in capsys.readouterr().out
    assert np.allclose(json.loads(Path(out).read_text())["T_cam_base"], doc["T_cam_base"])


def test_every_option_says_what_it_does_and_its_default():
    """`--help` of every command explains each option and shows its default where it has one."""
    import argparse

    from dream.cli.app import build_parser

    def commands(parser, prefix=""):
        """(name, parser) of every command, those under a command's own commands included."""
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                for name, child in action.choices.items():
                    yield f"{prefix}{name}", child
                    yield from commands(child, f"{prefix}{name} ")

    silent, names = [], []
    for name, parser in commands(build_parser()):
        names.append(name)
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction) or action.help == argparse.SUPPRESS:
                continue
            has_default = action.default not in (None, False, [])
            if not action.help or (has_default and "default" not in action.help):
                silent.append(f"{name} {'/'.join(action.option_strings) or action.dest}")
    assert not silent, silent
    assert {"calibrate", "batch calibrate", "batch synth"} <= set(names)
