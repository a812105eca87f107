"""The simultaneous 5-axis posts on the hemisphere path of tests/test_post_simultaneous.py (issue 19):
points inserted, the ball centre's largest deviation from the planned segments with and without them
(as the post measures it), and the tool tip against the planned one read back by LinuxCNC's rs274 and
by the text reader, per bundled profile.

    .venv/bin/python bench/bench_post_simultaneous.py
"""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

from planning.post.simultaneous import iso_5axis_program, linuxcnc_5axis_program  # noqa: E402
from test_post_simultaneous import OP, PLACE, PROFILES, read, tip_error  # noqa: E402


def main() -> int:
    print(f"{'profile':22} {'inserted lcnc/iso':>17} {'dev with/without mm':>22} {'tip rs274/text mm':>20}")
    for name in PROFILES:
        text, [fig] = linuxcnc_5axis_program(OP, profile=name, placement_mm=PLACE, return_figures=True)
        _, [iso] = iso_5axis_program(OP, profile=name, placement_mm=PLACE, return_figures=True)
        rs = tip_error(read(text, "linuxcnc", name, reader="rs274"), fig, OP)
        tx = tip_error(read(text, "linuxcnc", name), fig, OP)
        print(f"{name:22} {fig['n_inserted']:>8} / {iso['n_inserted']:<6} "
              f"{fig['max_deviation_mm']:>9.4f} / {fig['max_deviation_unlinearised_mm']:<9.3f} "
              f"{rs:>9.1e} / {tx:.1e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
