"""The command line as a user runs it: outputs per the contract, clear errors, nothing half-written."""

import json

import jsonschema
import numpy as np
import pytest

from planning.inputs.cloud import read_cloud
from scanmill.cli import EXIT_ERROR, EXIT_INFEASIBLE, EXIT_OK, EXIT_UNFINISHED, EXIT_UNSAFE, main
from schemas.plan import plan_json_schema

HS = ["--set", "normals.method=\"input\"", "--set", "setups.max_setups=2", "--set", "tool.diameter_mm=10",
      "--set", "paths.finishing.scallop_mm=0.2", "--set", "paths.roughing.step_down_mm=5"]


def expected_exit(doc: dict) -> int:
    """The exit status plan.json calls for (scanmill/cli.py): 4 unsafe, 3 infeasible or incomplete,
    5 unfinished (the programs finish less than setups.coverage of the scan), else 0."""
    if doc["verification"]["status"] == "failed":
        return EXIT_UNSAFE
    if doc["status"] in ("infeasible", "incomplete"):
        return EXIT_INFEASIBLE
    if doc["status"] == "unfinished":
        assert doc["figures"]["finished_share"] < doc["parameters"]["setups"]["coverage"]
        return EXIT_UNFINISHED
    assert doc["figures"]["finished_share"] >= doc["parameters"]["setups"]["coverage"]
    return EXIT_OK


@pytest.fixture(scope="module")
def half_sphere_ply(tmp_path_factory):
    path = tmp_path_factory.mktemp("in") / "half_sphere.ply"
    assert main(["sample", "half_sphere", "--out", str(path)]) == EXIT_OK
    return path


