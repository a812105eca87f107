"""3D biarcs through a path of ball centres (Chui, Chiu & Yu 2008, §3.4 and Appendix A).

A biarc joins two points ``A`` and ``C`` with given unit tangents ``t1`` and ``t3`` by two circular
arcs that meet at a junction ``B`` with a common tangent ``t2`` (G1).  In 3D each arc lies in its own
plane: arc 1 in the plane of ``t1, t2``, arc 2 in the plane of ``t2, t3``; the dihedral angle between
them is the *twist*.  The biarc is a *C* when both arcs turn the same way (plane normals agree) and an
*S* when they turn opposite ways.  The ball centre is posted along these arcs (or their chords, see
:func:`biarc_chords`), and :func:`fit_biarcs` replaces a dense polyline of ball centres by as few
biarcs as keep every input point within a tolerance.

Units: lengths in mm (whatever the input points use), angles in radians in names ending ``_rad``.

Equations (Appendix A).  With ``s = C - A`` (A.1), chords ``AB = a (t1 + t2)`` (A.2) and
``BC = b (t2 + t3)`` (A.3), ``(a + b) t2 = s - a t1 - b t3`` (A.5) and ``|t2| = 1`` give A.6::

    a b w + a (s.t1) + b (s.t3) = |s|^2 / 2,      w = 1 - t1.t3.

Errata applied (see ``/work/shared/papers/NOTES.md``; each checked numerically):

* "s.t" in A.7 is ``s.t1``; in A.8 "s^2 t1.t3" is ``(s.t1)(s.t3)``.
* The minimum of ``a + b`` on A.6 (A.8) is ``a = (u - s.t3)/w``, ``b = (u - s.t1)/w`` with
  ``u^2 = (s.t1)(s.t3) + w |s|^2/2``; the printed ``a = -s.t3 + u/w`` does not satisfy A.6.
* The curvatures of §3.4 / A.10-A.12 need an absolute value (``kappa = |...| / |...|``).
* ``w = 0`` (``t1 = t3``) has no A.8 solution; it is the equal-chord case below.

Choice of the free parameter (default ``method="equal"``): ``a = b``, the positive root of
``w a^2 + (s.t1 + s.t3) a - |s|^2/2 = 0``.  Chui's A.8 (``method="chui"``) is *not* the default
because (i) it is singular as ``w -> 0``: ``a ~ s.(t1 - t3) / w`` blows up and ``a`` or ``b`` turns
negative (``t1`` 5.7 degrees off a 10 mm chord and ``t3`` = ``t1`` turned by 1e-4 rad give
a = 1.0e4 mm, b = -1.0e4 mm); (ii) it gives ``a <= 0`` or ``b <= 0`` -- an arc of more than 180
degrees, a loop -- whenever ``u < max(s.t1, s.t3)``, which held for about half of random
forward-leaning tangent pairs in a numerical check.  The equal choice always has ``a > 0`` when
``w > 0`` (the roots' product is ``-|s|^2/(2w) < 0``), so both arcs sweep less than 180 degrees, and
(for ``s.t1 + s.t3 > 0``) it tends continuously to the equal-chord biarc at ``w = 0``, where ``B`` is
the midpoint of ``AC`` (``B = A + (s + a (t1 - t3))/2`` for ``a = b``).  For
co-circular data (``s.t1 = s.t3``) both choices coincide and reproduce the circle.  ``"chui"`` falls
back to ``"equal"`` for spans where A.8 has no proper solution.

Tangents (:func:`path_tangents`): the paper's rule ``t_i = n_i x (P_iP_{i+1} x n_i)`` projects the
forward chord on the surface tangent plane, which is only first-order accurate; here the tangents come
from the curve itself, the circle through each point and its neighbours (exact on circles).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

__all__ = [
    "Biarc",
    "BiarcFit",
    "biarc",
    "biarc_chords",
    "distance_to_biarcs",
    "fit_biarcs",
    "path_tangents",
]

# An arc whose half turn angle is below this is a straight piece (sagitta < 2.5e-13 x chord).
_STRAIGHT_SIN = 1e-12
# w below this counts as parallel tangents (|t1 - t3| < 1.4e-15).
_W_PARALLEL = 1e-30
# Two junction points closer than this (mm) are one point when listing chords.
_SAME_POINT_MM = 1e-9


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", u, v)


def _unit(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors and norms; zero vectors stay zero."""
    n = np.sqrt(_dot(v, v))
    safe = np.where(n > 0.0, n, 1.0)
    return v / safe[..., None], n


