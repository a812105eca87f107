"""Simultaneous 5-axis finishing (issue 19; Chui, Chiu and Yu 2008): tool axes per position, 3D biarcs."""