def test_plan_writes_the_contract(half_sphere_ply, tmp_path, capsys):
    out = tmp_path / "plan"
    code = main(["plan", str(half_sphere_ply), "--out", str(out), *HS])
    text = capsys.readouterr()
    assert "set-up" in text.out and "coverage" in text.out      # summary table
    assert "normals" in text.err and "setups" in text.err       # progress per stage
    doc = json.loads((out / "plan.json").read_text())
    jsonschema.validate(doc, plan_json_schema())
    assert doc["parameters"]["visibility"]["global"] is True
    # per-axis filter counts: every candidate axis, each sampled point removed at most once
    vs = doc["visibility"]
    n = doc["normals"]["n_sampled"]
    assert len(vs["per_axis"]) == doc["orientations"]["n_candidates"]
    for a in vs["per_axis"]:
        assert a["machine"] + a["cone"] + a["travel"] + a["fixture_collision"] + a["cloud_collision"] \
            + a["visible"] == n
    assert vs["pairs_visible"] == sum(a["visible"] for a in vs["per_axis"])
    assert {t["stage"] for t in doc["timings"]} >= {"normals", "orientations", "visibility", "setups", "areas"}
    npz = np.load(out / "plan.npz")
    for key in ("sample_index", "normals", "candidate_axes", "visibility", "selected", "labels", "integrated"):
        assert key in npz.files, key
    assert npz["labels"].max() < len(doc["setups"])
    seg = read_cloud(out / "segmentation.ply")
    assert seg.points.shape[0] == doc["input"]["n_points"]
    assert (out / "preview.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in out.iterdir() if p.name.startswith(".")]   # no temporary files left
    # tool paths: a line per area in the summary, and its programs and cl_i on disk
    for st in doc["setups"]:
        assert f"area {st['id']}: roughing" in text.out and "gouge free" in text.out
        assert f"cl_{st['id']}" in npz.files
        for name in list(st["path"]["programs"].values()) + [st["path"]["moves"]]:
            assert (out / name).is_file()
    assert {"paths", "post"} <= {t["stage"] for t in doc["timings"]}
    # the verdict of the simulated machine sets the exit status and is printed
    assert code == expected_exit(doc)
    assert f"verification: {doc['verification']['status'].upper()}" in text.out


def test_schema_document_rejects_a_broken_plan(half_sphere_ply, tmp_path):
    out = tmp_path / "plan"
    main(["plan", str(half_sphere_ply), "--out", str(out), "--quiet", *HS])
    doc = json.loads((out / "plan.json").read_text())
    del doc["selection"]
    with pytest.raises(jsonschema.ValidationError):
        jsonschema.validate(doc, plan_json_schema())


def test_infeasible_exit_code_and_message(half_sphere_ply, tmp_path, capsys):
    out = tmp_path / "plan"
    rc = main(["plan", str(half_sphere_ply), "--out", str(out), "--quiet", *HS, "--set", "setups.max_setups=1"])
    assert rc == EXIT_INFEASIBLE
    assert "max_setups" in capsys.readouterr().out
    assert json.loads((out / "plan.json").read_text())["status"] == "infeasible"


@pytest.mark.parametrize("content, code", [
    (b"", "empty_cloud"),
    (b"\x00\x01\x02garbage\xff" * 50, None),
    (b"1 2 3\n4 5 6\nnan 1 2\n" + b"1 1 1\n" * 20, "non_finite"),
])
def test_bad_input_is_a_clear_error_and_writes_nothing(tmp_path, capsys, content, code):
    src = tmp_path / "scan.xyz"
    src.write_bytes(content)
    out = tmp_path / "out"
    assert main(["plan", str(src), "--out", str(out), "--quiet"]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert err.startswith("error [")
    if code:
        assert f"[{code}]" in err
    assert "Traceback" not in err
    assert not out.exists()


def test_bad_parameter_and_missing_file(half_sphere_ply, tmp_path, capsys):
    assert main(["plan", str(half_sphere_ply), "--out", str(tmp_path / "o"), "--set", "setups.coverage=2"]) == EXIT_ERROR
    assert "setups.coverage = 2" in capsys.readouterr().err
    assert main(["plan", str(tmp_path / "nope.ply"), "--out", str(tmp_path / "o")]) == EXIT_ERROR
    assert "nope.ply" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_input_normals_missing(tmp_path, capsys):
    src = tmp_path / "s.xyz"
    rng = np.random.default_rng(0)
    np.savetxt(src, rng.uniform(0, 50, size=(50, 3)))
    assert main(["plan", str(src), "--out", str(tmp_path / "o"), "--set", "normals.method=input"]) == EXIT_ERROR
    assert "missing_normals" in capsys.readouterr().err


def test_schema_and_profiles_commands(capsys):
    assert main(["schema", "plan"]) == EXIT_OK
    assert json.loads(capsys.readouterr().out)["title"] == "scanmill plan"
    assert main(["schema", "config"]) == EXIT_OK
    assert "setups" in json.loads(capsys.readouterr().out)["properties"]
    assert main(["profiles"]) == EXIT_OK
    assert "compact_trunnion_bc" in capsys.readouterr().out


def test_plan_with_a_mesh_fixture_next_to_the_config(half_sphere_ply, tmp_path, capsys):
    import open3d as o3d
    box = o3d.geometry.TriangleMesh.create_box(18.0, 20.0, 25.0)
    box.translate((52.0, -10.0, 0.0))            # a clamp beside the half sphere's rim
    cfg_dir = tmp_path / "job"
    cfg_dir.mkdir()
    o3d.io.write_triangle_mesh(str(cfg_dir / "clamp.stl"), box.compute_triangle_normals())
    cfg = {"fixtures": {"items": [{"type": "mesh", "name": "clamp", "path": "clamp.stl"}]}}
    (cfg_dir / "config.json").write_text(json.dumps(cfg))
    out = tmp_path / "plan"
    code = main(["plan", str(half_sphere_ply), "--config", str(cfg_dir / "config.json"), "--out", str(out), *HS])
    doc = json.loads((out / "plan.json").read_text())
    assert code == expected_exit(doc)
    assert "clamp" not in " ".join(doc["verification"]["notes"])      # the clamp was simulated as a solid
    assert doc["visibility"]["removed_total"]["fixture_collision"] > 0
    # a missing mesh is a clear error, and nothing is written
    cfg["fixtures"]["items"][0]["path"] = "nope.stl"
    (cfg_dir / "config.json").write_text(json.dumps(cfg))
    out2 = tmp_path / "plan2"
    capsys.readouterr()
    assert main(["plan", str(half_sphere_ply), "--config", str(cfg_dir / "config.json"), "--out", str(out2),
                 *HS]) == EXIT_ERROR
    assert "nope.stl" in capsys.readouterr().err
    assert not out2.exists()
