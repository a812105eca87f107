"""The configuration schema: defaults, ranges, clear messages naming the parameter."""

import pytest

from planning.errors import ParameterError
from schemas.params import PAPER_DIRECTIONS, PlanConfig, apply_overrides, parse_config


def test_defaults_follow_design():
    c = parse_config({})
    assert c.normals.method == "sphere_throwing"
    assert c.normals.sphere_diameter_mm == 7.0
    assert [tuple(d) for d in c.normals.directions] == [tuple(d) for d in PAPER_DIRECTIONS]
    assert (c.orientations.phi_step_deg, c.orientations.theta_step_deg) == (10, 30)
    assert tuple(c.visibility.cone_deg) == (10, 80)
    assert (c.setups.coverage, c.setups.max_setups, c.setups.min_points) == (0.95, 5, 1)
    assert c.to_json_dict()["visibility"]["global"] is False


@pytest.mark.parametrize("doc, needle", [
    ({"setups": {"coverage": 1.5}}, "setups.coverage = 1.5"),
    ({"setups": {"max_setups": 0}}, "setups.max_setups = 0"),
    ({"visibility": {"cone_deg": [60, 10]}}, "visibility.cone_deg"),
    ({"visibility": {"cone_deg": [10, 95]}}, "v2 <= 90"),
    ({"normals": {"sphere_diameter_mm": -1}}, "normals.sphere_diameter_mm = -1"),
    ({"normals": {"directions": [[0, 0, 0]]}}, "zero vector"),
    ({"normals": {"method": "pca"}}, "normals.method"),
    ({"setups": {"covrage": 0.9}}, "setups.covrage: unknown parameter"),
    ({"visibility": {"global": True}}, "not available"),
    ({"setups": {"functional_zones": [{"type": "box", "min_mm": [1, 1, 1], "max_mm": [0, 2, 2]}]}}, "must not exceed"),
])
def test_bad_parameters_name_the_parameter(doc, needle):
    with pytest.raises(ParameterError) as exc:
        parse_config(doc)
    assert needle in str(exc.value)
    assert exc.value.code == "invalid_parameter"


def test_not_an_object():
    with pytest.raises(ParameterError, match="JSON object"):
        parse_config([1, 2])


def test_overrides_parse_json_values_and_nest():
    doc = apply_overrides({"setups": {"coverage": 0.9}}, [
        "setups.max_setups=2", "visibility.cone_deg=[10,60]", "machine.profile=fork_head_ac",
        "normals.grid_spacing_mm=null"])
    c = parse_config(doc)
    assert c.setups.max_setups == 2 and c.setups.coverage == 0.9
    assert tuple(c.visibility.cone_deg) == (10, 60)
    assert c.machine.profile == "fork_head_ac"
    assert c.normals.grid_spacing_mm is None


@pytest.mark.parametrize("bad", ["nopath", "=3", "setups.coverage.x=1"])
def test_bad_overrides(bad):
    with pytest.raises(ParameterError):
        parse_config(apply_overrides({"setups": {"coverage": 0.9}}, [bad]))


def test_zones_discriminated():
    c = parse_config({"setups": {"functional_zones": [
        {"type": "indices", "indices": [1, 2]},
        {"type": "sphere", "center_mm": [0, 0, 0], "radius_mm": 3},
        {"type": "box", "min_mm": [0, 0, 0], "max_mm": [1, 1, 1]}]}})
    assert [z.type for z in c.setups.functional_zones] == ["indices", "sphere", "box"]


def test_round_trip_through_json():
    c = parse_config({"setups": {"coverage": 0.8}, "visibility": {"cone_deg": [5, 70]}})
    again = PlanConfig.model_validate(c.to_json_dict())
    assert again == c