def path_tangents(points: np.ndarray) -> np.ndarray:
    """Unit tangents (n, 3) of a polyline of ball centres, taken from the fitted curve.

    At an interior point ``P_i`` the tangent is that of the circle through ``P_{i-1}, P_i, P_{i+1}``:
    with ``d0 = P_i - P_{i-1}`` and ``d1 = P_{i+1} - P_i`` it is ``|d1|^2 d0 + |d0|^2 d1`` normalised
    (Bessel's three-point tangent; exact for points on one circle, and for unequal spacing).  At the
    two ends the tangent is that of the end circle, i.e. the neighbour's tangent reflected in the end
    chord, ``t_0 = 2 (t_1.u) u - t_1`` with ``u`` the unit end chord.  Collinear triples give the
    chord direction.  Degenerate triples (a repeated point, or a reversal) fall back to the mean of the
    two chord directions, then to whichever chord is not zero.  A path of two points gets its chord
    direction at both ends; a single point gets ``(1, 0, 0)``.
    """
    P = np.asarray(points, dtype=float)
    n = len(P)
    if n < 2:
        return np.tile(np.array([1.0, 0.0, 0.0]), (n, 1))
    d = np.diff(P, axis=0)
    u, ln = _unit(d)
    T = np.zeros_like(P)
    if n == 2:
        T[:] = u[0] if ln[0] > 0 else np.array([1.0, 0.0, 0.0])
        return T
    l2 = ln * ln
    t_mid, nm = _unit(l2[1:, None] * d[:-1] + l2[:-1, None] * d[1:])
    fb, nf = _unit(u[:-1] + u[1:])
    t_mid = np.where((nm > 0)[:, None], t_mid, fb)
    one = np.where((ln[1:] > 0)[:, None], u[1:], u[:-1])
    t_mid = np.where(((nm > 0) | (nf > 0))[:, None], t_mid, one)
    T[1:-1] = t_mid
    first, last = u[0], u[-1]
    T[0] = 2.0 * np.dot(T[1], first) * first - T[1] if ln[0] > 0 else T[1]
    T[-1] = 2.0 * np.dot(T[-2], last) * last - T[-2] if ln[-1] > 0 else T[-2]
    return _unit(T)[0]


def _arc_from_chord(P0: np.ndarray, T0: np.ndarray, P1: np.ndarray):
    """Circular arc leaving ``P0`` along unit ``T0`` and ending at ``P1``.

    Returns ``inward`` (unit in-plane normal towards the centre; zero for a straight piece),
    ``kappa`` (1/mm, 0 for straight), ``length`` (arc length, mm) and ``half`` (half the sweep).
    """
    c, lc = _unit(P1 - P0)
    cos_h = _dot(T0, c)
    perp = c - cos_h[..., None] * T0
    inward, sin_h = _unit(perp)
    half = np.arctan2(sin_h, cos_h)
    straight = sin_h < _STRAIGHT_SIN
    inward = np.where(straight[..., None], 0.0, inward)
    kappa = np.where(straight | (lc <= 0), 0.0, 2.0 * sin_h / np.where(lc > 0, lc, 1.0))
    # L = R * 2 half = lc * half / sin(half); a chord exactly behind T0 (half = pi) is degenerate
    sinc = np.sinc(np.where(straight, 0.0, half) / np.pi)
    length = np.where(sinc > 1e-12, lc / np.where(sinc > 1e-12, sinc, 1.0), lc)
    return inward, kappa, length, np.where(straight, 0.0, half)


def _piece_point(start, tangent, inward, kappa, s):
    """Point at arc length ``s`` along a piece (stable for kappa -> 0)."""
    th = kappa * s
    along = s * np.sinc(th / np.pi)  # R sin(th)
    across = s * (th / 2.0) * np.sinc(th / (2.0 * np.pi)) ** 2  # R (1 - cos th)
    return start + along[..., None] * tangent + across[..., None] * inward


def _piece_tangent(tangent, inward, kappa, s):
    th = kappa * s
    return np.cos(th)[..., None] * tangent + np.sin(th)[..., None] * inward


def _piece_distance(P, start, tangent, inward, kappa, length):
    """Exact distance from points to pieces (arcs or segments), broadcast over leading axes.

    Returns ``(distance, s)`` with ``s`` the arc length of the closest point on the piece.
    """
    d = P - start
    x = _dot(d, tangent)
    y = _dot(d, inward)
    rest = d - x[..., None] * tangent - y[..., None] * inward
    z2 = _dot(rest, rest)
    k = kappa
    # angle of P seen from the centre, from the start point towards the tangent: atan2(k x, 1 - k y)
    th = np.mod(np.arctan2(k * x, 1.0 - k * y), 2.0 * np.pi)
    # |P - centre|_in-plane - R, computed without subtracting two large numbers
    radial = (k * (x * x + y * y) - 2.0 * y) / (np.sqrt((k * x) ** 2 + (1.0 - k * y) ** 2) + 1.0)
    is_arc = k > 0
    s_arc = np.where(is_arc, th / np.where(is_arc, k, 1.0), x)
    inside = np.where(is_arc, th <= k * length, (x >= 0.0) & (x <= length))
    d_in = np.sqrt(radial * radial + z2)
    end = _piece_point(start, tangent, inward, kappa, length)
    d0 = np.sqrt(_dot(d, d))
    de = P - end
    d1 = np.sqrt(_dot(de, de))
    dist = np.where(inside, d_in, np.minimum(d0, d1))
    s = np.where(inside, s_arc, np.where(d0 <= d1, 0.0, length))
    return dist, s


