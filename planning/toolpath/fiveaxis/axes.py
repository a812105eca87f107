"""A tool axis for every ball-centre position of a simultaneous 5-axis finishing path (issue 19;
Chui, Chiu and Yu 2008 §3.5, eq. 9-12).

For each cutting position (ball centre ``c``, mm, any Cartesian frame) along a pass:

1. **Contact normal** ``n`` (:func:`contact_normals`): the ball rests on the scan, so the unit
   vector from the nearest scan point ``q`` to ``c`` is the surface normal at the contact
   (``|c - q|`` is ``R`` up to the gouge tolerance).
2. **Feed direction** ``t`` (:func:`feed_directions`): the unit tangent of the centre path, from the
   circle through each point and its two neighbours on the same pass (exact on a circle; the
   chord direction where the three are in line), one-sided at the ends of a pass.
3. **Reference direction** ``m`` in the plane normal to ``t`` (:func:`reference_directions`):
   ``"frenet"`` (Chui's default): the principal normal of the centre curve (eq. 9, towards the
   centre of the three-point circle), turned to the outward side (``m . n > 0``), because the
   paper's tool axis must leave the part; where the curve is straight (curvature below
   :data:`KAPPA_MIN_PER_MM`) or the principal normal lies more than 45 degrees from the surface
   normal (a pass that curves sideways on the surface: its Frenet normal lies in the surface), the
   surface normal projected normal to ``t`` takes its place. ``"surface"``: always that projected
   surface normal (the Darboux frame of the pass).
4. **Tilt and lead** (:func:`lead_tilt_axes`): eq. 12, ``a0 = cos(tilt) m + sin(tilt) b`` with the
   binormal ``b = t x m`` (the axis leans sideways, to the right of the feed seen from the spindle
   for a positive tilt), then the lead ``a = cos(lead) a0 + sin(lead) t`` (a positive lead puts the
   spindle ahead of the contact along the feed). Chui suggests about 15 degrees of tilt so that the
   tip, whose cutting speed is zero, does not cut.
5. **Tool cone** (:func:`clamp_to_cone`): the axis is turned in the plane of ``n`` and ``a`` to
   within ``[v1, v2]`` of the normal (Makki's tool visibility, ``visibility.cone_deg``).
6. **Admissible axes** (:func:`plan_axes`): an axis must pass the caller's test ``ok(centres,
   axes)`` (the tool assembly clear of the cloud, the rotary and linear travel); where the ideal
   axis fails, axes on rings inside the cone are tried, nearest to the ideal first.
7. **Rate limit** (:func:`limit_axis_rate`): along a pass the axis turns at most
   ``max_rate_deg_per_mm`` per mm of centre path, by forward and backward sweeps that move each
   axis towards its wanted one by at most the allowed angle and back into its cone (alternated a
   few times, so that where the cone narrows round an edge the axis starts turning early enough).
   Smoothing moves axes, so the test of step 6 is applied again, for a few rounds (a smoothed axis
   that fails is replaced by the admissible ring axis nearest to it). What still fails is reported: a position with no admissible axis is
   ``blocked`` (cut out by the caller, never cut with a bad axis) and a step that still turns too
   fast is a ``break`` (the caller ends the pass there: the tool leaves along its axis, turns in
   air and comes back).

Angles in degrees in every public name; radians inside (``_rad``). Vectorised numpy; the sweeps of
step 7 are a numba kernel (inherently sequential along a pass).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from planning.errors import ParameterError

__all__ = [
    "AXIS_FRAMES", "KAPPA_MIN_PER_MM", "AxisPlan", "clamp_to_cone", "contact_normals", "feed_directions",
    "lead_tilt_axes", "limit_axis_rate", "plan_axes", "reference_directions", "ring_candidates", "slerp",
    "turn_deg",
]

AXIS_FRAMES = ("frenet", "surface")

#: Below this curvature of the centre path (1/mm, a radius above 10 m) the Frenet frame is undefined
#: and the surface normal takes its place.
KAPPA_MIN_PER_MM = 1e-4

#: The Frenet normal is used only within this angle of the surface normal (degrees).
FRENET_MAX_DEG = 45.0


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 0, n, 1.0)


def turn_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n,) angle between unit vectors ``a`` and ``b`` (n,3), degrees (atan2 form: exact near 0)."""
    c = np.einsum("ij,ij->i", a, b)
    s = np.linalg.norm(np.cross(a, b), axis=1)
    return np.degrees(np.arctan2(s, c))


