"""One exception hierarchy. Every message says what is wrong and what to do about it."""

from __future__ import annotations

from pathlib import Path


class DreamError(Exception):
    """Base class of every error the project raises on purpose.

    The command line turns any `DreamError` into one line on stderr and a non-zero exit.
    """


def _message(problem: str, path: Path | None, fix: str | None) -> str:
    where = f"{path}: " if path is not None else ""
    how = f" Fix: {fix}" if fix else ""
    ended = problem if problem.endswith(("?", "!")) else f"{problem.rstrip('.')}."
    return f"{where}{ended}{how}"


class InputError(DreamError):
    """A file or value given by the user is missing, unreadable or malformed.

    Args:
        problem: what is wrong, e.g. "joint 3 is NaN".
        path: the file (or folder) concerned, when there is one.
        fix: what the user should do, e.g. "write 7 finite joint angles in radians".
    """

    def __init__(self, problem: str, path: str | Path | None = None, fix: str | None = None):
        self.problem = problem
        self.path = None if path is None else Path(path)
        self.fix = fix
        super().__init__(_message(problem, self.path, fix))


class CannotRefine(InputError):
    """An image refinement cannot run on this data (no image edge near the robot's outline,
    no solved frame with an image): `--refine auto` keeps the pose before it, an explicit
    `--refine` reports it."""


class RobotError(DreamError):
    """Unknown robot, unknown link or joint, or joint values that do not fit the robot."""


class CalibrationError(DreamError):
    """The calibration cannot be solved from the given observations (too few keypoints...).

    Args:
        problem: why, e.g. "only 3 usable keypoints, at least 4 are needed".
        path: the data concerned, when known.
        fix: what the user should do, when there is something to do.
    """

    def __init__(self, problem: str, path: str | Path | None = None, fix: str | None = None):
        self.problem = problem
        self.path = None if path is None else Path(path)
        self.fix = fix
        super().__init__(problem if path is None and fix is None
                         else _message(problem, self.path, fix))
