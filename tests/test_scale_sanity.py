"""Unit and scale sanity (issue 18): a scan in metres read as millimetres is refused with the unit hint,
in the library, the CLI (exit 2) and the service (422 at submission); accept_small_part overrides."""

from __future__ import annotations

import json
import os
import warnings

import numpy as np
import pytest

from planning.errors import InputError
from planning.inputs.samples import half_sphere
from planning.inputs.scale import (
    MIN_NORMAL_SHARE,
    check_normal_share,
    check_part_size,
    unit_hints,
)
from planning.report.files import write_ply
from scanmill.cli import EXIT_ERROR, main

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from starlette.testclient import TestClient

# the half sphere (100 mm across) exported in metres: 0.1 x 0.1 x 0.05 "mm" when read as mm
METRES = half_sphere().points / 1000.0
LIGHT = {"tool": {"diameter_mm": 10.0}, "visibility": {"cone_deg": [10, 80]},
         "setups": {"coverage": 0.95, "max_setups": 2},
         "paths": {"finishing": {"enabled": False}, "roughing": {"enabled": False}},
         "simulate": {"enabled": False}}


def _size_check(points, units="mm", accept=False, tool=6.0):
    check_part_size(points, units=units, tool_diameter_mm=tool, min_tool_diameters=2.0, max_extent_mm=5000.0,
                    accept_small_part=accept)


def test_metre_cloud_read_as_mm_is_refused_with_the_unit_hint():
    with pytest.raises(InputError) as e:
        _size_check(METRES)
    assert e.value.code == "part_too_small" and e.value.status == 422
    msg = e.value.message
    assert "input.units=m" in msg and "0.0999 x 0.0999 x 0.0487 mm" in msg           # the extent as read
    assert "99.9 x 99.9 x 48.7 mm" in msg                                  # what it would be in metres
    assert "accept_small_part" in msg


def test_the_hint_names_only_units_that_give_a_plausible_size():
    ext = np.array([2.0, 1.0, 1.0])                   # a 50 mm part exported in inches, read as mm
    hints = unit_hints(ext, "mm", 12.0, 5000.0)
    assert any(h.startswith("input.units=in") for h in hints)
    assert any(h.startswith("input.units=m ") for h in hints)             # 2 m is also plausible
    assert unit_hints(np.array([0.001, 0.001, 0.001]), "mm", 12.0, 5000.0) == []   # 1 mm even in metres


def test_part_of_a_few_tool_diameters_passes_and_override_works():
    pts = np.random.default_rng(0).uniform(0, 13.0, (200, 3))
    _size_check(pts)                                   # 13 mm >= 2 x 6 mm
    with pytest.raises(InputError):
        _size_check(pts, tool=8.0)                     # 13 mm < 2 x 8 mm
    _size_check(METRES, accept=True)


def test_almost_no_normals_is_refused_unless_accepted():
    pts = np.random.default_rng(1).uniform(0, 100.0, (10_000, 3))
    kw = dict(units="mm", sphere_diameter_mm=7.0, tool_diameter_mm=6.0, max_extent_mm=5000.0)
    check_normal_share(pts, int(MIN_NORMAL_SHARE * 10_000), accept_small_part=False, **kw)
    with pytest.raises(InputError) as e:
        check_normal_share(pts, 3, accept_small_part=False, **kw)
    assert e.value.code == "too_few_normals" and "3 of 10,000" in e.value.message
    check_normal_share(pts, 3, accept_small_part=True, **kw)


def test_cli_refuses_the_metre_cloud_with_exit_2_and_writes_nothing(tmp_path, capsys):
    src = tmp_path / "part_in_metres.ply"
    write_ply(src, METRES)
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps(LIGHT))
    out = tmp_path / "out"
    assert main(["plan", str(src), "--config", str(cfg), "--out", str(out)]) == EXIT_ERROR
    err = capsys.readouterr().err
    assert "part_too_small" in err and "input.units=m" in err
    assert not out.exists() or not any(out.iterdir())


def test_cli_plans_the_same_file_with_input_units_m(tmp_path, capsys):
    src = tmp_path / "part_in_metres.ply"
    write_ply(src, METRES)
    cfg = tmp_path / "c.json"
    cfg.write_text(json.dumps({**LIGHT, "input": {"units": "m"}}))
    assert main(["plan", str(src), "--config", str(cfg), "--out", str(tmp_path / "out")]) == 0
    plan = json.loads((tmp_path / "out" / "plan.json").read_text())
    assert plan["status"] == "planned" and plan["input"]["bbox_max_mm"][0] > 40


@pytest.fixture
def app_client(tmp_path, monkeypatch):
    from service.app import create_app
    from service.settings import load_settings
    from service.workers import PINNED_VARS
    for var in PINNED_VARS:
        monkeypatch.setenv(var, os.environ.get(var, "1"))
    s = load_settings(env={}, data_dir=str(tmp_path / "data"), workers=1)
    with TestClient(create_app(s), client=("127.0.0.1", 50000), raise_server_exceptions=False) as c:
        yield c, tmp_path / "data"


def _post(client, path, params):
    with open(path, "rb") as fh:
        return client.post("/jobs", files={"cloud": (path.name, fh, "application/octet-stream")},
                           data={"parameters": json.dumps(params)})


def test_service_answers_422_with_the_unit_hint_and_keeps_no_job(app_client, tmp_path):
    client, _ = app_client
    src = tmp_path / "part_in_metres.ply"
    write_ply(src, METRES)
    r = _post(client, src, LIGHT)
    assert r.status_code == 422, r.text
    body = r.json()
    assert r.headers["content-type"].startswith("application/problem+json")
    assert body["code"] == "part_too_small" and "input.units=m" in body["detail"]
    assert client.get("/jobs").json()["items"] == []
    # the override is accepted at submission
    r = _post(client, src, {**LIGHT, "input": {"accept_small_part": True}})
    assert r.status_code == 202, r.text
