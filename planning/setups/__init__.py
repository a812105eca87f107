"""Stage 5, set-ups (Makki 2010 §3.1): the fewest orientations that cover the part with the least overlap,
solved exactly.
"""
