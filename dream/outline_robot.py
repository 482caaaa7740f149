"""The robot as the images show it: every joint the data logs moves its links, also those off
the keypoints' chains (a second arm, a head, a gripper's fingers), which a keypoint robot
holds at rest. The silhouette search and the overlays' outline draw this robot."""

from __future__ import annotations

import dataclasses
import logging

log = logging.getLogger(__name__)


def with_logged_joints(seq, robot):
    """`robot` with the links of the joints `seq` logs off its keypoints' chains added as
    keypoints (`dream.robot.keypoint_choice.logged_joint_links`), each branch only where its
    readings lie within the URDF's limits (else it stays at rest, with a warning: a gripper's
    width logged for a finger's travel). Its first keypoints are `robot`'s, in order."""
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


def joints_at_rest(robot) -> list[str]:
    """The URDF's moving joints below the base (none that follows another, none behind a
    floating or planar joint: their links are not drawn) that `robot` does not drive: their
    links are drawn at rest."""
    from dream.robot.tree import SUPPORTED_TYPES

    tree, depth = robot.tree, len(robot.tree.path(robot.base_link))
    return [j.name for j in tree.joints if j.moves and j.mimic is None
            and j.name not in robot.joint_names and tree.is_ancestor(robot.base_link, j.child)
            and all(tree.joints[k].type in SUPPORTED_TYPES
                    for k in tree.path(j.child)[depth:])]
