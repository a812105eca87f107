"""Fuzzing the readers: damaged files end in a Cloud or a typed PlanningError, never another exception.

A deterministic (seeded) corpus of mutated small valid files of every format read (tests/hostile_files.py:
truncations, bit flips, header counts inflated x1000, to 2**31 and to 2**63-1, list counts inflated,
negative and huge numbers) is read in ONE child process under an address-space limit, and each file is
also planned there through the CLI's own ``scanmill.cli.main(["plan", FILE, "--out", DIR, "--quiet",
...])`` with cheap parameters: the README's exit-code promise, 0, 2, 3 or 4 and never an exception, with
exit 2 printing exactly one ``error [code]: ...`` line and writing nothing. The child's report is then
checked per reader (one test each). A bigger corpus (more seeds of bit flips) is ``slow``. The fast
helpers the readers rely on are property-tested against plain references with Hypothesis.
"""

from __future__ import annotations

import re

import numpy as np
import pytest
from hostile_files import RSS_LIMIT, base_files, corpus, read_in_child
from hypothesis import given, settings
from hypothesis import strategies as st

#: cheap plan parameters: no paths, no simulation, no collision test, few orientations, few mesh points
PLAN_ARGS = [item for setting in (
    "paths.finishing.enabled=false", "paths.roughing.enabled=false", "simulate.enabled=false",
    "visibility.global=false", "areas.method=per_point", "input.accept_small_part=true",
    "input.mesh_max_points=300", "orientations.phi_step_deg=30", "orientations.theta_step_deg=90",
    "post.dialects=[]") for item in ("--set", setting)]

#: the base files, one per reader (PLY ascii and binary, with polygons of mixed sizes, and a binary cloud)
READERS = ["mesh_ascii.ply", "mesh_binary.ply", "cloud_binary.ply", "cloud_ascii.pcd", "cloud_binary.pcd", "cloud.xyz",
           "mesh_ascii.stl", "mesh_binary.stl", "mesh.obj", "cloud.las", "cloud.laz", "grid.e57"]
_ERROR_LINE = re.compile(r"error \[([a-z_]+)\]: \S.*")


def _run(tmp_path, items) -> dict:
    paths = []
    for name, data in items:
        path = tmp_path / name
        path.write_bytes(data)
        paths.append(path)
    report = read_in_child(paths, plan_args=PLAN_ARGS)
    assert report["returncode"] == 0, report["stderr"][-4000:]
    assert report["stderr"] == ""                                # nothing printed past Python (a Rust panic)
    assert report["limit_enforced"] is True
    assert len(report["results"]) == len(paths)
    return report


@pytest.fixture(scope="module")
def fuzzed(tmp_path_factory):
    """The default corpus (seed 0, two bit-flipped copies of each file) read and planned in one child."""
    return _run(tmp_path_factory.mktemp("fuzz"), corpus(seed=0, n_flips=2))


def check(result: dict) -> None:
    """One file's outcome: a Cloud or a typed refusal; then the CLI's exit status and output."""
    name = result["path"].rsplit("/", 1)[-1]
    assert result["python_warnings"] == [], (name, result["python_warnings"])
    assert result["max_rss"] < RSS_LIMIT, (name, result["max_rss"])
    if result["ok"]:
        assert result["n_points"] >= 3, (name, result)
    else:
        assert result["error"] in ("InputError", "InputTooLarge"), (name, result)
        assert re.fullmatch(r"[a-z_]+", result["code"] or "") and 400 <= result["status"] < 500, (name, result)
        assert result["message"], name
    cli = result["cli"]
    assert cli.get("exception") is None, (name, cli)
    assert cli["status"] in (0, 2, 3, 4), (name, cli)
    assert cli["python_warnings"] == [], (name, cli)
    if cli["status"] == 2:
        lines = cli["stderr"].splitlines()
        assert len(lines) == 1, (name, cli["stderr"])
        match = _ERROR_LINE.fullmatch(lines[0])
        assert match, (name, lines[0])
        assert not cli["out_exists"], name                       # nothing is written
        if not result["ok"]:
            assert match.group(1) == result["code"], (name, lines[0], result["code"])
    else:
        assert result["ok"], (name, result, cli)                 # a file that does not read is not planned
        assert cli["stderr"] == "" and cli["out_exists"], (name, cli)


