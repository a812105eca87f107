"""The placement search: which candidate pose lets the fewest set-ups reach the coverage.

Makki 2010 answers a part that no ``n_pmax`` set-ups can cover with "change the set-up of the part".
:func:`search_placement` tries the poses of :mod:`planning.placement.poses` (as scanned, the stable
hull faces, the principal axes up and down) with the plan's own stages, and keeps the one that
reaches ``setups.coverage`` with the fewest set-ups, then the least overlap, then the lowest placed
part (``part_height_mm``: a squat part is stiffer on its riser and needs less Z travel), then the
earlier candidate (the order of :func:`~planning.placement.poses.candidate_poses`): deterministic.

Normals. They are computed once, in the scanned frame (sphere throwing along the configured
directions, which are where the scanner saw the part from), and each pose turns them: ``R n``. That is
exact: a sphere-throwing normal is ``(centre - contact) / r`` of a ball resting on the cloud, and a
rigid motion carries the ball, its contact and its centre along, so the placed part's normal at the
same point is the rotated one, with no new estimate and no new error. (Throwing again in the placed
frame would sample other points, along directions that no longer match the scan.) The placed plan
runs on the same sampled points with these normals.

Evaluation of one candidate, cheapest first; each step can only rule it out:

1. ``bound``: the placed cloud through the tool cone, the translational travel and the fixtures and
   table (:func:`planning.visibility.global_visibility` with ``check_cloud=False``, the functions the
   plan's visibility stage runs, the part placed by the same ``fixtures`` rule). Those pairs are a
   superset of the plan's visible pairs, so the price bound of
   :func:`planning.setups.coverage_upper_bound` (the LP dual of max coverage with ``max_setups``
   axes) on them bounds the plan's coverage: below ``ceil(coverage * n)`` the candidate is proven
   infeasible without any collision test.
2. ``screened``: the cloud-collision test with the sampled points as the only obstacles (what
   ``visibility.obstacles = "sampled"`` does: fewer obstacles can only free pairs, so still a
   superset), then the plan's set-up stage (:func:`planning.pipeline._setups`). Infeasible there is
   infeasible in the plan; feasible gives the screening figures (k, overlap). Every sampled point
   is evaluated (no subsample: the cost of the collision test grows with the obstacles, about 10x
   less with the sampled points on the femur-like scan, and hardly with the rows).
3. ``confirmed``: the screened-feasible candidates in the order above on their screening figures,
   at most :data:`MAX_CONFIRM`, run through the plan's own visibility and set-up stages
   (:func:`planning.pipeline._visibility`, :func:`planning.pipeline._setups`: every input point an
   obstacle where ``visibility.obstacles`` is "all"). The first confirmed feasible is the winner;
   its visibility is handed to the plan, which does not compute it again. A candidate later in the
   screening order could in principle do better once confirmed (its exact overlap is unknown); the
   confirmation stops at the first success to bound the cost.

Where ``visibility.global`` is false step 1 is the plan's visibility already and the candidate is
confirmed at once. Functional zones enter every selection as the plan's (their mask is computed in
the scanned frame and belongs to the points, so it does not change with the pose); fixture items are
taken in the placed frame (they describe how the placed part is held: a riser under z = 0 stays
under it), and ``fixtures.placement_mm`` is null with ``"auto"``.

Cost (``bench/bench_placement.py``): a candidate costs about its bound step (cone, travel, fixtures:
well under a second on the femur-like scan) plus, when the bound does not rule it out, a collision
test with ~100k obstacles instead of 1M and a set-up search; one exact confirmation costs what the
plan's visibility stage costs, and the plan then reuses it.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from planning.geometry.collision import cloud_collision_free
from planning.placement.poses import Pose, apply_pose, candidate_poses, turn
from planning.progress import Throttled
from planning.setups import coverage_upper_bound
from planning.visibility import cone_visibility, global_visibility

__all__ = ["MAX_CONFIRM", "Tried", "PlacementSearch", "full_yaw", "search_placement", "search_work"]

#: At most this many screened-feasible candidates are confirmed with the plan's own stages.
MAX_CONFIRM = 3
#: The search's progress (its own lines and those of the stages it runs) is passed on at most once per
#: this many seconds (:class:`planning.progress.Throttled`; a candidate's start always).
PROGRESS_EVERY_S = 0.1

_FEASIBLE = ("optimal", "feasible")

SCREENING = ("every sampled point; step 1 bounds the coverage on the pairs left by the cone, travel, fixtures and "
             "table, step 2 adds the collision test with the sampled points as the only obstacles; both are "
             "supersets of the plan's visible pairs, so what they rule out is ruled out; the winner is confirmed "
             "with the plan's own visibility and set-up stages")


@dataclass
class Tried:
    """One candidate's evaluation: ``stage`` ``"bound"``, ``"screened"`` or ``"confirmed"``;
    ``feasible`` False (proven at that stage), True (confirmed) or None (screened feasible, not
    confirmed); ``k``, ``overlap``, ``coverage`` of the selection at that stage; ``coverage_bound``:
    proven most that ``max_setups`` set-ups cover here (fraction); ``seconds``."""

    index: int
    pose: Pose
    stage: str
    feasible: bool | None
    k: int | None = None
    overlap: int | None = None
    coverage: float | None = None
    coverage_bound: float | None = None
    seconds: float = 0.0

    def key(self) -> tuple:
        """The order of the winner: fewest set-ups, least overlap, lowest part, earliest candidate."""
        return (self.k, self.overlap, round(self.pose.part_height_mm, 6), self.index)

    def describe(self) -> str:
        """One line: the candidate and what it reaches."""
        if self.stage == "bound":
            what = f"at most {self.coverage_bound * 100:.1f} % (price bound)"
        elif self.feasible is False:
            what = f"best {self.coverage * 100:.1f} % with {self.k} set-ups"
        else:
            what = f"{self.k} set-ups cover {self.coverage * 100:.1f} %, overlap {self.overlap}"
        return f"{self.index} {self.pose.label}: {self.stage}, {what}"


@dataclass
class PlacementSearch:
    """The search's outcome: ``winner`` (a :class:`Tried`, confirmed feasible) or None; every
    candidate tried; the winner's exact ``visibility`` ``(cone, GlobalVisibility)`` and ``selection``
    (:class:`planning.setups.SetupSelection`) for the plan to reuse; ``seconds``; ``message``."""

    winner: Tried | None
    tried: list[Tried]
    n_sampled: int
    required: int
    seconds: float
    visibility: tuple | None = None
    selection: object | None = None
    message: str = ""


def full_yaw(profile) -> bool:
    """The machine's rotary (C) axis turns a full 360 degrees: every yaw of the part is presented anyway."""
    if getattr(profile, "rotary_continuous", False):
        return True
    lo, hi = getattr(profile, "rotary_min_deg", None), getattr(profile, "rotary_max_deg", None)
    return lo is not None and hi is not None and hi - lo >= 360.0 - 1e-9


