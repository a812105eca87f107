"""Stage 3, orientations: candidate tool axes on the Gaussian sphere (Makki 2010 §2.2.1), the machine's
kinematics (rotary angles, rotations, positions of the controlled point) and machine visibility (§2.2.2).

The kinematics live here and nowhere else: visibility, tool paths and posts call them, never the reverse.

Entries: :func:`candidate_axes` (sampling steps, deg -> :class:`CandidateAxes`) in
:mod:`planning.orientations.candidates`; :func:`machine_visibility` (axes, profile -> rotary angles, deg,
and feasibility, :class:`MachineVisibility`) in :mod:`planning.orientations.kinematics`. The placement of
the part and the machine X/Y/Z of the controlled point are in :mod:`planning.orientations.positions`.
"""

from planning.orientations.candidates import CandidateAxes, candidate_axes
from planning.orientations.kinematics import MachineVisibility, load_profile, machine_visibility

__all__ = ["CandidateAxes", "MachineVisibility", "candidate_axes", "load_profile", "machine_visibility"]
