"""`dream robots`: the built-in robots and their default keypoints; with `--urdf FILE` (or a
built-in name), one robot's links and joints, the keypoint links suggested for it, and warnings
about keypoints that cannot work (`dream.robot.keypoint_choice`)."""

from __future__ import annotations

import argparse
import math
import sys
import textwrap
from typing import TextIO

from dream.cli.options import add_command, parse_keypoints

WRAP_COLUMNS = 100          # width of the wrapped lists
INDENT = "  "


def run_robots() -> None:
    """Each built-in robot: its name, description, keypoints and why these keypoints."""
    from dream.robot import builtin_robots

    for entry in builtin_robots():
        print(f"{entry.name}: {entry.description}")
        print(f"  keypoints: {', '.join(entry.keypoints)}")
        print(f"  why: {entry.rationale}")


def _wrapped(label: str, items, out: TextIO) -> None:
    print(textwrap.fill(f"{label}{', '.join(items)}", WRAP_COLUMNS,
                        subsequent_indent=INDENT * 2, break_on_hyphens=False,
                        break_long_words=False), file=out)


def _limits(joint) -> str:
    from dream.robot.tree import CONTINUOUS, FIXED, PRISMATIC

    if joint.type == FIXED:
        return ""
    if joint.type == CONTINUOUS:
        return "no limits (sampled in -pi .. pi)"
    unit = "m" if joint.type == PRISMATIC else "rad"
    text = f"{joint.lower:.4g} .. {joint.upper:.4g} {unit}"
    if unit == "rad":
        text += f" ({math.degrees(joint.lower):.1f} .. {math.degrees(joint.upper):.1f} deg)"
    mimic = joint.mimic
    if mimic is not None:
        text += f", mimics {mimic.master}"
        if (mimic.multiplier, mimic.offset) != (1.0, 0.0):
            text += f" (x {mimic.multiplier:g} + {mimic.offset:g})"
    return text


def _print_joints(tree, out: TextIO) -> None:
    print(f"joints ({len(tree.joints)}):", file=out)
    name_w = max(len(j.name) for j in tree.joints)
    type_w = max(len(j.type) for j in tree.joints)
    link_w = max(len(f"{j.parent} -> {j.child}") for j in tree.joints)
    for j in tree.joints:
        line = (f"{INDENT}{j.name:<{name_w}}  {j.type:<{type_w}}  "
                f"{f'{j.parent} -> {j.child}':<{link_w}}  {_limits(j)}")
        print(line.rstrip(), file=out)


def _collinear_lines(sets, whose: str) -> list[str]:
    """A warning for each set on one fixed line; a note for each on a line that moves."""
    lines = []
    for s in sets:
        links = ", ".join(s.links)
        if s.fixed_line:
            lines.append(f"warning: {whose} {links} stay on one line, the same for every joint "
                         "value: together they fix only that line, and no number of frames "
                         "fixes the camera's rotation about it: use them with keypoints off "
                         "it, never alone")
        else:
            lines.append(f"note: {whose} {links} stay on one line in every joint configuration "
                         "(a line that moves with the joints)")
    return lines


def _print_lines(lines: list[str], out: TextIO) -> None:
    for line in lines:
        print(textwrap.fill(line, WRAP_COLUMNS, subsequent_indent=INDENT * 2), file=out)


def _print_columns(tree, path, advice, keypoints, out: TextIO) -> None:
    """The joints a recording must log for `keypoints` (the suggestion, or one arm's), and
    the moving joints they do not drive (the search moves their links where logged)."""
    from dream.outline_robot import joints_at_rest
    from dream.robot import Robot

    robot = Robot(name=tree.name or "urdf", urdf_path=str(path), base_link=advice.base_link,
                  keypoint_names=keypoints, tree=tree)
    _wrapped(f"{INDENT}joints a recording logs for them (joints.csv columns, radians or "
             "metres): ", robot.joint_names, out)
    held = joints_at_rest(robot)
    if held:
        _wrapped(f"{INDENT}move no keypoint (the silhouette search moves their links where the "
                 "recording logs them, and draws them at rest where it does not: then keep "
                 "them still while you record): ", held, out)


