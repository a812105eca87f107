"""The scallop a ball-end finishing leaves, held on every curvature (issue 31 item 2; Sood 2015 ch. 5).

Everything in the area frame of :mod:`planning.toolpath.finishing` (tool axis +Z, passes along X at
y = const, ball centres from the ball drop), in mm.

**Across the passes** (:func:`scallop_across_mm`). Two neighbouring passes at the same x put ball
centres ``c1 = (y1, z1)`` and ``c2 = (y2, z2)`` in the cross-section x = const, ``d = |c2 - c1|`` apart.
The two balls meet in the cusp ``q``, on the perpendicular bisector of ``c1 c2``, ``sqrt(R^2 - d^2/4)``
below the chord's midpoint. The ball centres lie on the surface's offset at distance R; where that offset
is a circle in the cross-section (a cylinder, a sphere, and to second order any smooth surface), the
scallop, the cusp's height over the surface, is exactly

    h = R - sqrt(R^2 - d^2/4) + delta

where ``delta`` is how far the offset curve's point between the two centres lies below their chord's
midpoint (along the chord's downward normal). On a plane ``delta = 0`` (Sood's flat-plane check,
``s = 2 sqrt(2 R h - h^2)``); on a concave section of radius rho (offset radius rho - R) ``delta > 0``
and the scallop is about rho / (rho - R) times the plane's at the same centre distance (2x at
rho = 2 R: the rule that kept only the centre distance under the plane step-over left that much); on a
convex one ``delta < 0`` and the passes may lie farther apart. Derivation: the offset arc's midpoint
``cm`` and the cusp lie on one radius of the circle; the surface point under the cusp is R from ``cm``
along it, so ``h = R - |cm - q|``; docs/design.md, "Finishing: the scallop on every curvature".

``delta`` comes from the offset curve's curvature across the passes, the second divided difference of
the ball-centre heights of three passes (the previous pass, this one and the next; at the first pass the
next two, and wherever the previous pass has no height within the window) at each x:
``z(y) ~ a + b y + c y^2`` gives ``delta = c dy^2 / 4 * dy / d``. A point cloud's
ball drop rests on discrete points (and on the scan's noise), so the heights jitter by a few microns;
``c`` is taken as the running median of CURVATURE_WINDOW samples along the pass before it is used
(on a uniform sample of a plane at 0.3 mm spacing the largest scallop per pass reads 1.1 x the target
with it and 1.4 x without, in a scratch measurement), and then taken closer to 0 by NOISE_SEMS standard errors of what the
median leaves of the jitter (estimated from the spread about the median). Where neither triple has heights within the window (an edge of the
band) ``c = 0``: the plane's formula on the 3-D centre distance.

**Along a pass** (:func:`refine_chords`). CL points every ``step_mm``; a straight move between two
ball-drop positions runs above the ball-drop height between them where the offset curve is concave
along the pass (a chord over a valley leaves up to L^2 / (8 (rho - R))). Each move is bisected with a
fresh ball drop at its midpoint while the chord's midpoint lies more than ``chord_mm`` above the drop
there (measured normal to the move), beyond what the drop heights' jitter explains, at most
``max_rounds`` times. Where the chord runs below the drop
(convex), :func:`planning.toolpath.finishing._make_safe_many` splits it for gouge safety as before.
"""

from __future__ import annotations

import math

import numpy as np

from planning.toolpath.moves import BisectedLines

#: Ball-centre heights' curvature across the passes is the running median of this many samples along a
#: pass (odd; at the forward step R / 4, 9 samples span 2 R): the ball drop's jitter on a point cloud
#: averages out, a concavity wider than about R is kept
CURVATURE_WINDOW = 9
#: The side step is at most this many plane step-overs (``2 sqrt(2 R h - h^2)``): on a convex section
#: the formula allows wider steps (sqrt 2 at rho = R), on a sharp ridge unboundedly wide
SIDE_STEP_MAX = 2.0
#: The curvature across the passes is trusted only beyond this many standard errors of what its running
#: median leaves of the ball drop's jitter (robust: from the median absolute deviation about it); on a
#: scan the noise otherwise reads as curvature and crowds the passes
NOISE_SEMS = 2.0
#: A side step is taken when its scallop lies within [ACCEPT_LOW, 1] of the target (fewer drops than
#: hitting the target exactly; at most that much narrower than it could be)
ACCEPT_LOW = 0.85


