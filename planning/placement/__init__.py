"""Placement when infeasible (Makki 2010: "change the set-up of the part"): candidate poses of the
part on the table and the search that plans the best one (``fixtures.placement = "auto"``).

* :mod:`~planning.placement.poses`: the candidates (as scanned, the stable faces of the convex hull,
  the principal axes up and down) as rigid motions of the scan;
* :mod:`~planning.placement.search`: each candidate through the plan's own visibility and set-up
  stages, cheapest proof first; the winner and every candidate's figures;
* :mod:`~planning.placement.stage`: the plan's placement stage (``run_plan`` calls it): the placed cloud,
  the as-scanned hint, the ``plan.json`` block.
"""

from planning.placement.poses import Pose, apply_pose, candidate_poses, stable_faces, stable_poses, turn
from planning.placement.search import PlacementSearch, Tried, full_yaw, search_placement, search_work

__all__ = ["PlacementSearch", "Pose", "Tried", "apply_pose", "candidate_poses", "full_yaw", "search_placement",
           "search_work", "stable_faces", "stable_poses", "turn"]
