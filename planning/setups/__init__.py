"""Stage 5, set-ups (Makki 2010 §3.1): the fewest orientations that cover the part with the least overlap,
solved exactly.

Entry: :func:`select_setups` (a boolean visibility matrix, points x candidate axes -> the chosen axes,
covered and overlap point counts and the proof, :class:`SetupSelection`) in
:mod:`planning.setups.select`; :func:`brute_force_setups` is the exhaustive reference, and
:data:`SOLVERS` names the solvers.  The modules, in reading order:

* :mod:`~planning.setups.select`: the entry, the rules and tie order of the answer;
* :mod:`~planning.setups.problem`: validated inputs and the reduced problem (weighted classes of
  identical rows, distinct kept axes);
* :mod:`~planning.setups.result`: :class:`SetupSelection` and its message;
* :mod:`~planning.setups.heuristics`: greedy max coverage and local exchanges (incumbents, hints);
* :mod:`~planning.setups.search` and :mod:`~planning.setups.bounds`: the branch and bound (default);
* :mod:`~planning.setups.lagrange`: the price (LP dual) bound on the coverage of r axes, which proves
  infeasibility and bounds the searches of the infeasible case;
* :mod:`~planning.setups.cpsat`: the OR-Tools CP-SAT model (a cross-check);
* :mod:`~planning.setups.bruteforce`: every combination, the reference for tests;
* :mod:`~planning.setups.zones`: the functional zones of the configuration as a per-point mask.
"""

from planning.setups.bruteforce import brute_force_setups
from planning.setups.result import SetupSelection
from planning.setups.select import SOLVERS, CoverageBound, coverage_upper_bound, select_setups
from planning.setups.zones import zone_mask

__all__ = ["SOLVERS", "CoverageBound", "SetupSelection", "brute_force_setups", "coverage_upper_bound", "select_setups",
           "zone_mask"]
