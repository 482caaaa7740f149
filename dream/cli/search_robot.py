"""The robot the silhouette search draws (`dream calibrate` without keypoints, `dream overlay`
of a user URDF's outline): every joint the data logs moves its links, keypoints or not."""

from __future__ import annotations

import dataclasses
import logging
from pathlib import Path

log = logging.getLogger(__name__)


def robot_for_search(seq, request):
    """The robot of the data or `--robot` (a user URDF without `--keypoints` gets the suggested
    keypoint links, `dream robots --urdf`; the search does not use them), with the links of the
    joints the data logs off those keypoints' chains added as keypoints
    (`dream.robot.keypoint_choice.logged_joint_links`: a second arm, a head), so that the
    silhouettes draw every link at its reading, not at rest."""
    from dream.errors import RobotError
    from dream.pipeline import robot_for
    from dream.plausibility import check_robot_readings
    from dream.robot.keypoint_choice import analyse_keypoints

    try:
        robot = robot_for(seq, request.robot, option_keypoints=request.keypoint_links)
    except RobotError:
        from dream.robot.urdf import parse_urdf

        name = request.robot or seq.robot
        robot = robot_for(seq, request.robot, analyse_keypoints(parse_urdf(Path(name)))
                          .suggested)
    check_robot_readings(seq, robot)
    return with_logged_joints(seq, robot)


def with_logged_joints(seq, robot):
    """`robot` with the links of the joints `seq` logs off its keypoints' chains added as
    keypoints, each branch only where its readings lie within the URDF's limits (else it is
    drawn at rest, with a warning: a gripper's width logged for a finger's travel)."""
    from dream.errors import InputError
    from dream.plausibility import check_robot_readings
    from dream.robot.keypoint_choice import logged_joint_links

    added: list[str] = []
    for link in logged_joint_links(robot.tree, robot.base_link, seq.joint_names,
                                   robot.keypoint_names):
        trial = dataclasses.replace(robot, keypoint_names=robot.keypoint_names + (link,))
        try:
            check_robot_readings(seq, trial)
        except InputError as exc:
            log.warning("the logged joints up to %s are drawn at rest: %s", link, exc.problem)
            continue
        robot = trial
        added.append(link)
    if added:
        log.info("the silhouettes also move the logged joints up to %s", ", ".join(added))
    return robot
