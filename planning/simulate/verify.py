"""Stage 9, verification (issue 15): the posted programs run on a simulated machine and stock.

1. the stock (``stock.*``: a box or a cylinder around the part, in the part frame) and the solids
   that may never be cut (the fixtures, the riser under the stock, the table top) as tri-dexel
   models at ``simulate.resolution_mm`` (:mod:`planning.simulate.dexel`, :mod:`planning.simulate.stock`);
2. each area's program in the chosen dialect read back from its TEXT as a control would
   (:func:`planning.simulate.program.read_program`), in the plan's set-up order, the stock carried
   from one set-up to the next;
3. every move, in program order: a rapid whose tool meets the stock (more than
   ``simulate.rapid_clearance_mm``) is a rapid into material; a feed move cuts what its cutting
   part sweeps, and its shank or holder meeting the stock is a holder collision; any part of the
   tool meeting a fixture, the riser or the table is a fixture collision; the machine's axes at
   the end of every move are checked against the profile's travel
   (:func:`planning.simulate.program.check_travel`; a continuous C against its register), and every
   feed line's rotary turns against the profile's rotary feed limits at the line's F word
   (:func:`planning.simulate.rotary_speed.rotary_feed_excesses`);
4. the signed deviation of every scan point from the final surface (positive: material left); a
   point read as cut below the surface is measured again exactly against the tools of the moves
   that ran (:mod:`planning.simulate.gouge`), and only a confirmed cut counts as a gouge; and the
   finish measured exactly from the finishing moves (:mod:`planning.simulate.finish`,
   ``simulate.exact_finish``): each point's distance to the surface the ball swept;
5. the verdict: ``passed`` only when there are no collisions, no rapids into material, no travel
   excursions, no feed move turning a rotary axis too fast and no gouge beyond the tolerance.

What it does not prove (docs/programs.md): dynamics (acceleration, the control's look-ahead, feed
overrides), a mis-set work offset or tool length, the fixture model matching the real set-up, and
anything finer than the resolution (a wall thinner than one ray spacing can vanish between rays).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from planning.errors import PlanningError
from planning.geometry.tool import ToolAssembly
from planning.simulate.motion import FEED, RAPID, ProgramMotion
from planning.simulate.tools import finishing_shape, roughing_shape
from schemas.plan import (
    AreaVerification,
    DeviationFigures,
    FinishFigures,
    OperationFigures,
    Verification,
    VerificationOffence,
)

Progress = Callable[[float, str], None]

#: Offences of each class listed in ``verification.worst``.
WORST_PER_CLASS = 5
#: The share of the verification's progress that reading the programs back (and proving them) takes.
READ_SHARE = 0.1

#: Scan points whose deviation is read in one call (the calls report progress between them).
DEVIATION_CHUNK = 500_000


@dataclass
class SimulationOutcome:
    """``verification``: the plan.json block; ``deviation_mm`` (N,) per input point (NaN where not
    measured); ``stock``: the final stock model (for the mesh artifact); ``again``: ``again(mode)``
    runs the verification once more in another ``simulate.mode`` (set by the pipeline);
    ``finish_left_mm`` (N,): the exact material left (:mod:`planning.simulate.finish`; NaN where not
    measured, +inf where no finishing move reaches), None when it was not measured."""

    verification: Verification
    deviation_mm: np.ndarray | None = None
    stock: object = None
    again: object = None
    finish_left_mm: np.ndarray | None = None


def skipped(message: str) -> SimulationOutcome:
    """The verification block of a plan that was not simulated."""
    return SimulationOutcome(Verification(status="skipped", message=message))


def choose_dialect(programs: dict[str, str], wanted: str) -> str | None:
    """``simulate.dialect``: ``auto`` = linuxcnc when posted, else iso; None when nothing is posted."""
    posted = {name.split(".")[1] for name in programs if name.endswith(".nc")}
    if wanted != "auto":
        return wanted if wanted in posted else None
    for d in ("linuxcnc", "iso"):
        if d in posted:
            return d
    return None


def stock_extent(points: np.ndarray, stock, blank=None) -> tuple[np.ndarray, np.ndarray]:
    """The stock's bounding box (lo, hi) in the part frame, mm (``stock``: :class:`StockParams`;
    ``blank``: the mesh of a 'mesh' stock)."""
    if blank is not None:
        v = np.asarray(blank.vertices, float)
        return v.min(axis=0), v.max(axis=0)
    if stock.min_mm is not None:
        return np.asarray(stock.min_mm, float), np.asarray(stock.max_mm, float)
    lo, hi = points.min(axis=0), points.max(axis=0)
    return lo - stock.margin_mm, hi + stock.margin_mm


def tool_shapes(config, tool: ToolAssembly) -> dict:
    """The plan's tools as the simulation sees them, by T number (:mod:`planning.simulate.tools`)."""
    post = config.post
    out = {post.finishing_tool_number: finishing_shape(tool, post.finishing_tool_number, config.tool.flute_length_mm),
           post.roughing_tool_number: roughing_shape(tool, post.roughing_tool_number, config.paths.roughing,
                                                     config.tool.stickout_mm)}
    if config.paths.semi_finishing.enabled:
        from planning.toolpath.semi_finishing import semi_flute_mm, semi_tool

        n = post.semi_finishing_tool_number
        out[n] = finishing_shape(semi_tool(config), n, semi_flute_mm(config))
    return out