def slerp(a: np.ndarray, b: np.ndarray, f) -> np.ndarray:
    """(n,3) unit vectors a fraction ``f`` (a scalar or (n,)) of the way from the unit vectors ``a`` to
    ``b`` (n,3) along the great circle (linear, then normalised, where they are within 1e-9 rad)."""
    f = np.broadcast_to(np.asarray(f, dtype=np.float64), (a.shape[0],))[:, None]
    th = np.arccos(np.clip(np.einsum("ij,ij->i", a, b), -1.0, 1.0))[:, None]
    s = np.sin(th)
    small = s < 1e-9
    safe = np.where(small, 1.0, s)
    w0 = np.where(small, 1 - f, np.sin((1 - f) * th) / safe)
    w1 = np.where(small, f, np.sin(f * th) / safe)
    out = w0 * a + w1 * b
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def contact_normals(centres: np.ndarray, surface_points: np.ndarray, tree: cKDTree | None = None) -> np.ndarray:
    """(n,3) unit surface normals at the contacts of ball centres ``centres`` (n,3, mm) resting on
    ``surface_points`` (K,3, mm): from the nearest surface point towards the centre (step 1)."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    tree = cKDTree(surface_points) if tree is None else tree
    _, j = tree.query(c, k=1)
    return _unit(c - np.asarray(surface_points, dtype=np.float64)[j])


def _runs(pass_index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(same_prev, same_next)`` (n,) bool: the point before / after is on the same pass (>= 0)."""
    pi = np.asarray(pass_index).reshape(-1)
    on = pi >= 0
    same = on[1:] & on[:-1] & (pi[1:] == pi[:-1])
    prev = np.concatenate([[False], same])
    nxt = np.concatenate([same, [False]])
    return prev, nxt


def _three_point(p0, p1, p2):
    """Unit tangent at ``p1`` (n,3) of the circle through ``p0 p1 p2``, the unit principal normal there
    (towards the circle's centre; 0 where in line) and the curvature (1/mm; 0 where in line)."""
    u, w = p0 - p1, p2 - p1
    lu, lw = np.linalg.norm(u, axis=1), np.linalg.norm(w, axis=1)
    ok = (lu > 0) & (lw > 0)
    lu, lw = np.where(ok, lu, 1.0), np.where(ok, lw, 1.0)
    # tangent of the circle at p1: the bisector rule t ~ w/|w|^2 - u/|u|^2 (exact on a circle)
    t = w / (lw ** 2)[:, None] - u / (lu ** 2)[:, None]
    t = _unit(t)
    axb = np.cross(u, w)
    area2 = np.linalg.norm(axb, axis=1)
    chord = np.linalg.norm(p2 - p0, axis=1)
    kappa = np.where(ok & (chord > 0), 2.0 * area2 / np.maximum(lu * lw * chord, 1e-300), 0.0)
    # principal normal: towards the centre, in the plane, normal to t
    mid = _unit(u / lu[:, None] + w / lw[:, None])          # bisector of the two chords points inwards
    nrm = _unit(mid - np.einsum("ij,ij->i", mid, t)[:, None] * t)
    nrm[kappa <= 0] = 0.0
    return t, nrm, kappa


