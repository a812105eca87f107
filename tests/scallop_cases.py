"""The analytic surfaces the scallop is measured on (issue 31 item 2), shared by tests/test_scallop.py
and bench/bench_scallop_analytic.py, and the finishing moves as the simulation reads them
(bench/bench_scallop_sood.py too). Imports only planning modules that predate the scallop work, so a
bench can plan with an older checkout (``--root``)."""

from __future__ import annotations

import math

import numpy as np

R = 3.0
#: the surfaces, in the order the bench prints them
SURFACES = ("plane", "slope_40", "convex_cylinder", "concave_cylinder_across", "concave_cylinder_along",
            "sphere", "bowl", "saddle")


def surface_z(kind: str, x, y):
    """Height (mm) of the analytic surface ``kind`` at (x, y): a plane, a 40-degree slope across the
    passes, a convex cylinder rho 10, a concave one rho 6 = 2 R across and along the passes, a sphere
    rho 15, a bowl rho 10, a saddle (x^2 - y^2) / 24."""
    if kind == "plane":
        return 0.0 * x
    if kind == "slope_40":
        return math.tan(math.radians(40.0)) * y
    if kind == "convex_cylinder":
        return np.sqrt(100.0 - y * y) - 10.0
    if kind == "concave_cylinder_across":          # rho = 2 R, its axis along the passes
        return 6.0 - np.sqrt(36.0 - y * y)
    if kind == "concave_cylinder_along":           # rho = 2 R, across the passes: the forward step
        return 6.0 - np.sqrt(36.0 - x * x)
    if kind == "sphere":
        return np.sqrt(225.0 - x * x - y * y) - 15.0
    if kind == "bowl":
        return 10.0 - np.sqrt(100.0 - x * x - y * y)
    if kind == "saddle":
        return (x * x - y * y) / 24.0
    raise ValueError(kind)


def ball_motion(tp, radius_mm: float = R):
    """The straight feed moves of a 3-axis ball-end toolpath (:class:`planning.toolpath.moves.Toolpath`,
    ball centres, tool axis +Z) as the simulation's :class:`planning.simulate.motion.ProgramMotion`
    (tool tips), T1."""
    from planning.simulate.motion import FEED, ProgramMotion

    cl, kind = tp.xyz_mm, tp.kind
    f = kind[1:] == FEED
    n = int(f.sum())
    tip = np.array([0.0, 0.0, float(radius_mm)])
    return ProgramMotion(program="t", area=0, line=np.arange(1, n + 1), kind=np.full(n, FEED, np.int8),
                         tool=np.ones(n, np.int64), start_mm=cl[:-1][f] - tip, end_mm=cl[1:][f] - tip,
                         axis=np.tile([0.0, 0.0, 1.0], (n, 1)), machine_mm=np.zeros((n, 3)),
                         rotary_deg=np.zeros((n, 2)))


def ball(radius_mm: float = R):
    """The finishing ball as the simulation sees it, T1."""
    from planning.simulate.motion import ToolShape

    return ToolShape(number=1, kind="ball", radius_mm=float(radius_mm), corner_radius_mm=float(radius_mm),
                     flute_length_mm=20.0, pieces=((20.0, 60.0, 4.0),))


def finish_and_measure(kind: str, scallop_mm: float, tol_mm: float, every: int = 1):
    """Finish the middle of ``kind`` (a 0.05 mm grid of its points; the middle 10 x 10 mm, 6 x 6 on the
    concave ones) with :func:`planning.toolpath.finishing.finishing_passes` (R 3 mm) and measure from
    the finishing moves the material left over every ``every``-th point 1 mm or more inside it
    (:func:`planning.simulate.finish.finish_left_mm`): ``(left (k,), the FinishingPath)``."""
    from planning.simulate.finish import finish_left_mm
    from planning.toolpath.finishing import finishing_passes

    half = 3.0 if kind.startswith("concave") or kind == "bowl" else 5.0
    g = np.arange(-half - 2.0, half + 2.0 + 1e-9, 0.05)
    X, Y = np.meshgrid(g, g, indexing="ij")
    x, y = X.ravel(), Y.ravel()
    pts = np.column_stack([x, y, surface_z(kind, x, y)])
    pts[:, 2] -= pts[:, 2].max()
    area = (np.abs(x) <= half) & (np.abs(y) <= half)
    fin = finishing_passes(pts, area, radius_mm=R, scallop_mm=scallop_mm, tol_mm=tol_mm, margin_mm=1.0)
    inner = np.flatnonzero((np.abs(x) <= half - 1.0) & (np.abs(y) <= half - 1.0))[::every]
    return finish_left_mm(pts[inner], [ball_motion(fin.toolpath)], ball()), fin
