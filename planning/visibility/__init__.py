"""Stage 4, visibility (Makki 2010 §2.2.3-2.2.4): the tool cone about each normal, the machine's X/Y/Z
travel, and the global filter chain (tool and holder against the cloud, fixtures and the table).

Entries: :func:`cone_visibility` (normals, axes, cone in deg -> (n, m) bool) in
:mod:`planning.visibility.cone`, then :func:`global_visibility` (-> :class:`GlobalVisibility`, the
filter chain) in :mod:`planning.visibility.chain`; the X/Y/Z travel check is
:mod:`planning.visibility.travel`.
"""

from planning.visibility.chain import GlobalVisibility, global_visibility
from planning.visibility.cone import cone_visibility

__all__ = ["GlobalVisibility", "cone_visibility", "global_visibility"]
