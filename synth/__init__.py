"""Domain-randomised MuJoCo renders of URDF arms, written in the DREAM layout (`dream synth`).

RGB images, per-link masks, keypoint labels with occlusion, and ground truth, from a YAML recipe
of named ranges (`configs/synth/`); every frame's randomness derives from (seed, frame index), so
a killed run resumes and ends equal to an uninterrupted one.
"""
