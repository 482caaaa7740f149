"""The robot the silhouette search draws (`dream calibrate` without keypoints, `dream overlay`
of a user URDF's outline): every joint the data logs moves its links, keypoints or not."""

from __future__ import annotations

from pathlib import Path


def robot_for_search(seq, request):
    """The robot of the data or `--robot` (a user URDF without `--keypoints` gets the suggested
    keypoint links, `dream robots --urdf`; the search does not use them), with the links of the
    joints the data logs off those keypoints' chains added as keypoints
    (`dream.outline_robot.with_logged_joints`: a second arm, a head), so that the
    silhouettes draw every link at its reading, not at rest."""
    from dream.errors import RobotError
    from dream.outline_robot import with_logged_joints
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
