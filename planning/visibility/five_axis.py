"""Which set-up can finish which point in simultaneous 5-axis finishing (issue 19).

In 3+2 a set-up finishes the points its one fixed axis sees (Makki 2010 §2.2: the visibility matrix
after the cone, travel, fixture and cloud checks). In 5-axis finishing a set-up's axis is the
direction its passes are laid along (the ball drops along it) and every position takes its own axis
within ``max_swing_deg`` of it (:mod:`planning.toolpath.fiveaxis`). So set-up ``j`` can finish
sampled point ``i`` when

* the point faces the drop direction: the angle between its normal and axis ``j`` is at most
  ``max_swing_deg`` (the ball dropping along ``j`` reaches the surface from its side), and
* some candidate axis ``k`` within ``max_swing_deg`` of axis ``j`` sees the point in the visibility
  matrix (the tool cone, the travel, the fixtures and the cloud, all checked exactly for ``k``), and
* (``along``, when the travel is checked) the machine can present axis ``j`` itself there within its
  X/Y/Z travel: the set-up roughs along ``j`` and drops its ball along ``j``. Without this a pass
  direction could be chosen that the table cannot tilt to over the part (on the range femur of issue
  24 the second of two pass directions reached none of its points along itself; its roughing cut
  1.3 cm^3, and the finishing's shank met the stock left 12-15 mm off the scan on a third of the area).

The selection of set-ups (:func:`planning.setups.select_setups`) then runs unchanged on this matrix:
the fewest set-ups, which on a 5-axis machine with the part clamped once is the number of pass
directions, covering ``setups.coverage`` with the least overlap. The answer is a claim about the
candidate axes only: the paths stage plans the real per-position axes and reports the positions
for which none is admissible.
"""

from __future__ import annotations

import math

import numpy as np

from planning.errors import ParameterError

__all__ = ["five_axis_visibility"]


def five_axis_visibility(visible: np.ndarray, axes: np.ndarray, normals: np.ndarray, max_swing_deg: float,
                         along: np.ndarray | None = None) -> np.ndarray:
    """Bool (n, m): set-up axis ``j`` can finish sample ``i`` in 5-axis finishing (module docstring).

    ``visible`` (n, m) bool: the visibility matrix over the candidate ``axes`` (m,3, unit, part
    frame); ``normals`` (n,3) unit outward normals of the samples; ``max_swing_deg``: the largest
    angle between a position's axis and its set-up's axis, degrees (0 < swing < 90). ``along`` (n, m)
    bool or None: axis ``j`` itself within the travel at sample ``i``
    (:attr:`planning.visibility.chain.GlobalVisibility.along`; None: not required)."""
    vis = np.asarray(visible, dtype=bool)
    ax = np.asarray(axes, dtype=np.float64).reshape(-1, 3)
    nrm = np.asarray(normals, dtype=np.float64).reshape(-1, 3)
    if vis.shape != (nrm.shape[0], ax.shape[0]):
        raise ParameterError(f"visible must be ({nrm.shape[0]},{ax.shape[0]}), got {vis.shape}")
    if not 0 < float(max_swing_deg) < 90:
        raise ParameterError(f"max_swing_deg must be in (0, 90), got {max_swing_deg}")
    c = math.cos(math.radians(float(max_swing_deg)))
    near = (ax @ ax.T) >= c - 1e-12                              # (m, m) axes within the swing of each other
    reach = (vis.astype(np.float32) @ near.astype(np.float32)) > 0.5
    facing = (nrm @ ax.T) >= c - 1e-12
    if along is not None:
        al = np.asarray(along, dtype=bool)
        if al.shape != vis.shape:
            raise ParameterError(f"along must be {vis.shape}, got {al.shape}")
        facing &= al
    return reach & facing
