"""`dream plan`: the robot poses to record for the most accurate calibration.

Valid poses (no collision, every keypoint in view and unoccluded; `plan.feasibility`) are drawn
at random; the plan is the set that maximises the information about the extrinsic, averaged
over the camera's stated uncertainty (`plan.design`), visited along a short joint-space path
(`plan.ordering`). `plan.planner` puts these together; `plan.output` writes the plan folder.
"""