def move_minutes(motion: ProgramMotion, config) -> np.ndarray:
    """(P,) minutes each move of ``motion`` takes as the control runs it, without acceleration: a rapid at
    ``post.rapid_mm_min``; a feed move at the F word in force on its program line (mm/min), or under G93
    (inverse time) the line's 1/F minutes shared among the chords the reader split it into, by length.
    Where the reader gave no F (``line_feed`` None or NaN) a feed move runs at its tool's nominal feed
    (``post.feed_mm_min``, ``post.roughing_feed_mm_min`` for the roughing tool)."""
    length = np.linalg.norm(motion.end_mm - motion.start_mm, axis=1)
    out = np.zeros(length.shape[0])
    if not length.size:
        return out
    rapid = motion.kind == RAPID
    out[rapid] = length[rapid] / config.post.rapid_mm_min
    feed = ~rapid
    nominal = np.where(motion.tool == config.post.roughing_tool_number, config.post.roughing_feed_mm_min,
                       config.post.feed_mm_min).astype(np.float64)
    if config.paths.semi_finishing.enabled:
        nominal[motion.tool == config.post.semi_finishing_tool_number] = config.post.semi_finishing_feed_mm_min
    if motion.line_feed is None:
        out[feed] = length[feed] / np.maximum(nominal[feed], 1e-9)
        return out
    row = np.clip(motion.line - 1, 0, motion.line_feed.shape[0] - 1)
    f = motion.line_feed[row]
    inverse = np.zeros(length.shape[0], dtype=bool) if motion.line_inverse_time is None else \
        motion.line_inverse_time[row]
    known = feed & np.isfinite(f) & (f > 0)
    per_mm = feed & known & ~inverse
    out[per_mm] = length[per_mm] / f[per_mm]
    inv = feed & known & inverse
    if inv.any():                            # one program line's time, shared among its chords
        line_len = np.bincount(row[inv], weights=length[inv], minlength=motion.line_feed.shape[0])
        share = np.where(line_len[row[inv]] > 0, length[inv] / np.maximum(line_len[row[inv]], 1e-300), 0.0)
        first = np.zeros(inv.sum(), dtype=bool)        # a zero-length line still takes its 1/F once
        _, at = np.unique(row[inv], return_index=True)
        first[at] = True
        share = np.where(line_len[row[inv]] > 0, share, first.astype(np.float64))
        out[inv] = share / f[inv]
    rest = feed & ~known
    out[rest] = length[rest] / np.maximum(nominal[rest], 1e-9)
    return out


#: The chord tolerance the program reader splits arcs with (mm): a gouge is confirmed only deeper
#: than the finishing tolerance plus this and the programs' last decimal.
READER_CHORD_TOL_MM = 0.005

def gouge_allowance_mm(config) -> float:
    """How deep (mm) the exact measures may find a tool below a scan point before it counts: the
    finishing tolerance, the reader's chords (:data:`READER_CHORD_TOL_MM`) and the programs' last decimal."""
    return config.paths.finishing.tolerance_mm + READER_CHORD_TOL_MM + 10.0 ** -config.post.decimals


#: A feed move within this angle of straight down the tool axis is a plunge (degrees).
PLUNGE_DEG = 10.0


