"""Edge alignment: the extrinsic refined by the robot's outline on the images' own edges.

No masks needed: from a keypoint extrinsic, the projected outline of the robot's URDF visual
meshes is matched to the images' intensity edges along its normals, coarse to fine, jointly over
the frames of a fixed camera, or frame by frame (`dream calibrate --refine edges`). Modules:
    settings    `EdgeSettings`, every constant
    search      the outline points of a pose and the edges that face them
    background  the background model of a fixed camera (the scene without the moving arm)
    refine      the coarse-to-fine Levenberg-Marquardt alignment
    score       the outline's agreement with the images, in all and per link
    calibration a sequence's extrinsic aligned, kept or not (`refine_with_edges`)
    frames      each frame's own pose aligned, kept or not (`refine_frames_with_edges`)
    motion      motion masks against a colour background model (`dream masks`,
                `--polish --motion-masks`)
    documents   the `edges` object of RESULT.json
"""

from dream.edges.calibration import EdgeResult, refine_with_edges
from dream.edges.settings import EdgeSettings

__all__ = ["EdgeResult", "EdgeSettings", "refine_with_edges"]