def search_work(n_points: int, n_sampled: int, n_axes: int, n_candidates: int, obstacles: str) -> float:
    """Point-axis pairs the collision tests of a search rasterise (its cost, deterministically):
    ``n_candidates`` screenings with the sampled points as obstacles and one confirmation."""
    exact = n_sampled if obstacles == "sampled" else n_points
    return float(n_candidates) * n_sampled * n_axes + float(exact) * n_axes


def search_placement(points: np.ndarray, sample_index: np.ndarray, normals: np.ndarray, config, profile, tool, *,
                     zone_mask: np.ndarray | None = None, base_dir=None, poses: list[Pose] | None = None,
                     skip_identity: bool = False, max_confirm: int = MAX_CONFIRM, progress=None) -> PlacementSearch:
    """Try every candidate pose and keep the best that reaches ``config.setups.coverage`` (module docstring).

    ``points`` (N,3) mm: the scanned cloud; ``sample_index`` (n,), ``normals`` (n,3): its sampled
    points and their normals in the scanned frame; ``config``: the plan's :class:`PlanConfig`;
    ``profile``, ``tool``: the machine profile and tool assembly of the plan; ``zone_mask`` (n,) bool:
    the functional zones' mask (scanned frame) or None; ``poses``: the candidates (default
    :func:`candidate_poses` with the profile's yaw rule); ``skip_identity``: leave the as-scanned pose
    out (the plan has just evaluated it); ``progress(fraction, message)``: "candidate i of m" and, from
    inside each candidate, its fixture check, collision test and set-up search (the fraction never goes back).
    """
    from planning import pipeline as pl   # the plan's own stage functions (lazy: the pipeline imports us)

    t0 = time.perf_counter()
    # one throttle for the whole search: the fraction never goes back (the set-up search's own
    # fractions do, between its phases), and the per-axis reports of the collision tests are thinned
    say = Throttled(progress, PROGRESS_EVERY_S)
    pts = np.asarray(points, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    sidx = np.asarray(sample_index, dtype=np.int64)
    if poses is None:
        poses = candidate_poses(pts, full_yaw=full_yaw(profile))
    listed = [(i, p) for i, p in enumerate(poses) if not (skip_identity and p.kind == "as_scanned" and p.yaw_deg == 0)]
    vp, sp = config.visibility, config.setups
    zm = zone_mask if zone_mask is not None and np.any(zone_mask) else None
    n = int(sidx.size)
    required = int(math.ceil(sp.coverage * n - 1e-9))
    ori = pl._orientations(config, profile)
    m = len(listed)
    tried: list[Tried] = []
    survivors: list[Tried] = []        # screened feasible (the placed clouds are turned again to confirm)

    def setups(visible: np.ndarray, normals: np.ndarray, progress=None, along=None):
        return pl._setups(pl.selection_matrix(visible, ori.axes, normals, config, along=along),
                          zm if zm is not None else np.zeros(n, bool), config, progress)

    def within(lo: float, hi: float, what: str):
        """progress(fraction, message) of one step mapped onto [lo, hi] of the search, ``what: message``."""
        part = say.part(lo, hi)
        return lambda f, msg="": part(f, f"{what}: {msg}" if msg else what)

    for j, (i, pose) in enumerate(listed):
        # candidate j's share of the search, [lo, lo + w]: the bound (fixtures) its first tenth, the
        # screening collision test up to 0.4, its set-up search the rest
        lo, w = 0.8 * j / max(m, 1), 0.8 / max(m, 1)
        what = f"candidate {j + 1} of {m}: {pose.label}"
        say(lo, what, force=True)
        c0 = time.perf_counter()
        P = apply_pose(pts, pose)
        N = turn(nrm, pose.rotation)
        cone = cone_visibility(N, ori.axes, vp.cone_deg)
        g0 = global_visibility(P, sidx, N, ori.axes, ori.angles_deg, cone, tool=tool, profile=profile,
                               fixtures_params=config.fixtures, check_global=vp.global_, check_travel=vp.travel,
                               obstacles=vp.obstacles, base_dir=base_dir, check_cloud=False,
                               progress=within(lo, lo + 0.1 * w, what), along_swing_deg=pl._along_swing(config))
        if not vp.global_:
            sel = setups(g0.visible, N, within(lo + 0.1 * w, lo + w, f"{what}: set-ups"), along=g0.along)
            t = _from_selection(i, pose, "confirmed", sel, exact=True)
            t.seconds = time.perf_counter() - c0
            tried.append(t)
            if t.feasible:
                survivors.append(t)
            continue
        b = coverage_upper_bound(g0.visible, coverage=sp.coverage, max_setups=sp.max_setups, min_points=sp.min_points,
                                 zone_mask=zm)
        if b.proven_infeasible:
            tried.append(Tried(i, pose, "bound", False, coverage_bound=b.bound / n, seconds=time.perf_counter() - c0))
            continue
        forbidden = g0.forbidden_mm
        screen = within(lo + 0.1 * w, lo + 0.4 * w, what)
        ok = cloud_collision_free(P[sidx], np.arange(n), N, ori.axes, tool, candidates=g0.visible,
                                  obstacles=forbidden if forbidden.size else None,
                                  progress=lambda d, t, say=screen: say(d / max(t, 1), f"screening collisions, axis {d}/{t}"))
        sel = setups(g0.visible & ok, N, within(lo + 0.4 * w, lo + w, f"{what}: set-ups"), along=g0.along)
        t = _from_selection(i, pose, "screened", sel, exact=False)
        t.seconds = time.perf_counter() - c0
        tried.append(t)
        if sel.status in _FEASIBLE:
            survivors.append(t)

    winner = None
    visibility = selection = None
    order = sorted(survivors, key=Tried.key)
    n_confirm = max(min(len(order), max_confirm), 1)
    for r, t in enumerate(order[:max(0, max_confirm)]):
        # confirmation r's share, [lo, lo + w]: the plan's visibility stage its first half, set-ups the rest
        lo, w = 0.8 + 0.2 * r / n_confirm, 0.2 / n_confirm
        what = f"confirming candidate {t.index}: {t.pose.label}"
        say(lo, what, force=True)
        c0 = time.perf_counter()
        P, N = apply_pose(pts, t.pose), turn(nrm, t.pose.rotation)
        cone, gv = pl._visibility(P, pl._Normals(sidx, N, None), ori, config, tool, profile, base_dir,
                                  within(lo, lo + 0.5 * w, what))
        sel = setups(gv.visible, N, within(lo + 0.5 * w, lo + w, f"{what}: set-ups"), along=gv.along)
        c = _from_selection(t.index, t.pose, "confirmed", sel, exact=True)
        c.seconds = t.seconds + time.perf_counter() - c0
        tried[[x.index for x in tried].index(t.index)] = c
        if c.feasible:
            winner, visibility, selection = c, (cone, gv), sel
            break
    say(1.0, "placement chosen" if winner else "no placement reaches the coverage", force=True)
    res = PlacementSearch(winner=winner, tried=tried, n_sampled=n, required=required,
                          seconds=time.perf_counter() - t0, visibility=visibility, selection=selection)
    res.message = _message(res, sp.coverage, sp.max_setups, len(order), max_confirm)
    return res


def _from_selection(i: int, pose: Pose, stage: str, sel, *, exact: bool) -> Tried:
    """A :class:`Tried` from a set-up selection: infeasible is proven either way (a superset cannot
    cover less); feasible is True only when ``exact``."""
    if sel.status in _FEASIBLE:
        return Tried(i, pose, stage, True if exact else None, k=int(sel.k), overlap=int(sel.overlap),
                     coverage=float(sel.coverage))
    if sel.status == "infeasible":
        return Tried(i, pose, stage, False, k=int(sel.k), overlap=int(sel.overlap), coverage=float(sel.coverage),
                     coverage_bound=float(sel.coverage))
    # "unknown": the set-up search's time limit came first: neither proven nor found (not confirmed)
    return Tried(i, pose, stage, None, k=int(sel.k), overlap=int(sel.overlap), coverage=float(sel.coverage))


def _message(res: PlacementSearch, coverage: float, max_setups: int, n_screened_ok: int, max_confirm: int) -> str:
    target = f"{coverage * 100:g} %"
    setups = f"{max_setups} set-up{'s' if max_setups != 1 else ''}"
    if res.winner is not None:
        w = res.winner
        return (f"placed {w.pose.describe()}: {w.k} set-up{'s' if w.k != 1 else ''} cover {w.coverage * 100:.1f} % "
                f"(candidate {w.index}, {len(res.tried)} tried)")
    best = max((t.coverage_bound if t.coverage_bound is not None else (t.coverage or 0.0) for t in res.tried),
               default=0.0)
    if n_screened_ok > max_confirm:
        return (f"no placement confirmed within {max_confirm} tries: none of the {len(res.tried)} candidates was "
                f"proven to reach {target} with {setups}")
    return (f"no tested placement reaches {target} with {setups} ({len(res.tried)} candidates; "
            f"the most any can cover is {best * 100:.1f} %)")