def _plunges(motion: ProgramMotion, removed_mm3: np.ndarray, roughing_tool: int) -> int:
    """Feed moves of the roughing end mill within :data:`PLUNGE_DEG` of straight down its axis
    that removed material."""
    d = motion.end_mm - motion.start_mm
    length = np.linalg.norm(d, axis=1)
    down = -np.einsum("ij,ij->i", d, motion.axis)
    steep = down > length * math.cos(math.radians(PLUNGE_DEG))
    return int((steep & (motion.kind == FEED) & (motion.tool == roughing_tool) & (removed_mm3 > 1e-6)).sum())


#: A feed move that removed less than this from the stock model cut nothing: it fed through air (mm^3).
AIR_MM3 = 1e-6


def engagement_figures(motion: ProgramMotion, engagement, bound_deg: float) -> dict:
    """The roughing figures of :class:`~schemas.plan.OperationFigures` from the per-move engagement
    (:class:`planning.simulate.engagement.Engagement`; None: not measured): the largest, the 95th
    percentile weighted by length, and the moves over ``bound_deg`` with their length (mm)."""
    if engagement is None or not engagement.level.any():
        return {}
    lv = engagement.level
    deg = engagement.deg[lv]
    length = np.linalg.norm(motion.end_mm[lv] - motion.start_mm[lv], axis=1)
    order = np.argsort(deg)
    cum = np.cumsum(length[order])
    p95 = float(deg[order][min(order.size - 1, int(np.searchsorted(cum, 0.95 * cum[-1])))])
    over = deg > bound_deg
    return dict(engagement_max_deg=round(float(deg.max()), 1), engagement_p95_deg=round(p95, 1),
                over_engagement_moves=int(over.sum()), over_engagement_mm=round(float(length[over].sum()), 1))


def operation_figures(motion: ProgramMotion, removed_mm3: np.ndarray, config, engagement=None) -> list[OperationFigures]:
    """Per tool of ``motion`` (roughing first, then by T number): feed length, the part of it that removed no
    material (``removed_mm3`` per move below :data:`AIR_MM3`), rapid length, removed volume, machining time
    (as :func:`move_minutes`: as the control runs them), straight plunges into material and, for the roughing
    end mill, its engagement (``engagement``: :class:`planning.simulate.engagement.Engagement` of its moves,
    :func:`engagement_figures`). Lengths mm, volumes mm^3, times s."""
    out = []
    if motion.n_moves == 0:
        return out
    length = np.linalg.norm(motion.end_mm - motion.start_mm, axis=1)
    minutes = move_minutes(motion, config)
    feed = motion.kind != RAPID
    rough = int(config.post.roughing_tool_number)
    semi = int(config.post.semi_finishing_tool_number) if config.paths.semi_finishing.enabled else None
    # in the order they run: roughing, semi-finishing, then the others by T number
    tools = sorted({int(t) for t in np.unique(motion.tool)}, key=lambda t: (t != rough, t != semi, t))
    for t in tools:
        mine = motion.tool == t
        f = mine & feed
        feed_mm = float(length[f].sum())
        air_mm = float(length[f & (removed_mm3 < AIR_MM3)].sum())
        rapid_mm = float(length[mine & ~feed].sum())
        if feed_mm == 0.0 and rapid_mm == 0.0:     # T0 before the first tool change: nothing moves
            continue
        time_s = 60.0 * float(minutes[mine].sum())
        out.append(OperationFigures(
            tool=t, operation="roughing" if t == rough else ("semi_finishing" if t == semi else "finishing"),
            feed_mm=round(feed_mm, 1),
            air_feed_mm=round(air_mm, 1), air_share=round(air_mm / feed_mm, 4) if feed_mm > 0 else 0.0,
            rapid_mm=round(rapid_mm, 1), removed_mm3=round(float(removed_mm3[mine].sum()), 1),
            machining_time_s=round(time_s, 1),
            plunges_into_material=_plunges(motion, removed_mm3, rough) if t == rough else 0,
            **(engagement_figures(motion, engagement, config.paths.roughing.max_engagement_deg) if t == rough else {})))
    return out


def measure_engagement(motion: ProgramMotion, stock, tools: dict, config):
    """The roughing end mill's engagement on the moves of ``motion`` (:mod:`planning.simulate.engagement`), on
    ``stock`` as it was before them; None when ``simulate.engagement`` is off or the program has no roughing."""
    rough = int(config.post.roughing_tool_number)
    if not config.simulate.engagement or stock is None or rough not in tools or not np.any(motion.tool == rough):
        return None
    from planning.simulate.engagement import measure

    return measure(stock, motion.start_mm, motion.end_mm, motion.axis, motion.kind, motion.tool, tools[rough])


