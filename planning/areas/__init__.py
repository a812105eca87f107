"""Stage 6, areas (Makki 2010 §3.1): each point machined in one chosen set-up.

Entry: :func:`assign_areas` (visibility and chosen axes -> :class:`Areas`: a set-up per sampled and
input point, leftovers flagged) in :mod:`planning.areas.assign`. :mod:`planning.areas.bound` (not
called by the plan) bounds from below the label changes any labelling the visibility allows has.
"""

from planning.areas.assign import Areas, assign_areas

__all__ = ["Areas", "assign_areas"]
