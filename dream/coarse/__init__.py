"""Calibration without keypoints: the camera pose searched from the robot's silhouettes
(`dream.coarse.search`), its hypotheses, evidence and verdict."""
