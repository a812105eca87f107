"""Post-processors (docs/design.md stage 8): a neutral JSON move list and G-code for 3+2 machining.

* :func:`neutral_moves` (:mod:`.neutral`): controller-independent moves of one area, tool tips and
  arc centres in the part frame and the machine frame.
* :func:`iso_program` (:mod:`.iso`): ISO / Fanuc G-code with a tilted work plane (G68.2, G53.1).
* :func:`linuxcnc_program` (:mod:`.linuxcnc`): LinuxCNC G-code with explicit rotary positioning and
  3-axis X Y Z in the machine frame.

All take a list of :class:`Operation` (a toolpath with its tool, spindle speed and feeds) and the
area's :class:`~planning.toolpath.frames.AreaFrame`; the G-code posts take :class:`PostOptions`.

What the posts share:

* :mod:`.options`: :class:`Operation`, :class:`PostOptions` and the checks of every input;
* :mod:`.blocks`: number formatting, comments, the block writer, the header lines;
* :mod:`.arcs`: principal planes, chord points of linearised arcs, the safe height;
* :mod:`.motion`: the motion blocks of one operation (per move, and with whole arrays);
* :mod:`.bulk_text`: the whole-array number formatter and row layout (motion blocks, neutral JSON).

:mod:`.programs` writes every area's programs and moves file for the planning pipeline.
"""

from .arcs import ARC_PLANE_TOL
from .iso import euler_zxz_deg, euler_zxz_matrix, iso_program
from .linuxcnc import linuxcnc_program
from .neutral import neutral_moves
from .options import Operation, PostOptions

__all__ = [
    "ARC_PLANE_TOL",
    "Operation",
    "PostOptions",
    "euler_zxz_deg",
    "euler_zxz_matrix",
    "iso_program",
    "linuxcnc_program",
    "neutral_moves",
]
