"""The stock as one operation of one set-up sees it (issue 30, ``docs/design.md`` "Stock-first
planning"): the carried tri-dexel stock (:mod:`planning.simulate.dexel`) read in the set-up's frame,
and cut by the operation's moves as they are planned.

A :class:`StockView` holds its OWN copy of the stock, so planning never changes the carried stock;
the guard (:mod:`planning.toolpath.guard`) still runs the finished operation on the carried one. An
operation reads the view (:meth:`StockView.tops`: the highest material per raster cell along the
frame's Z between two heights, :func:`planning.simulate.heightfield.stock_tops_in_frame`) and
cuts it with the moves it has written (:meth:`StockView.cut`), so that what it plans next (the next
roughing level, its entries and lifts) meets the material that is really left, not a bound of it.
Frame: :class:`planning.toolpath.frames.AreaFrame` (tool axis +Z), mm; the moves are tool-tip
points.
"""

from __future__ import annotations

import numpy as np

from planning.simulate.dexel import TriDexel, cut
from planning.simulate.heightfield import stock_tops_in_frame
from planning.simulate.motion import FEED, RAPID, ToolShape
from planning.toolpath.frames import AreaFrame


class StockView:
    """A copy of ``stock`` seen in ``frame`` and cut by ``shape`` (the operation's tool as the
    simulation sees it). ``obstacles``: what is never cut (fixtures, riser, table; the carried
    obstacles, not copied) or None. ``resolution_mm``: the stock model's ray spacing (how far across
    its rays a reading may be off, :meth:`tops`)."""

    def __init__(self, stock: TriDexel, frame: AreaFrame, shape: ToolShape, obstacles: TriDexel | None = None):
        self.stock = stock.copy()
        self.obstacles = obstacles
        self.frame = frame
        self.shape = shape
        self.resolution_mm = float(stock.res)

    def tops(self, x0: float, y0: float, h: float, nx: int, ny: int, start, stop: float) -> np.ndarray:
        """(nx, ny) frame z (mm) of the highest material between ``stop`` and ``start`` (scalar or
        (nx, ny); -inf: skip the cell) on the line along the frame's Z through the centre of every
        cell of the raster (cells of side ``h`` from (``x0``, ``y0``)); -inf where there is none.
        Read on the stock's rays: within half a ray spacing across them of the line."""
        return stock_tops_in_frame(self.stock, self.frame.rotation, self.frame.origin_mm, x0, y0, h, nx, ny,
                                   start, stop)

    def cut(self, start_frame, end_frame, rapid) -> np.ndarray:
        """Cut the view's stock with the moves from ``start_frame`` to ``end_frame`` ((P,3) tool tips
        in the frame; ``rapid`` (P,) bool: rapids cut nothing), in their order; returns the volume each
        removed, mm^3."""
        s = self.frame.to_part(np.asarray(start_frame, dtype=np.float64).reshape(-1, 3))
        e = self.frame.to_part(np.asarray(end_frame, dtype=np.float64).reshape(-1, 3))
        if s.shape[0] == 0:
            return np.zeros(0)
        kind = np.where(np.asarray(rapid, dtype=bool).reshape(-1), RAPID, FEED).astype(np.int8)
        ax = np.broadcast_to(self.frame.rotation[2], s.shape)
        return cut(self.stock, s, e, ax, self.shape, kind)

    def column_clear_z(self, points_frame, top_z: float, clearance_mm: float) -> np.ndarray:
        """(n,) for each tool tip (frame, n,3) the lowest height (frame z) at or above it from which
        the whole tool, grown by ``clearance_mm`` and moved straight up to ``top_z``, meets none of
        the view's material nor the obstacles (:func:`planning.toolpath.guard.column_clear_z`, the
        guard's own test of a rapid up the tool axis)."""
        from planning.toolpath.guard import column_clear_z

        z = column_clear_z(self.frame, self.shape, self.stock, points_frame, float(top_z), 0.0, float(clearance_mm))
        if self.obstacles is not None:
            z = np.maximum(z, column_clear_z(self.frame, self.shape, self.obstacles, points_frame, float(top_z), 0.0,
                                             float(clearance_mm)))
        return z

    def column_is_clear(self, point_frame, top_z: float, clearance_mm: float) -> bool:
        """Whether the whole tool at the tip ``point_frame`` (frame x, y, z), grown by ``clearance_mm`` and
        moved straight up to ``top_z``, meets none of the view's material nor the obstacles: one swept
        test of the whole column each (:func:`planning.simulate.dexel.collide`), exact on the stock's
        rays, where :meth:`column_clear_z` finds the height (to its tolerance above the exact one)."""
        from planning.simulate.dexel import collide

        p = np.asarray(point_frame, dtype=np.float64).reshape(3)
        if not float(top_z) > p[2]:
            top_z = float(p[2])
        s = self.frame.to_part(p[None, :])
        e = self.frame.to_part(np.array([[p[0], p[1], float(top_z)]]))
        ax = self.frame.rotation[2][None, :]
        for model in (self.stock, self.obstacles):
            if model is not None and collide(model, s, e, ax, self.shape, which="tool", grow_mm=clearance_mm)[0] > 0:
                return False
        return True

    def rapid_clear_z(self, a_frame, b_frame, z: float, top_z: float, clearance_mm: float) -> float:
        """The lowest height (frame z) at or above ``z`` (at most ``top_z``) from which a rapid from
        ``a_frame`` to ``b_frame`` (frame x, y) keeps the whole tool ``clearance_mm`` from the view's
        material and the obstacles, and so does the same rapid at every height above it up to
        ``top_z`` (:func:`planning.simulate.dexel.column_rise` with the rapid as its sweep: to 0.02 mm
        above the exact height on the stock's rays; the guard's swept test of the rapid finds it
        clear); ``top_z`` when the rapid meets material there."""
        from planning.simulate.dexel import column_rise

        a2, b2 = np.asarray(a_frame, dtype=np.float64)[:2], np.asarray(b_frame, dtype=np.float64)[:2]
        if not float(top_z) > float(z):
            return float(top_z)
        start = self.frame.to_part(np.array([[a2[0], a2[1], float(z)]]))
        sweep = self.frame.to_part(np.array([[b2[0], b2[1], float(z)]])) - start
        rise = -np.inf
        for model in (self.stock, self.obstacles):
            if model is not None:
                rise = max(rise, float(column_rise(model, start, self.frame.rotation[2], float(top_z) - float(z),
                                                   self.shape, grow_mm=clearance_mm, sweep=sweep)[0]))
        if not rise >= 0.0:
            return float(z)
        return min(float(z) + rise + 1e-6, float(top_z))

    def obstacle_points(self) -> np.ndarray:
        """(K,3) points on the boundary of the obstacles in the frame (mm; empty when there are none)."""
        if self.obstacles is None:
            return np.zeros((0, 3))
        return self.frame.to_frame(self.obstacles.boundary_points())