def _offences(kind: str, motion: ProgramMotion, amount: np.ndarray, detail: str) -> list[VerificationOffence]:
    idx = np.flatnonzero(amount > 0)
    worst = idx[np.argsort(-amount[idx], kind="stable")][:WORST_PER_CLASS]
    return [VerificationOffence(kind=kind, program=motion.program, line=int(motion.line[i]),
                                position_mm=tuple(round(float(c), 4) for c in motion.end_mm[i]),
                                amount=round(float(amount[i]), 4), detail=detail) for i in worst]


def deviation_figures(dev: np.ndarray, limit_mm: float, gouge_mm: float,
                      dev_high: np.ndarray | None = None, exact_depth: np.ndarray | None = None,
                      exact_limit_mm: float = 0.0) -> DeviationFigures:
    """Figures of the signed deviations ``dev`` (mm; NaN = not measured): within ``limit_mm`` on
    both sides counts as finished; a cut deeper than ``gouge_mm`` is a gouge, judged on
    ``dev_high`` (the highest reading around each point, default ``dev``). With ``exact_depth``
    (per point, mm: how deep it lies inside a tool that ran, :func:`planning.simulate.gouge.penetration_mm`;
    NaN where not measured) a point read as gouged counts only when its exact depth exceeds
    ``exact_limit_mm`` (``n_suspected`` counts the readings), and the deepest cut is the exact one."""
    high = dev if dev_high is None else dev_high
    ok = np.isfinite(dev) & np.isfinite(high)
    d, h = dev[ok], high[ok]
    if d.size == 0:
        return DeviationFigures(n_points=0, finished_share=0.0, left_p50_mm=0.0, left_p95_mm=0.0, left_max_mm=0.0,
                                gouge_max_mm=0.0, n_gouged=0)
    left = np.maximum(d, 0.0)
    suspected = h < -gouge_mm
    ex = np.full(d.shape, np.nan) if exact_depth is None else np.asarray(exact_depth, dtype=np.float64)[ok]
    gouged = suspected if exact_depth is None else suspected & (ex > exact_limit_mm)
    # the depth of each point's cut as the pictures show it (:func:`reported_deviation`), so the whole
    # scan's deepest cut is the deepest of its areas'
    deepest = float(max(0.0, -reported_deviation(d, h, ex).min()))
    return DeviationFigures(
        n_points=int(d.size), finished_share=round(float((np.abs(d) <= limit_mm).mean()), 6),
        left_p50_mm=round(float(np.percentile(left, 50)), 4), left_p95_mm=round(float(np.percentile(left, 95)), 4),
        left_max_mm=round(float(left.max()), 4), gouge_max_mm=round(deepest, 4),
        n_gouged=int(gouged.sum()), n_suspected=int(suspected.sum()))


#: The seed of the points the exact finish is measured on, when there are more than ``exact_finish_points``.
FINISH_SEED = 20261129


def finish_sample(n: int, most: int) -> np.ndarray:
    """The indices (sorted) of the scan points the exact finish is measured on: all ``n``, or ``most``
    of them drawn at random without replacement (seed :data:`FINISH_SEED`; ``most`` 0: all)."""
    if most <= 0 or n <= most:
        return np.arange(n)
    return np.sort(np.random.default_rng(FINISH_SEED).choice(n, size=most, replace=False))