def describe_robot(name_or_urdf: str, keypoints: tuple[str, ...] | None = None,
                   out: TextIO | None = None) -> None:
    """The links, joints and suggested keypoint links of one robot (a built-in name or a URDF
    path), with warnings for origins that coincide and keypoints that stay on one line;
    `keypoints`: links to check as well (an unknown one is one `InputError` line)."""
    from dream.errors import InputError, RobotError
    from dream.robot import builtin_robots, parse_urdf
    from dream.robot.keypoint_choice import analyse_keypoints
    from dream.robot.registry import urdf_path_of

    out = out or sys.stdout
    path = urdf_path_of(name_or_urdf)
    tree = parse_urdf(path)
    builtin = {e.name: e for e in builtin_robots()}.get(name_or_urdf.strip().lower())
    fix = f"dream robots --urdf {name_or_urdf} lists its links and suggests keypoints"
    unknown = [k for k in keypoints or () if k not in tree.links]
    if unknown:
        raise InputError(f"--keypoints names {', '.join(repr(k) for k in unknown)}, not "
                         f"{'a link' if len(unknown) == 1 else 'links'} of robot "
                         f"{name_or_urdf!r}", fix=fix)
    try:
        advice = analyse_keypoints(tree, builtin.base_link if builtin else None, keypoints or ())
    except RobotError as exc:
        raise InputError(f"--keypoints {','.join(keypoints or ())}: {exc}", fix=fix) from None
    kind = "built-in robot" if builtin else "robot"
    print(f"{kind} '{builtin.name if builtin else tree.name}': {path}", file=out)
    print(f"base link: {advice.base_link} (the frame of the extrinsic)", file=out)
    _wrapped(f"links ({len(tree.links)}): ", tree.links, out)
    if advice.skipped:
        _wrapped("  not analysed (above the base, or below a floating or planar joint): ",
                 advice.skipped, out)
    if not tree.joints:
        print(f"joints (0):\n{INDENT}none: one rigid body, nothing for a recording of joints to "
              "move", file=out)
        return
    _print_joints(tree, out)
    if advice.coincident:
        _wrapped("warning: link origins that coincide for every joint value (they cannot be "
                 "told apart: one keypoint of each group at most): ",
                 [" = ".join(group) for group in advice.coincident], out)
    _wrapped(f"suggested keypoints ({len(advice.suggested)}): ", advice.suggested, out)
    _print_lines([f"{INDENT}(the base, then one link per group of coincident origins along the "
                  "arm, the distal one, ending at the hand or the flange/tool)"], out)
    if builtin is not None:
        same = builtin.keypoints == advice.suggested
        _wrapped(f"{INDENT}built-in keypoints{' (the same)' if same else ''}: ",
                 builtin.keypoints, out)
    ready = advice.branch_keypoints[0] if advice.branch_keypoints else advice.suggested
    print(f"{INDENT}use: --robot {name_or_urdf} --keypoints {','.join(ready)}"
          f"{' (one arm: see below)' if advice.branch_keypoints else ''}",
          file=out)
    _print_columns(tree, path, advice, ready, out)
    _print_lines(_collinear_lines(advice.suggested_collinear, "the suggested keypoints"), out)
    if advice.branches:
        _wrapped(f"warning: the chain branches at {advice.suggested[-1]} into "
                 f"{len(advice.branches)} alike branches (two arms?), so the suggestion stops "
                 "there; name the base and one arm's links with --keypoints (the arm that "
                 "moves in your recording), starting at one of: ", advice.branches, out)
        for branch, links in zip(advice.branches, advice.branch_keypoints, strict=True):
            print(f"{INDENT}along {branch}: --keypoints {','.join(links)}", file=out)
        print(f"{INDENT}(the silhouette search, without a network, needs no keypoints: it "
              "moves the joints the recording logs, both arms' where both are logged)",
              file=out)
    if keypoints:
        _print_given(advice, out)


def _print_given(advice, out: TextIO) -> None:
    _wrapped("given keypoints: ", advice.given, out)
    lines = [f"warning: the given keypoints {' = '.join(group)} coincide for every joint value: "
             "they cannot be told apart, keep one" for group in advice.given_coincident]
    line = advice.given_line
    if line is not None and line.fixed_line:
        lines.append("warning: all the given keypoints stay on one line, the same for every "
                     "joint value: PnP cannot solve the camera from them with any number of "
                     "frames; use the suggested keypoints, or add links off that line")
    elif line is not None:
        lines.append("warning: all the given keypoints stay on one line in every joint "
                     "configuration: no single frame fixes the camera (only frames of "
                     "different poses together do); add links off that line")
    else:
        lines += _collinear_lines(advice.given_collinear, "the given keypoints")
    _print_lines(lines, out)
    if not lines:
        print(f"{INDENT}no two coincide and no three stay on one line", file=out)


def cmd_robots(args: argparse.Namespace) -> int:
    if args.robot is None:
        if args.keypoints is not None:
            from dream.errors import InputError

            raise InputError("--keypoints are checked against a robot",
                             fix="add --urdf FILE (or a built-in robot's name)")
        run_robots()
    else:
        describe_robot(args.robot, parse_keypoints(args.keypoints))
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """The `dream robots` parser."""
    p = add_command(sub, "robots", cmd_robots, "list built-in robots and their default "
                    "keypoints; with --urdf, one robot's links, joints and suggested keypoints")
    p.add_argument("--urdf", "--robot", dest="robot", metavar="URDF_OR_NAME",
                   help="a URDF file or a built-in robot's name: print its links, joints and "
                        "the keypoint links suggested for it, with warnings for origins that "
                        "coincide or stay on one line (default: list the built-in robots)")
    p.add_argument("--keypoints", metavar="LINK,LINK,...",
                   help="keypoint links to check against the robot of --urdf (default: none)")
