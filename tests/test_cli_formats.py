"""The CLI on every input format (issue 18): damaged files of each new format stop with exit 2, the error
code and nothing written; a mesh (STL) is planned end to end with the ball on its triangles, its
programs verified on the simulated machine; a relief image plans."""

from __future__ import annotations

import json

import numpy as np
import pytest
from mesh_files import cube_mesh, image_bytes, las_bytes, stl_binary

from scanmill.cli import EXIT_ERROR, EXIT_OK, main

BROKEN = {
    "short.stl": lambda: stl_binary(*cube_mesh())[:-20],                       # 12 triangles claimed, fewer there
    "bad.obj": lambda: b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n",          # vertex 9 does not exist
    "cut.las": lambda: las_bytes(np.random.default_rng(0).uniform(0, 50, (500, 3)))[:400],
    "junk.e57": lambda: b"ASTM-E57" + b"\0" * 200,
    "notanimage.png": lambda: b"\x89PNG\r\n\x1a\n" + b"garbage" * 10,
}


@pytest.mark.parametrize("name", sorted(BROKEN))
def test_damaged_files_exit_2_with_a_code_and_write_nothing(tmp_path, capsys, name):
    src = tmp_path / name
    src.write_bytes(BROKEN[name]())
    out = tmp_path / "out"
    assert main(["plan", str(src), "--out", str(out), "--quiet"]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert "error [" in err and any(c in err for c in ("truncated_file", "unreadable_file", "invalid_input"))
    assert src.name in err                          # the message names the file
    assert not out.exists() or not any(out.iterdir())


LIGHT_MESH = {
    "tool": {"diameter_mm": 6.0}, "normals": {"method": "facets"}, "visibility": {"cone_deg": [0, 60]},
    "setups": {"coverage": 0.15, "max_setups": 1},
    "paths": {"roughing": {"enabled": False}, "finishing": {"scallop_mm": 0.05}},
    "input": {"mesh_sample_mm": 1.0},
}


def test_an_stl_mesh_plans_on_its_triangles_and_its_programs_verify(tmp_path, capsys):
    src = tmp_path / "block.stl"
    v, f = cube_mesh(40.0)
    src.write_bytes(stl_binary(v, f))
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps(LIGHT_MESH))
    out = tmp_path / "out"
    code = main(["plan", str(src), "--config", str(cfg), "--out", str(out), "--quiet"])
    plan = json.loads((out / "plan.json").read_text())
    assert code == EXIT_OK, capsys.readouterr()
    assert plan["input"]["format"] == "stl-binary" and plan["input"]["n_points"] == 8
    assert plan["input"]["n_faces"] == 12 and plan["input"]["n_points_planned"] > 5000
    assert plan["normals"]["method"] == "facets"
    assert plan["paths_surface"]["kind"] == "input_mesh" and plan["paths_surface"]["n_triangles"] == 12
    assert plan["verification"]["status"] == "passed"
    assert any(p.name.endswith(".linuxcnc.nc") for p in out.iterdir())


def test_a_relief_image_plans(tmp_path):
    img = np.zeros((60, 80), dtype=np.uint8)
    yy, xx = np.mgrid[0:60, 0:80]
    img[:] = (127 + 120 * np.sin(xx / 9.0) * np.cos(yy / 11.0)).astype(np.uint8)
    src = tmp_path / "relief.png"
    src.write_bytes(image_bytes(img))
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({"input": {"relief": {"size_mm": 60, "z_min_mm": 0, "z_max_mm": 5}},
                               "tool": {"diameter_mm": 6.0}, "visibility": {"cone_deg": [0, 60]},
                               "setups": {"coverage": 0.5, "max_setups": 1},
                               "paths": {"finishing": {"enabled": False}, "roughing": {"enabled": False}},
                               "simulate": {"enabled": False}}))
    out = tmp_path / "out"
    assert main(["plan", str(src), "--config", str(cfg), "--out", str(out), "--quiet"]) == EXIT_OK
    plan = json.loads((out / "plan.json").read_text())
    assert plan["input"]["format"] == "image-png" and plan["input"]["n_faces"] > 0
    assert plan["status"] == "planned"
