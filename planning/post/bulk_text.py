"""Whole-array text (docs/design.md stage 8, post-processing): the integers whose digits
:func:`~planning.post.blocks.fmt` prints, for whole arrays of numbers (:func:`_quantise`), and
:class:`_Rows`, which lays out many rows of words (program blocks, items of a JSON list) at once as
columns of characters. The motion blocks (:mod:`planning.post.motion`) and the neutral JSON
(:mod:`planning.post.neutral`) write their long texts with it, byte for byte what formatting one
number at a time prints.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

#: Largest ``|value| * 10^decimals`` the whole-array formatter takes (integers far inside what
#: float64 and int64 hold exactly); an operation with a larger coordinate goes through
#: :class:`~planning.post.motion.MotionEmitter`.
_Q_MAX = 2.0 ** 51


def _quantise(values, decimals: int) -> np.ndarray | None:
    """The integers ``q`` (int64, the shape of ``values``) whose digits :func:`~planning.post.blocks.fmt` prints:
    ``v * 10^decimals`` rounded half to even on the exact binary value of ``v``, as Python's
    ``f"{v:.{decimals}f}"`` (``float(fmt(v, d)) == q / 10^d`` exactly). None when some
    ``|v| * 10^decimals >= _Q_MAX``.

    The float product is off the exact one by at most ``|p| 2^-53``; where that could move it across
    a half-way point (exact ties included), Python's formatting decides."""
    v = np.asarray(values, dtype=np.float64)
    p = v * float(10 ** decimals)
    a = np.abs(p)
    if a.size and not a.max() < _Q_MAX:
        return None
    q = np.rint(p).astype(np.int64)
    for i in np.flatnonzero(np.abs(a - np.floor(a) - 0.5) <= a * 2.0 ** -52):
        q.flat[i] = int(f"{float(v.flat[i]):.{decimals}f}".replace(".", ""))
    return q


def _digits(q: np.ndarray, decimals: int, point: bool = True, repr_style: bool = False) -> list[tuple]:
    """The characters of ``fmt(q[i] / 10^decimals, decimals)`` for every i (``point=False``: the
    digits of the integers ``q >= 0``; ``repr_style``: Python's ``repr`` of the float
    ``q[i] / 10^decimals`` where that is positional: one digit after the point at least, ``10.0``,
    ``0.5``) as columns, left to right: ``(chars, keep)`` pairs, ``chars`` a (n,) uint8 array or one
    character code for all rows, ``keep`` (n,) bool (the row has it)."""
    n = q.shape[0]
    a = np.abs(q)
    top = int(a.max()) if n else 0
    nd = len(str(top // 10 ** decimals))                  # digits before the point
    rest = a.astype(np.uint32) if top < 2 ** 32 else a    # (uint32 divides several times faster)
    digit = {}
    frac_keep = {}
    nonzero = np.zeros(n, dtype=bool)
    for j in range(nd + decimals - 1, -1, -1):            # digit by digit from the right
        if j == nd - 1:
            ip = rest                                     # the integer part
        higher = rest // 10
        digit[j] = (rest - higher * 10).astype(np.uint8) + np.uint8(ord("0"))
        if j >= nd:                                       # no trailing zeros after the point
            nonzero = nonzero | (digit[j] != ord("0"))
            frac_keep[j] = nonzero
        rest = higher
    everyone = np.ones(n, dtype=bool)
    cols = [(ord("-"), q < 0)]
    cols += [(digit[j], ip >= 10 ** (nd - 1 - j)) for j in range(nd - 1)]      # no leading zeros
    cols.append((digit[nd - 1], everyone))
    if point:
        cols.append((ord("."), everyone))
    if repr_style:
        if decimals:
            frac_keep[nd] = everyone
        else:
            cols.append((ord("0"), everyone))
    cols += [(digit[j], frac_keep[j]) for j in range(nd, nd + decimals)]
    return cols


class _Rows:
    """The text of many rows at once (blocks of a program, items of a JSON list): words added left
    to right, each present or not in each row, joined by ``sep`` (where ``glue``), each row ended by
    ``end``. Every character position is a column (characters (n,) or one for all, kept (n,)
    bool); :meth:`text` lays them out row by row."""

    def __init__(self, n: int, sep: str = " ", end: str = "\n"):
        self.n = n
        self.sep, self.end = ord(sep), ord(end)
        self.cols: list[tuple] = []
        self.seen = np.zeros(n, dtype=bool)

    def _word(self, cols: list[tuple], present: np.ndarray, glue: bool = True) -> None:
        if glue:
            self.cols.append((self.sep, present & self.seen))
        self.cols += [(c, k & present) for c, k in cols]
        self.seen = self.seen | present

    def const(self, text: str, present: np.ndarray, glue: bool = True) -> None:
        """Word ``text`` in the rows where ``present``."""
        self._word([(ord(ch), present) for ch in text], present, glue)

    def table(self, idx: np.ndarray, words: Sequence[str], present: np.ndarray, glue: bool = True) -> None:
        """Word ``words[idx[i]]`` in row i where ``present[i]``."""
        if not present.any():
            return
        width = max(len(w) for w in words)
        tab = np.array([w.encode("ascii") for w in words], dtype=f"S{width}").view(np.uint8).reshape(-1, width)
        cols = []
        for j in range(width):
            c = tab[:, j]
            if np.all(c == c[0]):
                cols.append((int(c[0]), present))
            else:
                cols.append((c[idx], c[idx] != 0))
        self._word(cols, present, glue)

    def number(self, letter: str, q: np.ndarray, decimals: int, present: np.ndarray, point: bool = True,
               repr_style: bool = False, glue: bool = True) -> None:
        """Word ``letter + fmt(q[i] / 10^decimals, decimals)`` (see :func:`_digits` for ``point`` and
        ``repr_style``) in row i where ``present[i]``."""
        if not present.any():
            return
        lead = [(ord(letter), present)] if letter else []
        self._word(lead + _digits(q, decimals, point, repr_style), present, glue)

    def raw(self, rows: np.ndarray, texts: Sequence[str], glue: bool = True) -> None:
        """Word ``texts[j]`` in row ``rows[j]`` (ASCII)."""
        if not len(rows):
            return
        present = np.zeros(self.n, dtype=bool)
        present[rows] = True
        width = max(len(t) for t in texts)
        tab = np.zeros((self.n, width), dtype=np.uint8)
        tab[rows] = np.array([t.encode("ascii") for t in texts], dtype=f"S{width}").view(np.uint8).reshape(-1, width)
        self._word([(tab[:, j], tab[:, j] != 0) for j in range(width)], present, glue)

    def text(self) -> str:
        """The rows with a word, each ended by ``end``."""
        cols = self.cols + [(self.end, self.seen)]
        chars = np.empty((self.n, len(cols)), dtype=np.uint8)
        keep = np.empty((self.n, len(cols)), dtype=bool)
        for j, (c, k) in enumerate(cols):
            chars[:, j] = c
            keep[:, j] = k
        return chars[keep].tobytes().decode("ascii")