def finish_figures(left: np.ndarray, scallop_mm: float, tolerance_mm: float, below_mm: float | None = None) -> FinishFigures:
    """Figures of the exact material left ``left`` (mm per point, :func:`planning.simulate.finish.finish_left_mm`;
    ``+inf`` where no finishing move reaches the point): finished within ``scallop_mm + tolerance_mm``
    above and ``below_mm`` below (default ``tolerance_mm``; the verification allows what it allows an
    exact gouge depth: the tolerance, the reader's chords and the programs' last decimal)."""
    left = np.asarray(left, dtype=np.float64)
    limit = float(scallop_mm) + float(tolerance_mm)
    below = float(tolerance_mm if below_mm is None else below_mm)
    n = int(left.size)
    reached = left[np.isfinite(left)]
    if n == 0 or reached.size == 0:
        return FinishFigures(n_points=n, limit_mm=round(limit, 6), finished_share=0.0, reached_share=0.0,
                             left_p50_mm=0.0, left_p95_mm=0.0, left_max_mm=0.0, scallop_p95_mm=0.0,
                             below_max_mm=0.0, n_below_tolerance=0)
    up = np.maximum(reached, 0.0)
    done = (reached <= limit) & (reached >= -below)
    return FinishFigures(
        n_points=n, limit_mm=round(limit, 6), finished_share=round(float(done.sum()) / n, 6),
        reached_share=round(reached.size / n, 6),
        left_p50_mm=round(float(np.percentile(up, 50)), 4), left_p95_mm=round(float(np.percentile(up, 95)), 4),
        left_max_mm=round(float(up.max()), 4),
        scallop_p95_mm=round(float(np.percentile(up[done], 95)), 4) if done.any() else 0.0,
        below_max_mm=round(float(max(0.0, -reached.min())), 4),
        n_below_tolerance=int((reached < -below).sum()))


