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
    simulation sees it). ``resolution_mm``: the stock model's ray spacing (how far across its rays
    a reading may be off, :meth:`tops`). ``removed_mm3``: what :meth:`cut` has removed so far."""

    def __init__(self, stock: TriDexel, frame: AreaFrame, shape: ToolShape):
        self.stock = stock.copy()
        self.frame = frame
        self.shape = shape
        self.resolution_mm = float(stock.res)
        self.removed_mm3 = 0.0
        self.n_cut = 0

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
        removed = cut(self.stock, s, e, ax, self.shape, kind)
        self.removed_mm3 += float(removed.sum())
        self.n_cut += int(s.shape[0])
        return removed

    def column_clear_z(self, points_frame, top_z: float, clearance_mm: float) -> np.ndarray:
        """(n,) for each tool tip (frame, n,3) the lowest height (frame z) at or above it from which
        the whole tool, grown by ``clearance_mm`` and moved straight up to ``top_z``, meets none of
        the view's material (:func:`planning.toolpath.guard.column_clear_z`, the guard's own test of a
        rapid up the tool axis)."""
        from planning.toolpath.guard import column_clear_z

        return column_clear_z(self.frame, self.shape, self.stock, points_frame, float(top_z), 0.0, float(clearance_mm))