@pytest.mark.parametrize("reader", READERS)
def test_every_damaged_file_is_a_cloud_or_a_typed_error(fuzzed, reader):
    stem, ext = reader.rsplit(".", 1)
    pattern = re.compile(rf"{re.escape(stem)}__.*\.{ext}")
    mine = [r for r in fuzzed["results"] if pattern.fullmatch(r["path"].rsplit("/", 1)[-1])]
    assert len(mine) >= 8, reader
    for result in mine:
        check(result)
    valid = next(r for r in mine if "__valid." in r["path"])
    assert valid["ok"] and valid["cli"]["status"] in (0, 3, 4), valid  # the unmutated file reads and plans
    assert sum(not r["ok"] for r in mine) >= 4, reader           # and the mutations are refused, mostly


def test_the_corpus_covers_every_reader_and_mutation():
    names = [name for name, _ in corpus(seed=0, n_flips=2)]
    assert len(names) == len(set(names))
    assert {n.split("__")[0] + "." + n.rsplit(".", 1)[1] for n in names} == set(READERS) == set(base_files())
    for kind in ("cut-half", "cut-last", "flip0", "-1000", "-2147483648", "-9223372036854775807", "list_count",
                 "1e400", "-99999999999999999999", "--1"):
        assert any(kind in n for n in names), kind


@pytest.mark.slow
def test_a_bigger_corpus_is_read_and_planned_cleanly(tmp_path):
    report = _run(tmp_path, corpus(seed=1, n_flips=25))
    for result in report["results"]:
        check(result)


# ------------------------------------------------------------------- the helpers, against references

_lines_of_ints = st.lists(st.lists(st.integers(-10 ** 12, 10 ** 12), max_size=6), max_size=12)


@settings(max_examples=200, deadline=None)
@given(_lines_of_ints, st.sampled_from([" ", "  ", "\t"]), st.booleans())
def test_fast_integers_parses_what_python_does(rows, sep, final_newline):
    from planning.inputs.rows import _fast_integers

    text = ("\n".join(sep.join(str(v) for v in row) for row in rows) + ("\n" if final_newline else "")).encode()
    arr = np.frombuffer(text, dtype=np.uint8)
    starts = np.concatenate(([0], np.flatnonzero(arr[:-1] == 10) + 1)) if arr.size else np.zeros(0, np.int64)
    values, counts = _fast_integers(arr, starts)
    lines = text.split(b"\n") if text else []
    if text.endswith(b"\n"):
        lines.pop()                                         # no line after the last newline
    assert values.tolist() == [v for row in rows for v in row]
    assert counts.tolist() == [len(line.split()) for line in lines]


@settings(max_examples=50, deadline=None)
@given(st.lists(st.text(alphabet="0123456789-+ .eE/x", min_size=1, max_size=8), min_size=1, max_size=10))
def test_fast_integers_refuses_what_is_not_an_integer(tokens):
    from planning.inputs.rows import _fast_integers

    text = (" ".join(tokens) + "\n").encode()
    arr = np.frombuffer(text, dtype=np.uint8)
    parsed = _fast_integers(arr, np.array([0]))
    words = text.split()
    if all(re.fullmatch(rb"[-+]?\d+", w) for w in words):
        assert parsed is not None and parsed[0].size == len(words)
    else:
        assert parsed is None


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 6), st.integers(0, 6), st.integers(0, 6)), max_size=40),
       st.sampled_from([7, 3_000_000]))
def test_duplicate_faces_are_the_repeats_of_earlier_vertex_sets(faces, n_vertices):
    from planning.inputs.mesh import _duplicate_faces

    tri = np.array(faces, dtype=np.int64).reshape(-1, 3)
    seen, expected = set(), []
    for t in faces:
        key = tuple(sorted(t))
        expected.append(key in seen)
        seen.add(key)
    assert _duplicate_faces(tri, n_vertices).tolist() == expected
