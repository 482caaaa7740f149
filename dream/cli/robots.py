"""`dream robots`: the built-in robots and their default keypoints."""

from __future__ import annotations

import argparse

from dream.cli.options import add_command


def run_robots() -> None:
    """Each built-in robot: its name, description, keypoints and why these keypoints."""
    from dream.robot import builtin_robots

    for entry in builtin_robots():
        print(f"{entry.name}: {entry.description}")
        print(f"  keypoints: {', '.join(entry.keypoints)}")
        print(f"  why: {entry.rationale}")


def cmd_robots(args: argparse.Namespace) -> int:
    run_robots()
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """The `dream robots` parser."""
    add_command(sub, "robots", cmd_robots, "list built-in robots and their default keypoints")
