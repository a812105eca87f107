"""The text of the G-code posts (docs/design.md stage 8, post-processing): number formatting, comments, the
block writer with its line numbers, and the header and operation comments both posts print.

Numbers
-------
Coordinates are printed with ``decimals`` places (default 4, i.e. 0.1 micrometre), always with a
decimal point (``X10.`` — on a Fanuc without decimal-point programming ``X10`` would mean 10
micrometres), without trailing zeros and never as ``-0.`` (:func:`fmt`). A coordinate word is
printed only when its rounded value changes (modal); the first move of every operation prints X, Y
and Z. Arc centre offsets ``I J K`` are measured from the ROUNDED start point as printed, so the
centre the control computes is the planned one to within the rounding of the offsets (the motion
blocks: :mod:`planning.post.motion`).
"""

from __future__ import annotations

import re
from collections.abc import Sequence

import numpy as np

from .options import Operation, PostOptions

__all__ = ["BlockWriter", "comment", "fmt", "header_lines", "operation_comment", "rounded", "scanmill_version",
           "spindle_word"]


def scanmill_version() -> str:
    """The installed scanmill version (``scanmill.__version__``)."""
    import scanmill

    return str(scanmill.__version__)


def _tidy(s: str) -> str:
    """Python's fixed-point text ``s`` as the posts print it: a decimal point, no trailing zeros,
    never ``-0.``."""
    s = (s if "." in s else s + ".").rstrip("0")
    return "0." if s == "-0." else s


def fmt(value: float, decimals: int) -> str:
    """``value`` rounded to ``decimals`` places with a decimal point and no trailing zeros:
    ``10.``, ``-0.5``, ``0.`` (never ``-0.``)."""
    return _tidy(f"{float(value):.{int(decimals)}f}")


def fmt_many(values, decimals: int) -> list[str]:
    """``[fmt(v, decimals) for v in values]`` (a 1-D array or sequence) with one bound format: the
    posts' long 5-axis programs print millions of numbers."""
    text = f"{{:.{int(decimals)}f}}".format
    return [_tidy(text(v)) for v in np.asarray(values, dtype=np.float64).reshape(-1).tolist()]


def rounded(value: float, decimals: int) -> float:
    """The value a control reads from ``fmt(value, decimals)``."""
    return float(fmt(value, decimals))


_COMMENT_BAD = re.compile(r"[^A-Za-z0-9 .,:=+\-_/*#<>\[\]]")


def comment(text: str, *, upper: bool = False) -> str:
    """``(text)`` with parentheses and unusual characters replaced by spaces (no nesting)."""
    s = _COMMENT_BAD.sub(" ", str(text))
    s = re.sub(r"\s+", " ", s).strip()
    return f"({s.upper() if upper else s})"


class BlockWriter:
    """Collects program lines; numbers the blocks (not comments, not ``%``) when asked."""

    def __init__(self, options: PostOptions):
        self.lines: list[str] = []
        self.numbered = options.line_numbers
        self.step = int(options.line_number_step)
        self.n = 0

    def raw(self, text: str) -> None:
        self.lines.append(text)

    def block(self, *words: str) -> None:
        words = [w for w in words if w]
        if not words:
            return
        if self.numbered:
            self.n += self.step
            if self.n > 99999:
                self.n = self.step
            words = [f"N{self.n}"] + words
        self.lines.append(" ".join(words))

    def take_numbers(self, count: int) -> np.ndarray:
        """The ``N`` numbers (int64, (count,)) of the next ``count`` blocks, as :meth:`block` would give
        them one by one (the writer moves on past them)."""
        period = 99999 // self.step                      # blocks before the numbers wrap
        k = self.n // self.step + np.arange(count, dtype=np.int64)
        out = (k % period + 1) * self.step
        if count:
            self.n = int(out[-1])
        return out

    def text(self) -> str:
        return "\n".join(self.lines) + "\n"


def header_lines(*, post: str, area_id, setup_id, tool_axis: np.ndarray, rotary_deg, axis_names,
                 extra: Sequence[str], upper: bool) -> list[str]:
    """The header comment lines common to the posts."""
    lines = [comment(f"scanmill {scanmill_version()} - {post}", upper=upper)]
    lines.append(comment(f"area {area_id if area_id is not None else '-'} setup "
                         f"{setup_id if setup_id is not None else '-'}", upper=upper))
    lines.append(comment("tool axis in the part frame " + " ".join(
        f"{n}{fmt(v, 6)}" for n, v in zip("XYZ", tool_axis)), upper=upper))
    if rotary_deg is not None:
        names = axis_names or ("tilt", "rotary")
        lines.append(comment(f"rotary angles of the plan (planning.orientations.kinematics signs, deg) {names[0]}"
                             f"{fmt(rotary_deg[0], 6)} {names[1]}{fmt(rotary_deg[1], 6)}", upper=upper))
    lines.extend(comment(e, upper=upper) for e in extra)
    return lines


def operation_comment(k: int, op: Operation, upper: bool) -> str:
    return comment(f"operation {k + 1}: {op.name} - T{int(op.tool_number)} D{fmt(op.tool_diameter_mm, 3)} "
                   f"{op.tool_type} - S{fmt(op.spindle_rpm, 0)[:-1]} F{fmt(op.feed_mm_min, 3)} "
                   f"plunge F{fmt(op.plunge_mm_min, 3)} mm/min - tip offset {fmt(op.toolpath.tip_offset_mm, 4)}",
                   upper=upper)


def spindle_word(rpm: float) -> str:
    return f"S{round(float(rpm))}"