def feed_directions(centres: np.ndarray, pass_index: np.ndarray) -> np.ndarray:
    """(n,3) unit feed direction at every centre (step 2): the three-point circle's tangent inside a
    pass, the chord to the neighbour at its ends; a point on no pass (``pass_index`` -1) gets the
    direction of the move that reaches it (zero for a repeated point)."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    n = c.shape[0]
    prev, nxt = _runs(pass_index)
    out = np.zeros((n, 3))
    if n < 2:
        return out
    back = np.zeros((n, 3))
    back[1:] = c[1:] - c[:-1]
    fwd = np.zeros((n, 3))
    fwd[:-1] = c[1:] - c[:-1]
    out[:] = _unit(back)
    out[0] = _unit(fwd[:1])[0]
    only_next = nxt & ~prev
    out[only_next] = _unit(fwd[only_next])
    both = np.flatnonzero(prev & nxt)
    if both.size:
        t, _, _ = _three_point(c[both - 1], c[both], c[both + 1])
        out[both] = t
        # the ends of a pass of three or more: the end circle's tangent, the inner neighbour's tangent
        # mirrored about the chord (the two tangents at a chord's ends are symmetric about it)
        inner = np.zeros(n, dtype=bool)
        inner[both] = True
        first = np.flatnonzero(only_next[:-1] & inner[1:])
        d = _unit(c[first + 1] - c[first])
        t1 = out[first + 1]
        out[first] = _unit(2.0 * np.einsum("ij,ij->i", t1, d)[:, None] * d - t1)
        last = np.flatnonzero((prev & ~nxt)[1:] & inner[:-1]) + 1
        d = _unit(c[last] - c[last - 1])
        t1 = out[last - 1]
        out[last] = _unit(2.0 * np.einsum("ij,ij->i", t1, d)[:, None] * d - t1)
    return out


def reference_directions(centres: np.ndarray, pass_index: np.ndarray, tangents: np.ndarray, normals: np.ndarray,
                         frame: str = "frenet") -> np.ndarray:
    """(n,3) unit reference direction ``m`` normal to ``tangents`` (step 3): the outward Frenet
    principal normal of the centre path (``frame="frenet"``, Chui eq. 9) where it is defined and
    within :data:`FRENET_MAX_DEG` of the surface normal, else the surface ``normals`` projected
    normal to the tangent (always, for ``frame="surface"``)."""
    if frame not in AXIS_FRAMES:
        raise ParameterError(f"axis frame must be one of {AXIS_FRAMES}, not {frame!r}")
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    t = np.asarray(tangents, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    proj = nrm - np.einsum("ij,ij->i", nrm, t)[:, None] * t
    length = np.linalg.norm(proj, axis=1)
    m = np.where((length > 1e-9)[:, None], proj / np.maximum(length, 1e-300)[:, None], nrm)
    if frame == "surface":
        return m
    prev, nxt = _runs(pass_index)
    both = np.flatnonzero(prev & nxt)
    if both.size:
        _, pn, kappa = _three_point(c[both - 1], c[both], c[both + 1])
        side = np.sign(np.einsum("ij,ij->i", pn, nrm[both]))
        pn = pn * np.where(side == 0, 1.0, side)[:, None]
        close = np.einsum("ij,ij->i", pn, nrm[both]) >= math.cos(math.radians(FRENET_MAX_DEG))
        use = (kappa > KAPPA_MIN_PER_MM) & close
        m[both[use]] = pn[use]
    return m


def lead_tilt_axes(reference: np.ndarray, tangents: np.ndarray, *, lead_deg: float, tilt_deg: float) -> np.ndarray:
    """(n,3) unit tool axes from the reference direction and the feed direction (step 4, Chui eq. 12:
    ``a0 = cos(tilt) m + sin(tilt) (t x m)``, then ``a = cos(lead) a0 + sin(lead) t``)."""
    m = np.asarray(reference, dtype=np.float64)
    t = np.asarray(tangents, dtype=np.float64)
    tilt, lead = math.radians(float(tilt_deg)), math.radians(float(lead_deg))
    b = np.cross(t, m)
    a0 = math.cos(tilt) * m + math.sin(tilt) * b
    return _unit(math.cos(lead) * a0 + math.sin(lead) * t)


def _perp(normals: np.ndarray, axes: np.ndarray, fallback: np.ndarray | None) -> np.ndarray:
    """Unit direction of ``axes`` normal to ``normals``; where the axis lies along the normal, the
    ``fallback`` (projected) or any normal direction."""
    p = axes - np.einsum("ij,ij->i", axes, normals)[:, None] * normals
    length = np.linalg.norm(p, axis=1)
    bad = length < 1e-9
    if bad.any():
        fb = None if fallback is None else np.asarray(fallback, dtype=np.float64)[bad]
        if fb is not None:
            fb = fb - np.einsum("ij,ij->i", fb, normals[bad])[:, None] * normals[bad]
        alt = np.cross(normals[bad], np.where(np.abs(normals[bad][:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
        if fb is not None:
            alt = np.where((np.linalg.norm(fb, axis=1) > 1e-9)[:, None], fb, alt)
        p[bad] = alt
    return _unit(p)


def clamp_to_cone(axes: np.ndarray, normals: np.ndarray, cone_deg, fallback: np.ndarray | None = None) -> np.ndarray:
    """(n,3) the ``axes`` turned, in the plane they span with ``normals``, to within ``cone_deg`` =
    ``(v1, v2)`` degrees of the normal (step 5); axes already inside are returned unchanged. An axis
    along the normal is turned towards ``fallback`` (e.g. the tilt direction)."""
    a = np.asarray(axes, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    v1, v2 = (float(v) for v in cone_deg)
    ang = turn_deg(a, nrm)
    out = a.copy()
    low, high = ang < v1, ang > v2
    fix = low | high
    if fix.any():
        want = np.radians(np.where(low, v1, v2)[fix])
        p = _perp(nrm[fix], a[fix], None if fallback is None else np.asarray(fallback)[fix])
        out[fix] = np.cos(want)[:, None] * nrm[fix] + np.sin(want)[:, None] * p
    return out


@njit(cache=True, nogil=True)
def _toward(p0, p1, p2, q0, q1, q2, limit_rad):
    """The unit vector ``p`` turned towards ``q`` by at most ``limit_rad`` (great circle)."""
    cx = p1 * q2 - p2 * q1
    cy = p2 * q0 - p0 * q2
    cz = p0 * q1 - p1 * q0
    s = math.sqrt(cx * cx + cy * cy + cz * cz)
    c = p0 * q0 + p1 * q1 + p2 * q2
    ang = math.atan2(s, c)
    if ang <= limit_rad or ang == 0.0:
        return q0, q1, q2
    # slerp by f = limit / ang
    f = limit_rad / ang
    sa = math.sin(ang)
    w0 = math.sin((1.0 - f) * ang) / sa
    w1 = math.sin(f * ang) / sa
    r0, r1, r2 = w0 * p0 + w1 * q0, w0 * p1 + w1 * q1, w0 * p2 + w1 * q2
    ln = math.sqrt(r0 * r0 + r1 * r1 + r2 * r2)
    return r0 / ln, r1 / ln, r2 / ln


@njit(cache=True, nogil=True)
def _clamp1(a0, a1, a2, n0, n1, n2, f0, f1, f2, v1, v2):
    """One axis turned into the cone ``[v1, v2]`` (radians) about the normal, in their plane (towards
    the fallback ``f`` where the axis lies along the normal)."""
    c = a0 * n0 + a1 * n1 + a2 * n2
    p0, p1, p2 = a0 - c * n0, a1 - c * n1, a2 - c * n2
    s = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
    ang = math.atan2(s, c)
    if v1 <= ang <= v2:
        return a0, a1, a2
    if s < 1e-12:
        cf = f0 * n0 + f1 * n1 + f2 * n2
        p0, p1, p2 = f0 - cf * n0, f1 - cf * n1, f2 - cf * n2
        s = math.sqrt(p0 * p0 + p1 * p1 + p2 * p2)
        if s < 1e-12:
            return a0, a1, a2
    w = v1 if ang < v1 else v2
    cw, sw = math.cos(w), math.sin(w) / s
    return cw * n0 + sw * p0, cw * n1 + sw * p1, cw * n2 + sw * p2


@njit(cache=True, nogil=True)
def _sweeps(want, step_rad, linked, nrm, fb, v1, v2, iters, out):
    """Rate-limited sweeps with the cone applied at every step (module docstring, step 7):
    forward then backward, ``iters`` times (alternating the rate and the cone until both hold where
    they can). ``step_rad[i]``: the largest turn from point i-1 to i; ``linked[i]``: i continues the
    run of i-1; ``nrm``/``fb``: each point's normal and fallback direction; ``v1``/``v2``: the cone,
    radians."""
    n = want.shape[0]
    for i in range(n):
        out[i, 0], out[i, 1], out[i, 2] = want[i, 0], want[i, 1], want[i, 2]
    for _ in range(iters):
        for i in range(1, n):
            if linked[i]:
                a0, a1, a2 = _toward(out[i - 1, 0], out[i - 1, 1], out[i - 1, 2], out[i, 0], out[i, 1], out[i, 2],
                                     step_rad[i])
                out[i, 0], out[i, 1], out[i, 2] = _clamp1(a0, a1, a2, nrm[i, 0], nrm[i, 1], nrm[i, 2],
                                                          fb[i, 0], fb[i, 1], fb[i, 2], v1, v2)
        for i in range(n - 2, -1, -1):
            if linked[i + 1]:
                a0, a1, a2 = _toward(out[i + 1, 0], out[i + 1, 1], out[i + 1, 2], out[i, 0], out[i, 1], out[i, 2],
                                     step_rad[i + 1])
                out[i, 0], out[i, 1], out[i, 2] = _clamp1(a0, a1, a2, nrm[i, 0], nrm[i, 1], nrm[i, 2],
                                                          fb[i, 0], fb[i, 1], fb[i, 2], v1, v2)


def limit_axis_rate(axes: np.ndarray, centres: np.ndarray, linked: np.ndarray, max_rate_deg_per_mm: float,
                    min_step_deg: float = 0.0, *, normals: np.ndarray | None = None, cone_deg=(0.0, 180.0),
                    fallback: np.ndarray | None = None, iterations: int = 1) -> np.ndarray:
    """(n,3) the unit ``axes`` smoothed so that between linked neighbours (``linked[i]``: point i
    continues the run of point i-1) the axis turns at most ``max_rate_deg_per_mm`` times the centre
    distance (plus ``min_step_deg``), by the sweeps of step 7. With ``normals`` every step is also
    turned into ``cone_deg`` about the point's normal (towards ``fallback`` where the axis lies along
    it), and the sweeps run ``iterations`` times; without, one forward and one backward sweep meet
    the limit exactly."""
    a = np.ascontiguousarray(axes, dtype=np.float64)
    c = np.asarray(centres, dtype=np.float64)
    lk = np.asarray(linked, dtype=np.bool_).copy()
    if a.shape[0]:
        lk[0] = False
    d = np.zeros(a.shape[0])
    d[1:] = np.linalg.norm(c[1:] - c[:-1], axis=1)
    step = np.radians(float(max_rate_deg_per_mm) * d + float(min_step_deg))
    nrm = np.tile([0.0, 0.0, 1.0], (a.shape[0], 1)) if normals is None else np.ascontiguousarray(normals, np.float64)
    fb = np.ascontiguousarray(nrm if fallback is None else fallback, dtype=np.float64)
    v1, v2 = (math.radians(float(v)) for v in cone_deg)
    if normals is None:
        v1, v2, iterations = 0.0, math.pi, 1
    out = np.empty_like(a)
    _sweeps(a, step, lk, nrm, fb, v1, v2, max(int(iterations), 1), out)
    return out


def ring_candidates(normals: np.ndarray, cone_deg, *, n_rings: int = 4, n_azimuths: int = 16) -> np.ndarray:
    """(n, K, 3) axes on rings about each normal inside ``cone_deg`` (K = n_rings x n_azimuths): the
    rings at angles spread over ``(v1, v2)`` (both ends 0.5 degree inside), the azimuths evenly."""
    nrm = np.asarray(normals, dtype=np.float64)
    v1, v2 = (float(v) for v in cone_deg)
    lo, hi = v1 + min(0.5, 0.25 * (v2 - v1)), v2 - min(0.5, 0.25 * (v2 - v1))
    rings = np.radians(np.linspace(lo, hi, n_rings))
    az = np.linspace(0.0, 2 * math.pi, n_azimuths, endpoint=False)
    u = _perp(nrm, np.broadcast_to([[1.0, 0.0, 0.0]], nrm.shape).copy(), np.broadcast_to([[0.0, 1.0, 0.0]],
                                                                                         nrm.shape).copy())
    w = np.cross(nrm, u)
    ring = np.repeat(rings, n_azimuths)
    phi = np.tile(az, n_rings)
    dirs = np.cos(phi)[None, :, None] * u[:, None, :] + np.sin(phi)[None, :, None] * w[:, None, :]
    return np.cos(ring)[None, :, None] * nrm[:, None, :] + np.sin(ring)[None, :, None] * dirs


@dataclass
class AxisPlan:
    """The axes of one path (:func:`plan_axes`).

    ``axes`` (n,3): the tool axis at every position (unit; meaningful where not ``blocked``);
    ``normals`` (n,3) the contact normals; ``ideal`` (n,3) the lead/tilt axes before the cone,
    the admissibility search and the smoothing; ``blocked`` (n,) bool: no admissible axis (the
    position must not be cut); ``breaks`` (n,) bool: the turn from position i-1 to i still exceeds
    the rate limit (the caller ends the pass before i); ``moved_deg`` (n,) the angle between the
    final and the ideal axis; ``n_alternatives``: positions whose ideal axis failed ``ok`` and that
    took another; ``rounds``: smoothing rounds run."""

    axes: np.ndarray
    normals: np.ndarray
    ideal: np.ndarray
    blocked: np.ndarray
    breaks: np.ndarray
    moved_deg: np.ndarray
    n_alternatives: int = 0
    rounds: int = 0


def _search(centres, normals, want, cone_deg, ok, idx, n_rings, n_azimuths, memo: dict | None = None):
    """For positions ``idx`` whose wanted axis fails ``ok``: the ring candidate nearest to the wanted
    axis that passes, and whether one was found. ``memo``: answers kept by (centre, wanted axis,
    normal), to the bit, for the same ``ok``, cone and rings (:func:`plan_axes`' callers plan the same
    positions again after cutting out a few: only the new ones are searched)."""
    best = want[idx].copy()
    found = np.zeros(idx.size, dtype=bool)
    todo_pos = np.arange(idx.size)
    keys = None
    if memo is not None and idx.size:
        rows = np.ascontiguousarray(np.hstack([centres[idx], want[idx], normals[idx]]), dtype=np.float64)
        keys = rows.view(np.dtype((np.void, rows.shape[1] * 8))).ravel().tolist()
        got = [memo.get(k) for k in keys]
        known = np.array([g is not None for g in got], dtype=bool)
        for i in np.flatnonzero(known).tolist():
            best[i], found[i] = got[i]
        todo_pos = np.flatnonzero(~known)
    if todo_pos.size:
        sub = idx[todo_pos]
        cand = ring_candidates(normals[sub], cone_deg, n_rings=n_rings, n_azimuths=n_azimuths)
        order = np.argsort(-np.einsum("ikj,ij->ik", cand, want[sub]), axis=1, kind="stable")
        done = np.zeros(sub.size, dtype=bool)
        for r in range(order.shape[1]):
            todo = np.flatnonzero(~done)
            if todo.size == 0:
                break
            trial = cand[todo, order[todo, r]]
            good = ok(centres[sub[todo]], trial)
            hit = todo[good]
            best[todo_pos[hit]] = trial[good]
            done[hit] = True
        found[todo_pos] = done
        if keys is not None:
            for i in todo_pos.tolist():
                memo[keys[i]] = (best[i].copy(), bool(found[i]))
    return best, found


def plan_axes(centres: np.ndarray, pass_index: np.ndarray, normals: np.ndarray, *, lead_deg: float,
              tilt_deg: float, cone_deg, max_rate_deg_per_mm: float, frame: str = "frenet",
              ok: Callable[[np.ndarray, np.ndarray], np.ndarray] | None = None, rounds: int = 3,
              n_rings: int = 4, n_azimuths: int = 16, rate_slack_deg: float = 0.0, sweeps: int = 6,
              memo: dict | None = None) -> AxisPlan:
    """Tool axes for the cutting positions ``centres`` (n,3, mm) of one path (module docstring).

    ``pass_index`` (n,): the pass of every position (-1: not on a pass, e.g. a link or a lead);
    positions on one pass in a row are smoothed together. ``normals`` (n,3): unit contact normals
    (:func:`contact_normals`). ``lead_deg``, ``tilt_deg``: eq. 12 angles; ``cone_deg``: ``(v1,
    v2)`` degrees; ``max_rate_deg_per_mm``: the largest axis turn per mm of centre path; ``frame``:
    ``"frenet"`` or ``"surface"``. ``ok(centres, axes) -> bool``: admissibility of given pairs (None:
    every axis in the cone is admissible). ``rounds``: smoothing / admissibility rounds. ``memo``: a
    dict kept by the caller across calls with the same ``ok``, cone and rings: the ring search's
    answers by position (the same answers, searched once)."""
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    n = c.shape[0]
    nrm = _unit(np.asarray(normals, dtype=np.float64).reshape(-1, 3))
    pi = np.asarray(pass_index).reshape(-1)
    if pi.shape[0] != n or nrm.shape[0] != n:
        raise ParameterError("centres, pass_index and normals must have one row per position")
    if not max_rate_deg_per_mm > 0:
        raise ParameterError("max_rate_deg_per_mm must be > 0")
    t = feed_directions(c, pi)
    m = reference_directions(c, pi, t, nrm, frame)
    ideal = lead_tilt_axes(m, t, lead_deg=lead_deg, tilt_deg=tilt_deg)
    tilt_side = np.cross(t, m)
    want = clamp_to_cone(ideal, nrm, cone_deg, fallback=tilt_side)
    check = ok if ok is not None else (lambda cc, aa: np.ones(cc.shape[0], dtype=bool))
    blocked = np.zeros(n, dtype=bool)
    n_alt = 0
    if n:
        good = check(c, want)
        bad = np.flatnonzero(~good)
        if bad.size:
            best, found = _search(c, nrm, want, cone_deg, check, bad, n_rings, n_azimuths, memo)
            want[bad[found]] = best[found]
            blocked[bad[~found]] = True
            n_alt = int(found.sum())
    prev, _ = _runs(pi)
    axes = want.copy()
    done = 0
    for done in range(1, max(int(rounds), 1) + 1):
        linked = prev & ~blocked & np.concatenate([[False], ~blocked[:-1]]) if n else prev
        axes = limit_axis_rate(want, c, linked, max_rate_deg_per_mm, rate_slack_deg, normals=nrm,
                               cone_deg=cone_deg, fallback=tilt_side, iterations=sweeps)
        axes = clamp_to_cone(axes, nrm, cone_deg, fallback=tilt_side)
        moved = np.flatnonzero(~blocked & (turn_deg(axes, want) > 1e-9))
        if moved.size == 0:
            break
        good = check(c[moved], axes[moved])
        if good.all():
            break
        # where the smoothed axis fails: the admissible axis nearest to it becomes the wanted one
        failing = moved[~good]
        best, found = _search(c, nrm, axes, cone_deg, check, failing, n_rings, n_azimuths, memo)
        want[failing[found]] = best[found]
        axes[failing] = want[failing]
        blocked[failing[~found]] = True
    # the final checks: admissible, and the rate between linked neighbours
    if n:
        final_ok = check(c, axes) & ~blocked
        blocked |= ~final_ok & ~blocked
        linked = prev & ~blocked & np.concatenate([[False], ~blocked[:-1]])
        d = np.zeros(n)
        d[1:] = np.linalg.norm(c[1:] - c[:-1], axis=1)
        turn = np.zeros(n)
        turn[1:] = turn_deg(axes[1:], axes[:-1])
        breaks = linked & (turn > max_rate_deg_per_mm * d + 1e-6 + rate_slack_deg)
    else:
        breaks = np.zeros(0, dtype=bool)
    return AxisPlan(axes=axes, normals=nrm, ideal=ideal, blocked=blocked, breaks=breaks,
                    moved_deg=turn_deg(axes, ideal) if n else np.zeros(0), n_alternatives=n_alt, rounds=done)
