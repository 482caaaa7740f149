"""Block compression (JPEG) seen in a fixed camera's frames: how much their differences from
the background model step at the 8-pixel block grid (pure).

A JPEG frame is coded in 8x8 blocks, and a block that holds part of the moving arm rings: its
pixels beside the arm differ from the background model by a few grey levels, more at coarser
quality, and the step between two blocks is sharper than within one. Where the arm is absent
from a block, the frame and the background code alike and their difference is flat. So the
difference image of a compressed recording steps more across the block grid than elsewhere;
a recording stored losslessly (or a render) steps alike everywhere. `block_step_ratio` is the
mean absolute step across the grid's lines over the mean step elsewhere, along both axes.

    >>> difference = np.zeros((16, 16)); difference[:, 8:] = 5.0        # one step, on the grid
    >>> block_step_ratio(difference) > 1
    True
    >>> block_step_ratio(np.tile([0.0, 1.0], (16, 8)))                  # steps everywhere
    1.0
"""

from __future__ import annotations

import numpy as np

from dream.errors import InputError

BLOCK_PX = 8              # JPEG's coding block
NO_STEPS = 1e-12          # a difference image without steps off the grid has no ratio


def block_step_ratio(difference: np.ndarray) -> float:
    """The mean absolute step of an (H, W) image across the lines of the 8-pixel block grid
    over its mean absolute step elsewhere, averaged over rows and columns; 1 where the image
    is flat off the grid and on it.

    Raises:
        InputError: not (H, W), or smaller than two blocks along an axis.
    """
    d = np.asarray(difference, np.float64)
    if d.ndim != 2 or min(d.shape) < 2 * BLOCK_PX:
        raise InputError(f"difference has shape {d.shape}, expected (H, W) of at least "
                         f"{2 * BLOCK_PX} pixels each way")
    ratios = []
    for image in (d, d.T):
        steps = np.abs(np.diff(image, axis=1)).mean(axis=0)       # between columns x and x+1
        on_grid = np.zeros(len(steps), bool)
        on_grid[BLOCK_PX - 1::BLOCK_PX] = True
        off = steps[~on_grid].mean()
        on = steps[on_grid].mean()
        ratios.append(1.0 if off < NO_STEPS and on < NO_STEPS else on / max(off, NO_STEPS))
    return float(np.mean(ratios))