def running_median(v: np.ndarray, window: int) -> np.ndarray:
    """Median of the finite values in a centred window of ``window`` samples (odd) at each index of the
    1-D array ``v``; NaN where the window holds none. Vectorised (a sorted sliding window)."""
    v = np.asarray(v, dtype=np.float64)
    k = int(window) // 2
    if k <= 0 or v.size == 0:
        return v.copy()
    pad = np.concatenate([np.full(k, np.nan), v, np.full(k, np.nan)])
    win = np.sort(np.lib.stride_tricks.sliding_window_view(pad, 2 * k + 1), axis=1)   # NaN sort last
    n = np.isfinite(win).sum(axis=1)
    out = np.full(v.size, np.nan)
    ok = n > 0
    rows = np.flatnonzero(ok)
    lo = win[rows, (n[ok] - 1) // 2]
    hi = win[rows, n[ok] // 2]
    out[ok] = 0.5 * (lo + hi)
    return out


def curvature_across(ya: float, za: np.ndarray, yb: float, zb: np.ndarray, yc: float, zc: np.ndarray,
                     window: int = CURVATURE_WINDOW, noise: list | None = None) -> np.ndarray:
    """Per x, ``c`` of ``z(y) ~ a + b y + c y^2`` through the ball-centre heights of three passes at
    ``ya < yb < yc`` (their second divided difference, 1/mm), the running median of ``window`` samples
    along the pass; NaN where one of the three heights is missing and the window holds no value.
    ``noise``: a list to which the ball-drop heights' jitter (mm) this triple shows is appended (the
    spread of c about its running median, divided by the factor the divided difference multiplies a
    height's error by), when there are enough values to tell."""
    za, zb, zc = (np.asarray(z, dtype=np.float64) for z in (za, zb, zc))
    if not (ya < yb < yc):
        raise ValueError("the three passes must be in increasing y")
    c = ((zc - zb) / (yc - yb) - (zb - za) / (yb - ya)) / (yc - ya)
    cf = running_median(c, window)
    sig = robust_sigma(c - cf)
    if noise is not None and np.isfinite(c).sum() >= 5:
        h1, h2 = yb - ya, yc - yb
        gain = math.sqrt((1 / (h1 * (h1 + h2))) ** 2 + (1 / (h1 * h2)) ** 2 + (1 / (h2 * (h1 + h2))) ** 2)
        noise.append(sig / gain)
    # what the median leaves of the jitter (a point cloud's drop heights, the scan's noise): its standard
    # error from the spread of c about the median; the curvature is taken that much closer to 0, twice over
    sem = 1.2533 * sig / math.sqrt(max(int(window), 1))
    return np.sign(cf) * np.maximum(np.abs(cf) - NOISE_SEMS * sem, 0.0)


def robust_sigma(v: np.ndarray) -> float:
    """The standard deviation of normal noise that would give the finite values of ``v`` their median
    absolute deviation (1.4826 MAD); 0 with fewer than 5 values."""
    v = np.asarray(v, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size < 5:
        return 0.0
    return 1.4826 * float(np.median(np.abs(v - np.median(v))))


def scallop_across_mm(R: float, y1: float, z1: np.ndarray, y2: float, z2: np.ndarray,
                      curvature: np.ndarray | float = 0.0) -> np.ndarray:
    """Per x, the scallop (mm) between the balls of radius ``R`` at ``(y1, z1)`` and ``(y2, z2)``
    (``y2 > y1``) on a section whose ball-centre offset curve has ``z'' / 2 = curvature``
    (:func:`curvature_across`; 0: a plane; NaN counts as 0): ``R - sqrt(R^2 - d^2/4) + delta`` (module docstring);
    +inf where the balls do not meet (``d >= 2 R``), NaN where either height is missing."""
    z1 = np.asarray(z1, dtype=np.float64)
    z2 = np.asarray(z2, dtype=np.float64)
    dy = float(y2 - y1)
    d = np.hypot(dy, z2 - z1)
    with np.errstate(invalid="ignore"):
        h = R - np.sqrt(np.maximum(R * R - 0.25 * d * d, 0.0)) + np.nan_to_num(np.asarray(curvature, dtype=np.float64), nan=0.0) * dy * dy * 0.25 * dy / d
        h = np.where(d >= 2.0 * R, np.inf, h)
    return np.where(np.isfinite(z1) & np.isfinite(z2), h, np.nan)


def worst(h: np.ndarray) -> float:
    """The largest finite-or-infinite value of ``h`` ignoring NaN; 0 when there is none."""
    h = np.asarray(h, dtype=np.float64)
    ok = ~np.isnan(h)
    return float(h[ok].max()) if ok.any() else 0.0


def refine_chords(drop, lines: list[np.ndarray], chord_mm: float, max_rounds: int = 6,
                  noise_mm: float = 0.0) -> list[np.ndarray]:
    """The forward step held on concave stretches: each CL line ``lines[k]`` (L,3) of ball-drop
    positions along a pass gets, between two of its points, the ball-drop position at the move's
    midpoint (``drop(xy (k,2)) -> (k,) z``, -inf where nothing is under the ball) wherever the move's
    midpoint lies more than ``chord_mm`` above it, measured normal to the move; repeated on the new
    moves at most ``max_rounds`` times (the step then is at least ``step / 2^max_rounds``). Returns the
    refined lines, in order. ``noise_mm``: the ball-drop heights' jitter on a scan (the points the ball
    rests on, the noise; :func:`curvature_across` estimates it): a move is split only where its midpoint
    lies above the drop by more than ``chord_mm`` plus NOISE_SEMS times the jitter that comparison carries
    (sqrt(1.5) ``noise_mm``); a chord over the noise is no chord over a valley.
    """
    if not lines:
        return []
    pl = BisectedLines(lines)
    look = pl.inner()                              # the moves to look at: at first every one
    limit = chord_mm + NOISE_SEMS * math.sqrt(1.5) * float(noise_mm)
    for _ in range(int(max_rounds)):
        at = np.flatnonzero(look)
        if at.size == 0:
            break
        a, b = pl.xyz[at - 1], pl.xyz[at]
        mid = 0.5 * (a + b)
        z = np.asarray(drop(mid[:, :2]), dtype=np.float64)
        seg = b - a
        L = np.linalg.norm(seg, axis=1)
        horiz = np.hypot(seg[:, 0], seg[:, 1])
        # the chord's midpoint above the drop there, normal to the move: (dz) * cos(the move's slope)
        above = (mid[:, 2] - z) * np.divide(horiz, L, out=np.ones_like(L), where=L > 0)
        split = np.isfinite(z) & (above > limit)
        if not split.any():
            break
        mids = mid[split].copy()
        mids[:, 2] = z[split]
        new = pl.insert(at[split], mids)
        look = np.zeros(pl.lid.size, dtype=bool)
        look[new] = True                           # the move into each new point
        look[new + 1] = True                       # and out of it
    return pl.split()
