"""Keypoint belief-map network and its Lightning training (issue 4)."""