@dataclass(frozen=True)
class Biarc:
    """``m`` biarcs, each ``A -(arc 1)-> B -(arc 2)-> C``; arrays per arc have shape ``(m, 2, ...)``.

    Per arc: ``start`` point, unit ``tangent`` at the start, unit ``inward`` normal (in the arc's
    plane, towards the centre; zero for a straight piece), ``curvature`` (1/mm, 0 = straight) and
    arc ``length`` (mm).  ``a``/``b`` are the parameters of A.2/A.3 and ``proper`` says both are
    positive and finite, i.e. each arc sweeps less than 180 degrees.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    t1: np.ndarray
    t2: np.ndarray
    t3: np.ndarray
    a: np.ndarray
    b: np.ndarray
    proper: np.ndarray
    start: np.ndarray
    tangent: np.ndarray
    inward: np.ndarray
    curvature: np.ndarray
    length: np.ndarray

    def __len__(self) -> int:
        return len(self.A)

    @property
    def radius(self) -> np.ndarray:
        """(m, 2) arc radii, mm; ``inf`` for a straight piece."""
        k = self.curvature
        return np.where(k > 0, 1.0 / np.where(k > 0, k, 1.0), np.inf)

    @property
    def centre(self) -> np.ndarray:
        """(m, 2, 3) arc centres; the piece's midpoint for a straight piece (it has none)."""
        k = self.curvature
        r = np.where(k > 0, 1.0 / np.where(k > 0, k, 1.0), 0.0)
        mid = _piece_point(self.start, self.tangent, self.inward, k, self.length / 2.0)
        return np.where((k > 0)[..., None], self.start + r[..., None] * self.inward, mid)

    @property
    def normal(self) -> np.ndarray:
        """(m, 2, 3) unit normals of the arc planes (turning sense, right-handed: tangent x inward);
        zero for a straight piece."""
        return np.cross(self.tangent, self.inward)

    @property
    def sweep_rad(self) -> np.ndarray:
        """(m, 2) turning angle of each arc, radians (0 for straight)."""
        return self.curvature * self.length

    @property
    def end_tangent(self) -> np.ndarray:
        """(m, 2, 3) unit tangent at the end of each arc (from the arc itself)."""
        return _piece_tangent(self.tangent, self.inward, self.curvature, self.length)

    @property
    def end(self) -> np.ndarray:
        """(m, 2, 3) end point of each arc (from the arc itself)."""
        return _piece_point(self.start, self.tangent, self.inward, self.curvature, self.length)

    @property
    def straight(self) -> np.ndarray:
        """(m, 2) True for straight pieces."""
        return self.curvature <= 0

    @property
    def twist_rad(self) -> np.ndarray:
        """(m,) dihedral angle between the two arc planes in [0, pi/2] (0: planar); 0 when a piece
        is straight."""
        n = self.normal
        n1, n2 = n[:, 0], n[:, 1]
        return np.arctan2(np.sqrt(_dot(np.cross(n1, n2), np.cross(n1, n2))), np.abs(_dot(n1, n2)))

    @property
    def kind(self) -> np.ndarray:
        """(m,) ``'C'`` (both arcs turn the same way: plane normals at under 90 degrees), ``'S'``
        (opposite ways) or ``'L'`` (a piece is straight)."""
        n = self.normal
        c = _dot(n[:, 0], n[:, 1])
        out = np.where(c >= 0, "C", "S")
        return np.where(self.straight.any(axis=1), "L", out)

    def points(self, max_chord_error_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """``(owner, points)`` along the arcs; see :func:`biarc_chords`."""
        return biarc_chords(self, max_chord_error_mm)

    def distance(self, points: np.ndarray, owner: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Exact distance (and arc length from ``A`` of the closest point) of ``points[i]`` to
        biarc ``owner[i]``."""
        P = np.asarray(points, dtype=float)[:, None, :]
        o = np.asarray(owner)
        d, s = _piece_distance(P, self.start[o], self.tangent[o], self.inward[o], self.curvature[o],
                               self.length[o])
        s = s + np.stack([np.zeros(len(o)), self.length[o, 0]], axis=1)
        j = np.argmin(d, axis=1)
        r = np.arange(len(o))
        return d[r, j], s[r, j]


def biarc(A, t1, C, t3, method: str = "equal") -> Biarc:
    """Biarcs from ``A`` (tangent ``t1``) to ``C`` (tangent ``t3``), arrays (m, 3) or (3,).

    ``method="equal"`` (default) takes ``a = b`` (see the module docstring for why); ``"chui"`` takes
    the A.8 minimum of ``a + b`` (errata-corrected) where it is proper and ``a = b`` elsewhere.
    Parallel tangents (``w = 0``) give the equal-chord biarc with ``B`` the midpoint of ``AC`` (two
    equal arcs, an S unless ``t1`` is along ``AC``, which gives one straight line, radius ``inf``).
    ``A = C`` gives zero-length pieces.  Tangents need not be unit length.  No NaN for finite input.
    """
    if method not in ("equal", "chui"):
        raise ValueError(f"method must be 'equal' or 'chui', not {method!r}")
    A = np.atleast_2d(np.asarray(A, dtype=float))
    C = np.atleast_2d(np.asarray(C, dtype=float))
    t1 = _unit(np.atleast_2d(np.asarray(t1, dtype=float)))[0]
    t3 = _unit(np.atleast_2d(np.asarray(t3, dtype=float)))[0]
    A, C, t1, t3 = np.broadcast_arrays(A, C, t1, t3)
    s = C - A
    ss = _dot(s, s)
    p = _dot(s, t1)
    q = _dot(s, t3)
    dt = t1 - t3
    w = 0.5 * _dot(dt, dt)  # = 1 - t1.t3, without cancellation
    S = p + q
    parallel = w <= _W_PARALLEL
    wq = np.where(parallel, 1.0, w)
    root = np.sqrt(S * S + 2.0 * wq * ss)
    # positive root of w a^2 + S a - ss/2 = 0, in the form without cancellation for either sign of S
    den = S + root
    a_eq = np.where(S >= 0, ss / np.where(den > 0, den, 1.0), (root - S) / (2.0 * wq))
    a_eq = np.where(ss > 0, a_eq, 0.0)
    # w = 0: A.6 reads a (p + q) = ss/2 for a = b
    a_par = np.where(S > 0, ss / np.where(S > 0, 2.0 * S, 1.0), np.inf)
    a_eq = np.where(parallel, a_par, a_eq)
    a = a_eq.copy()
    b = a_eq.copy()
    if method == "chui":
        u2 = p * q + w * ss / 2.0
        ok = ~parallel & (u2 > 0)
        u = np.sqrt(np.where(ok, u2, 0.0))
        ac = (u - q) / wq
        bc = (u - p) / wq
        ok &= (ac > 0) & (bc > 0) & np.isfinite(ac) & np.isfinite(bc)
        a = np.where(ok, ac, a)
        b = np.where(ok, bc, b)
    # B = A + (a s + a b (t1 - t3)) / (a + b)   [from A.2 and A.5]; the midpoint when t1 = t3
    fin = np.isfinite(a) & np.isfinite(b) & (a + b > 0)
    ab = np.where(fin, a + b, 1.0)
    wa = np.where(fin, a / ab, 0.5)
    wab = np.where(fin, a * b / ab, 0.0)
    B = A + wa[:, None] * s + np.where(parallel, 0.0, wab)[:, None] * dt
    # t2 = t1 reflected in the chord AB (the end tangent of arc 1); equals (s - a t1 - b t3)/(a + b)
    c1, l1 = _unit(B - A)
    t2 = np.where((l1 > 0)[:, None], 2.0 * _dot(t1, c1)[:, None] * c1 - t1, t1)
    proper = fin & (a > 0) & (b > 0) & (ss > 0)
    in1, k1, L1, _ = _arc_from_chord(A, t1, B)
    in2, k2, L2, _ = _arc_from_chord(B, t2, C)
    return Biarc(
        A=A, B=B, C=C, t1=t1, t2=t2, t3=t3,
        a=np.where(np.isfinite(a), a, np.inf), b=np.where(np.isfinite(b), b, np.inf),
        proper=proper,
        start=np.stack([A, B], axis=1),
        tangent=np.stack([t1, t2], axis=1),
        inward=np.stack([in1, in2], axis=1),
        curvature=np.stack([k1, k2], axis=1),
        length=np.stack([L1, L2], axis=1),
    )


def biarc_chords(biarcs: Biarc, tol_mm: float) -> tuple[np.ndarray, np.ndarray]:
    """Points along the biarcs in order, ``(owner (N,), points (N, 3))``, ``owner`` = biarc index.

    Each arc is cut into equal-angle chords whose sagitta ``R (1 - cos(d/2))`` is at most
    ``tol_mm`` (so no chord is farther than ``tol_mm`` from its arc); straight pieces give one chord.
    Every biarc's start ``A`` is listed unless it is the previous biarc's end (within 1e-9 mm), so a
    G1 chain gives one polyline and a jump (a retract between pieces) shows as a new start point.
    Arc ends are the exact ``B`` and ``C``.
    """
    if tol_mm <= 0:
        raise ValueError("tol_mm must be positive")
    m = len(biarcs)
    if m == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 3))
    k = biarcs.curvature.reshape(-1)
    L = biarcs.length.reshape(-1)
    x = np.minimum(tol_mm * k / 2.0, 1.0)
    dmax = 4.0 * np.arcsin(np.sqrt(x))  # 2 acos(1 - tol k), stable for small tol k
    nseg = np.where(k > 0, np.ceil(k * L / np.where(dmax > 0, dmax, 1.0) * (1.0 + 1e-12)), 1.0)
    nseg = np.where(L > 0, np.maximum(nseg, 1.0), 0.0).astype(np.int64)
    # start points of biarcs not joined to the previous one
    gap = np.ones(m, dtype=bool)
    if m > 1:
        gap[1:] = np.sqrt(_dot(biarcs.A[1:] - biarcs.C[:-1], biarcs.A[1:] - biarcs.C[:-1])) > _SAME_POINT_MM
    # one block per biarc: [A if gap] + arc-1 points + arc-2 points
    n_first = gap.astype(np.int64)
    per_piece = nseg.reshape(m, 2)
    counts = n_first + per_piece.sum(axis=1)
    total = int(counts.sum())
    owner = np.repeat(np.arange(m), counts)
    pts = np.empty((total, 3))
    offs = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pts[offs[gap]] = biarcs.A[gap]
    # piece points
    piece = np.repeat(np.arange(2 * m), nseg)
    first_of_piece = np.concatenate([[0], np.cumsum(nseg)[:-1]])
    j = np.arange(len(piece)) - first_of_piece[piece] + 1  # 1..nseg
    sval = L[piece] * j / nseg[piece]
    st = biarcs.start.reshape(-1, 3)[piece]
    tg = biarcs.tangent.reshape(-1, 3)[piece]
    iw = biarcs.inward.reshape(-1, 3)[piece]
    P = _piece_point(st, tg, iw, k[piece], sval)
    last = j == nseg[piece]
    ends = np.stack([biarcs.B, biarcs.C], axis=1).reshape(-1, 3)
    P[last] = ends[piece[last]]
    # positions in the output: after each biarc's optional start point, in order
    bi = piece // 2
    within = np.arange(len(piece)) - np.concatenate([[0], np.cumsum(per_piece.sum(axis=1))[:-1]])[bi]
    pts[offs[bi] + n_first[bi] + within] = P
    return owner, pts


def distance_to_biarcs(points: np.ndarray, biarcs: Biarc, owner: np.ndarray | None = None,
                       chunk: int = 2_000_000) -> np.ndarray:
    """Exact distance of each point to the biarcs: to biarc ``owner[i]`` when given, else to the
    nearest of all of them (brute force over all biarcs, in chunks of about ``chunk`` pairs)."""
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    if owner is not None:
        return biarcs.distance(P, np.asarray(owner))[0]
    m = len(biarcs)
    out = np.full(len(P), np.inf)
    if m == 0:
        return out
    step = max(1, chunk // (2 * m))
    st, tg, iw = biarcs.start.reshape(-1, 3), biarcs.tangent.reshape(-1, 3), biarcs.inward.reshape(-1, 3)
    k, L = biarcs.curvature.reshape(-1), biarcs.length.reshape(-1)
    for i in range(0, len(P), step):
        d, _ = _piece_distance(P[i:i + step, None, :], st, tg, iw, k, L)
        out[i:i + step] = d.min(axis=1)
    return out


@dataclass(frozen=True)
class BiarcFit:
    """Result of :func:`fit_biarcs`.

    ``biarcs`` (m spans) run from ``points[span_start[k]]`` to ``points[span_end[k]]``;
    ``path_piece[k]`` numbers the G1 pieces (split at ``breaks`` and corners).  ``errors[i]`` is the
    exact distance of input point ``i`` to the biarc of its own span (recomputed for all points after
    fitting; an upper bound of its distance to the whole curve), ``max_error_mm`` their maximum.
    ``n_arcs_out`` counts the pieces of positive length, collinear straight neighbours once
    (``n_lines_out`` of them straight); ``tangents`` holds the tangents used, one array per piece.
    """

    biarcs: Biarc
    span_start: np.ndarray
    span_end: np.ndarray
    path_piece: np.ndarray
    corners: np.ndarray
    errors: np.ndarray
    tol_mm: float
    n_points_in: int
    n_biarcs: int
    n_arcs_out: int
    n_lines_out: int
    max_error_mm: float
    tangents: list = field(repr=False, default_factory=list)

    def points(self, max_chord_error_mm: float) -> tuple[np.ndarray, np.ndarray]:
        """``(owner, points)`` along the fitted curve; see :func:`biarc_chords`."""
        return biarc_chords(self.biarcs, max_chord_error_mm)


def _find_corners(P: np.ndarray, corner_rad: float) -> np.ndarray:
    d = np.diff(P, axis=0)
    u, ln = _unit(d)
    if len(d) < 2:
        return np.zeros(0, dtype=np.int64)
    c = np.clip(_dot(u[:-1], u[1:]), -1.0, 1.0)
    both = (ln[:-1] > 0) & (ln[1:] > 0)
    return np.flatnonzero(both & (np.arccos(c) > corner_rad)) + 1


def _span_ok(P, T, i, j, tol_mm, method) -> bool:
    if j - i < 2:
        return True  # no point in between; a single step is always accepted
    bi = biarc(P[i], T[i], P[j], T[j], method=method)
    if not bool(bi.proper[0]):
        return False
    inner = P[i + 1:j]
    d, s = bi.distance(inner, np.zeros(len(inner), dtype=np.int64))
    if not np.all(d <= tol_mm):
        return False
    # the curve must pass the points in their order (not merely near each of them)
    return bool(np.all(np.diff(s) >= -2.0 * tol_mm))


@njit(cache=True, nogil=True, inline="always")
def _u3(x, y, z):
    """A unit vector and the norm (a zero vector stays zero), as :func:`_unit`."""
    n = math.sqrt(x * x + y * y + z * z)
    if n > 0.0:
        return x / n, y / n, z / n, n
    return x, y, z, n


@njit(cache=True, nogil=True, inline="always")
def _sinc(x):
    """``numpy.sinc``: sin(pi x) / (pi x)."""
    y = math.pi * (x if x != 0.0 else 1.0e-20)
    return math.sin(y) / y


@njit(cache=True, nogil=True)
def _arc1(p0, t0, p1, out):
    """:func:`_arc_from_chord` of one arc into ``out``: [inward (3), kappa, length]."""
    cx, cy, cz, lc = _u3(p1[0] - p0[0], p1[1] - p0[1], p1[2] - p0[2])
    cos_h = t0[0] * cx + t0[1] * cy + t0[2] * cz
    ix, iy, iz, sin_h = _u3(cx - cos_h * t0[0], cy - cos_h * t0[1], cz - cos_h * t0[2])
    half = math.atan2(sin_h, cos_h)
    straight = sin_h < _STRAIGHT_SIN
    if straight:
        ix = iy = iz = 0.0
    kappa = 0.0 if (straight or lc <= 0.0) else 2.0 * sin_h / (lc if lc > 0.0 else 1.0)
    sc = _sinc((0.0 if straight else half) / math.pi)
    out[0], out[1], out[2] = ix, iy, iz
    out[3] = kappa
    out[4] = lc / sc if sc > 1e-12 else lc


@njit(cache=True, nogil=True, inline="always")
def _dist1(px, py, pz, st, tg, iw, k, length):
    """:func:`_piece_distance` of one point to one piece: (distance, arc length of the closest point)."""
    dx, dy, dz = px - st[0], py - st[1], pz - st[2]
    x = dx * tg[0] + dy * tg[1] + dz * tg[2]
    y = dx * iw[0] + dy * iw[1] + dz * iw[2]
    rx, ry, rz = dx - x * tg[0] - y * iw[0], dy - x * tg[1] - y * iw[1], dz - x * tg[2] - y * iw[2]
    z2 = rx * rx + ry * ry + rz * rz
    th = math.atan2(k * x, 1.0 - k * y)
    th = th - 2.0 * math.pi * math.floor(th / (2.0 * math.pi))
    radial = (k * (x * x + y * y) - 2.0 * y) / (math.sqrt((k * x) ** 2 + (1.0 - k * y) ** 2) + 1.0)
    if k > 0.0:
        s_arc = th / k
        inside = th <= k * length
    else:
        s_arc = x
        inside = (x >= 0.0) and (x <= length)
    if inside:
        return math.sqrt(radial * radial + z2), s_arc
    t2 = k * length
    along = length * _sinc(t2 / math.pi)
    across = length * (t2 / 2.0) * _sinc(t2 / (2.0 * math.pi)) ** 2
    ex = st[0] + along * tg[0] + across * iw[0]
    ey = st[1] + along * tg[1] + across * iw[1]
    ez = st[2] + along * tg[2] + across * iw[2]
    d0 = math.sqrt(dx * dx + dy * dy + dz * dz)
    d1 = math.sqrt((px - ex) ** 2 + (py - ey) ** 2 + (pz - ez) ** 2)
    if d0 <= d1:
        return d0, 0.0
    return d1, length


@njit(cache=True, nogil=True)
def _span_ok_equal(P, T, i, j, tol_mm, scratch):
    """:func:`_span_ok` for ``method="equal"``, compiled (the same formulas as :func:`biarc` for one span)."""
    if j - i < 2:
        return True
    A = P[i]
    C = P[j]
    t1x, t1y, t1z, _ = _u3(T[i, 0], T[i, 1], T[i, 2])
    t3x, t3y, t3z, _ = _u3(T[j, 0], T[j, 1], T[j, 2])
    sx, sy, sz = C[0] - A[0], C[1] - A[1], C[2] - A[2]
    ss = sx * sx + sy * sy + sz * sz
    p = sx * t1x + sy * t1y + sz * t1z
    q = sx * t3x + sy * t3y + sz * t3z
    dtx, dty, dtz = t1x - t3x, t1y - t3y, t1z - t3z
    w = 0.5 * (dtx * dtx + dty * dty + dtz * dtz)
    S = p + q
    parallel = w <= _W_PARALLEL
    wq = 1.0 if parallel else w
    root = math.sqrt(S * S + 2.0 * wq * ss)
    den = S + root
    if S >= 0:
        a = ss / (den if den > 0 else 1.0)
    else:
        a = (root - S) / (2.0 * wq)
    if not ss > 0:
        a = 0.0
    if parallel:
        a = ss / (2.0 * S) if S > 0 else np.inf
    b = a
    fin = math.isfinite(a) and (a + b > 0)
    if not (fin and a > 0 and ss > 0):
        return False                      # not proper
    ab = a + b
    wa = a / ab
    wab = 0.0 if parallel else a * b / ab
    Bx, By, Bz = A[0] + wa * sx + wab * dtx, A[1] + wa * sy + wab * dty, A[2] + wa * sz + wab * dtz
    c1x, c1y, c1z, l1 = _u3(Bx - A[0], By - A[1], Bz - A[2])
    if l1 > 0:
        d = t1x * c1x + t1y * c1y + t1z * c1z
        t2x, t2y, t2z = 2.0 * d * c1x - t1x, 2.0 * d * c1y - t1y, 2.0 * d * c1z - t1z
    else:
        t2x, t2y, t2z = t1x, t1y, t1z
    t1 = scratch[0]
    t2 = scratch[1]
    B = scratch[2]
    a1 = scratch[3]
    a2 = scratch[4]
    t1[0], t1[1], t1[2] = t1x, t1y, t1z
    t2[0], t2[1], t2[2] = t2x, t2y, t2z
    B[0], B[1], B[2] = Bx, By, Bz
    _arc1(A, t1, B, a1)
    _arc1(B, t2, C, a2)
    L1 = a1[4]
    prev = -np.inf
    for m in range(i + 1, j):
        d1, s1 = _dist1(P[m, 0], P[m, 1], P[m, 2], A, t1, a1[:3], a1[3], a1[4])
        d2, s2 = _dist1(P[m, 0], P[m, 1], P[m, 2], B, t2, a2[:3], a2[3], a2[4])
        if d2 < d1:
            d1, s1 = d2, s2 + L1
        if not d1 <= tol_mm:
            return False
        # the curve must pass the points in their order (not merely near each of them)
        if m > i + 1 and s1 - prev < -2.0 * tol_mm:
            return False
        prev = s1
    return True


@njit(cache=True, nogil=True)
def _fit_piece_equal(P, T, tol_mm):
    """:func:`_fit_piece` for ``method="equal"``, compiled: (k, 2) span ends (local indices)."""
    n = P.shape[0]
    out = np.empty((max(n - 1, 0), 2), np.int64)
    scratch = np.zeros((5, 5))
    k = 0
    i = 0
    while i < n - 1:
        good = i + 1
        bad = -1
        step = 2
        while good < n - 1:
            j = min(i + step, n - 1)
            if _span_ok_equal(P, T, i, j, tol_mm, scratch):
                good = j
                step *= 2
            else:
                bad = j
                break
        if bad >= 0:
            while bad - good > 1:
                mid = (good + bad) // 2
                if _span_ok_equal(P, T, i, mid, tol_mm, scratch):
                    good = mid
                else:
                    bad = mid
        out[k, 0] = i
        out[k, 1] = good
        k += 1
        i = good
    return out[:k]


def _fit_piece(P, T, tol_mm, method) -> list[tuple[int, int]]:
    """Greedy longest spans over one G1 piece (local indices): doubling, then bisection. The reference
    (numpy, one span at a time); ``fit_biarcs`` runs :func:`_fit_piece_equal` for ``method="equal"``."""
    n = len(P)
    spans = []
    i = 0
    while i < n - 1:
        good, bad, step = i + 1, None, 2
        while good < n - 1:
            j = min(i + step, n - 1)
            if _span_ok(P, T, i, j, tol_mm, method):
                good = j
                step *= 2
            else:
                bad = j
                break
        if bad is not None:
            while bad - good > 1:
                mid = (good + bad) // 2
                if _span_ok(P, T, i, mid, tol_mm, method):
                    good = mid
                else:
                    bad = mid
        spans.append((i, good))
        i = good
    return spans


def fit_biarcs(points: np.ndarray, tol_mm: float, tangents: np.ndarray | None = None,
               breaks=(), corners=(), corner_rad: float = np.pi / 3, method: str = "equal",
               memo: dict | None = None) -> BiarcFit:
    """Replace a dense polyline of ball centres by few G1 biarcs within ``tol_mm``.

    The path is cut into pieces: at each index in ``breaks`` a new piece starts and the move from
    ``points[i-1]`` to ``points[i]`` is not fitted (a retract or link); at corners -- where the
    polyline turns by more than ``corner_rad`` between neighbouring segments, plus any indices in
    ``corners`` -- the pieces share the corner point (G0 there).  Along each piece, spans are chosen
    greedily (from the previous span's end, the farthest end found by doubling then bisection) such
    that every input point strictly between the span's ends lies within ``tol_mm`` of the span's
    biarc (exact point-to-arc distance) and is passed in order; consecutive spans share end points
    and tangents (G1).  Tangents come from ``tangents`` (n, 3) if given, else from
    :func:`path_tangents` per piece; at a piece end that is a corner the tangent is always the
    piece's own end-circle tangent (one vector cannot serve both sides of a corner).  A span of one
    segment is always accepted.  ``max_error_mm`` is recomputed afterwards for all input points.
    ``memo``: a dict kept between calls (refits of the same path with more ``corners``): the spans
    of a piece are taken from it where the same points were fitted with the same tolerance and
    method before (without ``tangents`` only; the fit of a piece depends on nothing else).
    """
    P = np.asarray(points, dtype=float).reshape(-1, 3)
    n = len(P)
    if tol_mm <= 0:
        raise ValueError("tol_mm must be positive")
    user_T = None if tangents is None else _unit(np.asarray(tangents, dtype=float).reshape(-1, 3))[0]
    if user_T is not None and len(user_T) != n:
        raise ValueError("tangents must have one row per point")
    brk = sorted({int(b) for b in breaks if 0 < int(b) < n})
    extra = np.array(sorted({int(c) for c in corners if 0 < int(c) < n - 1}), dtype=np.int64)
    pieces, cor = [], set()
    for lo, hi in zip([0] + brk, [b - 1 for b in brk] + [n - 1]):
        # corners are looked for inside each run between breaks (the link move is not the path); the
        # given ones inside it by bisection (a path has thousands of runs and of corners)
        found = {lo + int(c) for c in _find_corners(P[lo:hi + 1], corner_rad)}
        inside = extra[np.searchsorted(extra, lo, side="right"):np.searchsorted(extra, hi, side="left")]
        here = sorted(found | {int(c) for c in inside})
        cor.update(here)
        for a, b in zip([lo] + here, here + [hi]):
            pieces.append((a, b))
    s0, s1, owner_piece, Ts = [], [], [], []
    pieces = [pc for pc in pieces if pc[1] > pc[0]]  # a lone point between two breaks: no move
    for pi, (i0, i1) in enumerate(pieces):
        Pp = P[i0:i1 + 1]
        own = path_tangents(Pp)
        if user_T is None:
            Tp = own
        else:
            Tp = user_T[i0:i1 + 1].copy()
            if i0 in cor:
                Tp[0] = own[0]
            if i1 in cor:
                Tp[-1] = own[-1]
        Ts.append(Tp)
        key = (Pp.tobytes(), float(tol_mm), method) if memo is not None and user_T is None else None
        spans = None if key is None else memo.get(key)
        if spans is None:
            if method == "equal":
                spans = [(int(a), int(b)) for a, b in _fit_piece_equal(np.ascontiguousarray(Pp),
                                                                        np.ascontiguousarray(Tp), float(tol_mm))]
            else:
                spans = _fit_piece(Pp, Tp, tol_mm, method)
            if key is not None:
                memo[key] = spans
        for a, b in spans:
            s0.append(i0 + a)
            s1.append(i0 + b)
            owner_piece.append(pi)
    s0 = np.asarray(s0, dtype=np.int64)
    s1 = np.asarray(s1, dtype=np.int64)
    owner_piece = np.asarray(owner_piece, dtype=np.int64)
    if len(s0):
        p0 = np.asarray([pieces[k][0] for k in owner_piece])
        tA = np.stack([Ts[k][i - i0] for k, i0, i in zip(owner_piece, p0, s0)])
        tC = np.stack([Ts[k][i - i0] for k, i0, i in zip(owner_piece, p0, s1)])
        bis = biarc(P[s0], tA, P[s1], tC, method=method)
    else:
        empty = np.zeros((0, 3))
        bis = biarc(empty, empty, empty, empty)
    # independent error: every input point against the biarc of every span that contains it
    errors = np.zeros(n)
    if len(s0):
        cnt = s1 - s0 + 1
        own = np.repeat(np.arange(len(s0)), cnt)
        idx = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt) + np.repeat(s0, cnt)
        d, _ = bis.distance(P[idx], own)
        np.maximum.at(errors, idx, d)
    n_arcs, n_lines = _count_pieces(bis, owner_piece)
    return BiarcFit(
        biarcs=bis, span_start=s0, span_end=s1, path_piece=owner_piece,
        corners=np.asarray(sorted(cor), dtype=np.int64), errors=errors, tol_mm=float(tol_mm),
        n_points_in=n, n_biarcs=len(s0), n_arcs_out=n_arcs, n_lines_out=n_lines,
        max_error_mm=float(errors.max()) if n else 0.0, tangents=Ts,
    )


def _count_pieces(bis: Biarc, owner_piece: np.ndarray) -> tuple[int, int]:
    """Pieces of positive length, a run of collinear straight pieces counted once; and how many of
    the counted pieces are straight lines."""
    m = len(bis)
    if m == 0:
        return 0, 0
    L = bis.length.reshape(-1)
    straight = bis.straight.reshape(-1)
    tg = bis.tangent.reshape(-1, 3)
    grp = np.repeat(owner_piece, 2)
    keep = L > 1e-12
    L, straight, tg, grp = L[keep], straight[keep], tg[keep], grp[keep]
    merged = np.zeros(len(L), dtype=bool)
    if len(L) > 1:
        collinear = _dot(tg[1:], tg[:-1]) > 1 - 1e-12
        merged[1:] = straight[1:] & straight[:-1] & (grp[1:] == grp[:-1]) & collinear
    counted = ~merged
    return int(counted.sum()), int((counted & straight).sum())
