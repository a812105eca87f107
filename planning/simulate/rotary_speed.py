"""How fast each feed move of a program turns the machine's rotary axes (issue 33 item 3).

A simultaneous 5-axis program turns the tilt (A or B) and the rotary (C) axis during its feed
moves. The control times a feed move by its F word: under ``G93`` (LinuxCNC inverse time) the line
takes ``1 / F`` minutes, under ``G94`` its tip path over F (mm/min). If the axes would have to turn
faster than the machine can, the control slows the move (LinuxCNC) or alarms, and in both cases the
program's machining time and its cutting conditions are not what was planned. The posts
(:mod:`planning.post.simultaneous`) time every feed move so that no axis turns faster than the
profile's ``tilt_feed_max_deg_min`` / ``rotary_feed_max_deg_min``; this module checks the programs
as they were read back, independently of the post.

:func:`rotary_feed_excesses` works per program LINE (the reader may split one line into several
chords: the line's turn is the sum of its chords' turns, its time the sum of their minutes from
:func:`planning.simulate.verify.move_minutes`, which shares a G93 line's ``1 / F`` among its
chords). A line is over the limit when ``turn / time > limit * (1 + RATE_TOL)``. Rapids are not
checked (the control runs them at its own axis speeds). Angles in degrees, times in minutes.
"""

from __future__ import annotations

import numpy as np

from planning.toolpath.moves import RAPID

__all__ = ["RATE_TOL", "rotary_feed_excesses"]

#: Relative slack of the rate check: the posts round F down, so a program they wrote is at or below
#: the limit up to floating-point error.
RATE_TOL = 1e-6


def rotary_feed_excesses(motion, minutes: np.ndarray, profile) -> list[dict]:
    """The feed lines of ``motion`` (:class:`planning.simulate.motion.ProgramMotion`) that turn an axis
    faster than the profile allows (module docstring). ``minutes`` (n_moves,): each move's time as the
    control runs it. Returns one dict per (line, axis) over the limit, ordered by line then axis:
    ``program``, ``line`` (1-based), ``move`` (the line's last move), ``axis`` (the profile's name),
    ``rate_deg_min``, ``limit_deg_min``, ``excess`` (rate / limit - 1)."""
    from planning.orientations.kinematics import as_profile

    p = as_profile(profile)
    n = motion.n_moves
    if n == 0:
        return []
    ang = np.asarray(motion.rotary_deg, dtype=np.float64)
    prev = np.vstack([ang[:1], ang[:-1]])
    turn = np.abs(ang - prev)                                  # (n, 2) each move's turn of (tilt, rotary)
    feed = np.asarray(motion.kind) != RAPID
    if not feed.any() or not np.any(turn[feed] > 0):
        return []
    line = np.asarray(motion.line, dtype=np.int64)
    idx = np.flatnonzero(feed)
    lines, inv = np.unique(line[idx], return_inverse=True)
    t_line = np.bincount(inv, weights=np.asarray(minutes, dtype=np.float64)[idx], minlength=lines.size)
    last = np.zeros(lines.size, dtype=np.int64)
    np.maximum.at(last, inv, idx)
    names = p.axis_names
    limits = p.feed_limits_deg_min
    found = []
    for k in range(2):
        tk = np.bincount(inv, weights=turn[idx, k], minlength=lines.size)
        rate = np.where(t_line > 0, tk / np.maximum(t_line, 1e-300), np.where(tk > 0, np.inf, 0.0))
        over = np.flatnonzero(rate > limits[k] * (1.0 + RATE_TOL))
        found += [(int(lines[j]), k, int(last[j]), float(rate[j])) for j in over]
    found.sort()
    return [{"program": motion.program, "line": ln, "move": mv, "axis": names[k], "rate_deg_min": r,
             "limit_deg_min": float(limits[k]), "excess": r / float(limits[k]) - 1.0} for ln, k, mv, r in found]