def reported_deviation(dev: np.ndarray, dev_high: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """(N,) the deviation the plan reports and shows (mm, + material left, - cut below the scan), one
    reading per point for the figures, the PLY, the PNG and the viewer alike: material left as read
    (``dev``, interpolated); a cut only as far as the highest of the four rays reads it (``dev_high``: a
    cut must show on all four; the interpolation dips between a sparse cloud's points); and where the
    points read as cut were measured exactly (``exact``, depth inside a tool of a move that ran; NaN
    where not measured), that depth: 0 when the point lies in no tool (the reading was an artefact)."""
    out = np.asarray(dev, dtype=np.float64).copy()
    neg = out < 0
    out[neg] = np.minimum(np.maximum(out[neg], dev_high[neg]), 0.0)
    m = np.isfinite(exact)
    out[m] = np.where(exact[m] > 0, -exact[m], np.maximum(out[m], 0.0))
    return out


def _message(v: Verification) -> str:
    lines = []
    if v.unreadable_programs:
        lines.append(f"{v.unreadable_programs} programs could not be read (verification notes)")
    if v.travel_excursions:
        lines.append(f"{v.travel_excursions} moves beyond the machine's travel")
    if v.rotary_feed_excesses:
        lines.append(f"{v.rotary_feed_excesses} feed moves that turn a rotary axis faster than the machine's limit")
    if v.rapids_into_material:
        lines.append(f"{v.rapids_into_material} rapids into material")
    if v.holder_collisions:
        lines.append(f"{v.holder_collisions} moves where the shank or holder meets material")
    if v.fixture_collisions:
        lines.append(f"{v.fixture_collisions} moves where the tool meets a fixture, the riser or the table")
    if v.deviation is not None and v.deviation.n_gouged:
        lines.append(f"{v.deviation.n_gouged} scan points cut below the surface (deepest "
                     f"{v.deviation.gouge_max_mm:.3f} mm)")
    if not lines:
        share = f"; {v.deviation.finished_share:.1%} of the scan finished within tolerance" if v.deviation else ""
        if v.finish is not None:
            share += (f" ({v.finish.finished_share:.1%} within {v.finish.limit_mm:g} mm of the finishing ball's "
                      f"surface, measured exactly)")
        lines.append(f"the programs ran clean on the simulated machine and stock{share}")
    if v.plunges_into_material:
        lines.append(f"(also {v.plunges_into_material} straight plunges of the roughing end mill into material)")
    return "; ".join(lines)


def verification_status(v: Verification) -> str:
    """``passed`` when every offence count is zero, else ``failed``."""
    bad = v.travel_excursions + v.rapids_into_material + v.holder_collisions + v.fixture_collisions
    bad += v.unreadable_programs + v.rotary_feed_excesses
    bad += v.deviation.n_gouged if v.deviation is not None else 0
    return "passed" if bad == 0 else "failed"


def verify_plan(*, programs: dict[str, str], order, config, profile, placement_mm, tool: ToolAssembly,
                fixtures: Sequence, points: np.ndarray, normals: np.ndarray, input_labels: np.ndarray,
                blank=None, progress: Progress | None = None, simulated: dict | None = None,
                stock_after=None) -> SimulationOutcome:
    """Run every area's program of ``programs`` on the simulated machine and stock (module docstring).

    ``order``: the areas in their machining order (``plan.json machining_order``; an int ``k``
    means 0..k-1); ``profile`` the machine profile; ``placement_mm`` the
    part-frame origin on the table; ``tool`` the finishing assembly; ``fixtures`` the fixture solids
    and the table (part frame); ``points`` (N,3) the scan with unit ``normals`` (N,3) and
    ``input_labels`` (N,); ``blank`` the mesh of a 'mesh' stock
    (:func:`planning.simulate.models.load_blank`). Lengths in mm.

    ``simulated``: per area, the operations' moves as the paths stage ran them on the carried stock
    (:class:`~planning.simulate.motion.SimulatedMoves`, in program order), and ``stock_after`` the
    carried stock they left: with ``simulate.mode = "single_pass"`` the programs proven to run those
    moves are not run again (:mod:`planning.simulate.single_pass`); when one is not, or without
    them, every program runs here (``verification.mode`` says which was done, and why)."""
    from planning.simulate import models as stock_models
    from planning.simulate.program import check_travel, read_program
    from planning.simulate.rotary_speed import rotary_feed_excesses
    from planning.simulate.run import deviation_pair, run_moves

    t0 = time.perf_counter()
    sim = config.simulate
    dialect = choose_dialect(programs, sim.dialect)
    if dialect is None:
        return skipped(f"no program in the dialect {sim.dialect!r} was posted")
    tools = tool_shapes(config, tool)
    lo, hi = stock_extent(points, config.stock, blank)
    models = stock_models.build_models(lo, hi, config, fixtures, tools, resolution_mm=sim.resolution_mm, blank=blank)
    v = Verification(status="passed", message="", dialect=dialect, resolution_mm=sim.resolution_mm,
                     stock_box_mm=(tuple(map(float, lo)), tuple(map(float, hi))),
                     stock_volume_mm3=round(float(models.stock.volume_mm3()), 1),
                     measuring_bound_mm=float(models.measuring_bound_mm), notes=list(models.notes))
    worst: list[VerificationOffence] = []
    motions = []
    order = list(range(order)) if isinstance(order, (int, np.integer)) else [int(i) for i in order]
    names = [f"area_{i}.{dialect}.nc" for i in order if f"area_{i}.{dialect}.nc" in programs]
    n_steps = len(names) + 1                  # every program, then the deviation of the scan

    def say(n_done: int, fraction: float, message: str) -> None:
        # the reading takes the first tenth, then every program and the deviation a share each
        if progress is not None:
            progress(READ_SHARE + (1.0 - READ_SHARE) * (n_done + max(0.0, min(1.0, fraction))) / n_steps, message)

    read = []                                 # (n_done, name, area, motion)
    for n_done, name in enumerate(names):
        area = int(name.split("_")[1].split(".")[0])
        if progress is not None:
            progress(0.5 * READ_SHARE * n_done / len(names), f"{name}: reading ({n_done + 1}/{len(names)})")
        try:
            motion = read_program(programs[name], dialect=dialect, program=name, area=area, profile=profile,
                                  placement_mm=placement_mm, tools=tools)
        except PlanningError as exc:          # a program a control would refuse: not run, and not passed
            v.unreadable_programs += 1
            v.notes.append(f"{name} could not be read: {exc}")
            continue
        v.notes += [n for n in motion.notes if n not in v.notes]
        motions.append(motion)
        read.append((n_done, name, area, motion))
    runs, stock = None, models.stock
    v.mode, v.mode_note = "independent", "simulate.mode is 'independent'"
    if sim.mode == "single_pass":
        runs, v.mode_note = _single_pass(read, simulated, stock_after, models, tools, config,
                                         None if progress is None else
                                         (lambda k, m: progress(READ_SHARE * (0.5 + 0.5 * k / len(read)), m)))
        if runs is not None:
            v.mode, stock = "single_pass", stock_after
    engagement_of = {}
    if runs is not None:
        # each program's roughing on the stock it met while the paths were planned: the programs at once
        if progress is not None:
            progress(READ_SHARE, f"the roughing's engagement in {len(read)} programs")
        engagement_of = _engagements(read, simulated, tools, config)
    for n_done, name, area, motion in read:
        travel = check_travel(motion, profile)
        minutes = move_minutes(motion, config)
        too_fast = rotary_feed_excesses(motion, minutes, profile)
        if runs is not None:
            run = runs[name]
            engaged = engagement_of[name]
        else:
            # the roughing runs first in its program: the stock now is the one it meets
            say(n_done, 0.0, f"{name}: the roughing's engagement ({n_done + 1}/{len(names)})")
            engaged = measure_engagement(motion, models.stock, tools, config)
            say(n_done, 0.05, f"{name}: simulating {motion.n_moves} moves ({n_done + 1}/{len(names)})")
            run = run_moves(models.stock, models.obstacles, motion, tools, rapid_clearance_mm=sim.rapid_clearance_mm,
                            progress=None if progress is None else
                            (lambda f, m, n_done=n_done, name=name: say(n_done, 0.05 + 0.95 * f, f"{name}: {m}")))
        av = AreaVerification(area=area, program=name, n_moves=motion.n_moves,
                              removed_mm3=round(float(run.removed_mm3.sum()), 1),
                              machining_time_s=round(60.0 * float(minutes.sum()), 1),
                              rapids_into_material=int((run.rapid_depth_mm > 0).sum()),
                              holder_collisions=int((run.holder_depth_mm > 0).sum()),
                              fixture_collisions=int((run.fixture_depth_mm > 0).sum()),
                              travel_excursions=len(travel),
                              rotary_feed_excesses=len({t["line"] for t in too_fast}),
                              plunges_into_material=_plunges(motion, run.removed_mm3,
                                                             config.post.roughing_tool_number),
                              operations=operation_figures(motion, run.removed_mm3, config, engaged))
        av.over_engagement_moves = sum(op.over_engagement_moves for op in av.operations)
        if engaged is not None and engaged.note:
            v.notes.append(f"{name}: {engaged.note}")
        v.areas.append(av)
        worst += _offences("rapid_into_material", motion, run.rapid_depth_mm, "tool in stock at rapid")
        worst += _offences("holder_collision", motion, run.holder_depth_mm, "shank or holder in stock")
        worst += _offences("fixture_collision", motion, run.fixture_depth_mm, "fixture, riser or table")
        worst += [VerificationOffence(kind="travel", program=t["program"], line=int(t["line"]),
                                      position_mm=tuple(round(float(c), 4) for c in motion.end_mm[t["move"]])
                                      if "move" in t else (math.nan,) * 3,
                                      amount=round(float(t["excess"]), 4),
                                      detail=f"{t['axis']} {t['value']:.3f} beyond {t['limit']:.3f}")
                  for t in sorted(travel, key=lambda t: -t["excess"])[:WORST_PER_CLASS]]
        worst += [VerificationOffence(kind="rotary_speed", program=t["program"], line=int(t["line"]),
                                      position_mm=tuple(round(float(c), 4) for c in motion.end_mm[t["move"]]),
                                      amount=round(float(t["excess"]), 6),
                                      detail=f"{t['axis']} turns at {t['rate_deg_min']:.1f} deg/min, limit "
                                             f"{t['limit_deg_min']:.1f}")
                  for t in sorted(too_fast, key=lambda t: -t["excess"])[:WORST_PER_CLASS]]
        say(n_done, 1.0, f"{name}: {motion.n_moves} moves " + ("proven simulated" if runs is not None else "simulated"))
    # the deviation of every scan point, in chunks so that a large scan still reports (per point: the same)
    dev, dev_high = np.empty(points.shape[0]), np.empty(points.shape[0])
    for a in range(0, max(points.shape[0], 1), DEVIATION_CHUNK):
        b = min(points.shape[0], a + DEVIATION_CHUNK)
        say(len(names), 0.7 * a / max(points.shape[0], 1), f"deviation of the scan from the simulated stock: "
                                                             f"points {a + 1}-{b} of {points.shape[0]}")
        dev[a:b], dev_high[a:b] = deviation_pair(stock, points[a:b], normals[a:b], max_mm=10.0)
    fp = config.paths.finishing
    limit = fp.tolerance_mm + fp.scallop_mm + models.measuring_bound_mm
    gouge = fp.tolerance_mm + models.measuring_bound_mm
    # the points read as gouged, measured exactly against the tools of the moves that ran
    exact = np.full(dev.shape, np.nan)
    suspect = np.flatnonzero(np.isfinite(dev_high) & (dev_high < -gouge))
    if suspect.size:
        from planning.simulate.gouge import penetration_mm

        say(len(names), 0.7, f"{suspect.size} points read below the scan: measured exactly")
        exact[suspect] = penetration_mm(points[suspect], motions, tools, lambda f, m: say(len(names), 0.7 + 0.15 * f, m))
    exact_limit = gouge_allowance_mm(config)
    dev = reported_deviation(dev, dev_high, exact)
    v.deviation = deviation_figures(dev, limit, gouge, dev_high, exact, exact_limit)
    for av in v.areas:
        mine = input_labels == av.area
        av.deviation = deviation_figures(dev[mine], limit, gouge, dev_high[mine], exact[mine], exact_limit)
    finish_left = None
    if sim.exact_finish:
        from planning.simulate.finish import finish_left_mm

        idx = finish_sample(points.shape[0], sim.exact_finish_points)
        say(len(names), 0.85, f"the finish, measured exactly from the finishing moves on {idx.size:,} scan points")
        left = finish_left_mm(points[idx], motions, tools[config.post.finishing_tool_number],
                              lambda f, m: say(len(names), 0.85 + 0.15 * f, f"the finish, exactly: {m}"))
        finish_left = np.full(points.shape[0], np.nan)
        finish_left[idx] = left
        v.finish = finish_figures(left, fp.scallop_mm, fp.tolerance_mm, exact_limit)
        for av in v.areas:
            av.finish = finish_figures(left[input_labels[idx] == av.area], fp.scallop_mm, fp.tolerance_mm, exact_limit)
    for field in ("rapids_into_material", "holder_collisions", "fixture_collisions", "travel_excursions",
                  "rotary_feed_excesses", "plunges_into_material", "over_engagement_moves"):
        setattr(v, field, sum(getattr(a, field) for a in v.areas))
    v.machining_time_s = round(sum(a.machining_time_s for a in v.areas), 1)
    v.worst = worst
    v.status = verification_status(v)
    v.message = _message(v)
    v.seconds = round(time.perf_counter() - t0, 3)
    return SimulationOutcome(verification=v, deviation_mm=dev, stock=stock,
                             finish_left_mm=finish_left)


def _engagements(read, simulated, tools, config) -> dict:
    """``{program name: Engagement or None}``: :func:`measure_engagement` of every program read, on the stock
    its roughing met in the paths stage (the roughing operation's ``stock_before``), on the kernels' threads."""
    import numba

    rough = int(config.post.roughing_tool_number)
    jobs = []
    for _, name, area, motion in read:
        before = next((op.stock_before for op in simulated.get(area, []) if op.tool == rough and op.n_moves), None)
        jobs.append((name, motion, before))
    out: dict = {}
    if len(jobs) <= 1 or numba.get_num_threads() <= 1:
        for name, motion, before in jobs:
            out[name] = measure_engagement(motion, before, tools, config)
        return out
    from planning.simulate.dexel import _map

    # on the simulation's own pool (its threads exist already: no new thread stacks or malloc arenas)
    def one(job):
        name, motion, before = job
        out[name] = measure_engagement(motion, before, tools, config)

    _map(one, jobs)
    return {name: out[name] for name, _, _ in jobs}


def _single_pass(read, simulated, stock_after, models, tools, config, say):
    """``({program name: MoveFigures}, note)`` when every program read in ``read`` is proven to run the
    moves the paths stage simulated (:func:`planning.simulate.single_pass.prove_program`), else
    ``(None, why not)``; ``say(k, message)`` before the k-th program (or None)."""
    from planning.simulate.single_pass import proof_tolerance_mm, prove_program

    if simulated is None or stock_after is None:
        return None, "the paths were not run on the carried stock (paths.carry_stock is false, or no paths)"
    if not read:
        return None, "no program was read"
    tol = proof_tolerance_mm(config.post.decimals)
    runs, n_sim, n_chk = {}, 0, 0
    for n_done, (_, name, area, motion) in enumerate(read):
        if say is not None:
            say(n_done, f"{name}: proving its {motion.n_moves} moves are the simulated ones")
        if area not in simulated:
            return None, f"{name}: the paths stage simulated no operation of area {area}"
        proof = prove_program(motion, simulated[area], models.stock, models.obstacles, tools, tol_mm=tol,
                              rapid_clearance_mm=config.simulate.rapid_clearance_mm)
        if proof.figures is None:
            return None, f"not proven, every program was run again: {proof.reason}"
        runs[name] = proof.figures
        n_sim += proof.n_simulated
        n_chk += proof.n_checked
    return runs, (f"{n_sim} program moves proven to be the moves simulated while planning (within "
                  f"{tol:g} mm); {n_chk} others (tool changes, moves to and from machine Z0) run here")
