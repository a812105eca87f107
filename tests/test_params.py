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
    d = c.to_json_dict()
    assert d["visibility"]["global"] is True and d["visibility"]["travel"] is True
    assert d["visibility"]["obstacles"] == "all"
    assert d["fixtures"] == {"placement_mm": None, "fixture_height_mm": 50.0, "table": True, "items": [],
                             "placement": "as_scanned"}
    assert (c.tool.flute_length_mm, c.tool.stickout_mm) == (12.0, 30.0)
    # the default assembly: cutter + shank to the holder face, a collet nut and a flange
    a = c.tool.assembly()
    assert a.radius_mm == 3.0 and a.gauge_length_mm == 30.0 + 45.0 + 40.0
    assert [s.part for s in a.segments] == ["cutter", "shank", "holder", "holder"]


@pytest.mark.parametrize("doc, needle", [
    ({"setups": {"coverage": 1.5}}, "setups.coverage = 1.5"),
    ({"setups": {"max_setups": 0}}, "setups.max_setups = 0"),
    ({"visibility": {"cone_deg": [60, 10]}}, "visibility.cone_deg"),
    ({"visibility": {"cone_deg": [10, 95]}}, "v2 <= 90"),
    ({"normals": {"sphere_diameter_mm": -1}}, "normals.sphere_diameter_mm = -1"),
    ({"normals": {"directions": [[0, 0, 0]]}}, "zero vector"),
    ({"normals": {"method": "pca"}}, "normals.method"),
    ({"setups": {"covrage": 0.9}}, "setups.covrage: unknown parameter"),
    ({"visibility": {"obstacles": "some"}}, "visibility.obstacles"),
    ({"tool": {"stickout_mm": 5}}, "at least tool.flute_length_mm"),
    ({"tool": {"flute_length_mm": 2}}, "at least the ball radius"),
    ({"tool": {"holder": [{"diameter_mm": 20, "length_mm": None}, {"diameter_mm": 30, "length_mm": 5}]}},
     "only the last holder element"),
    ({"tool": {"holder": [{"diameter_mm": -1, "length_mm": 5}]}}, "tool.holder.0.diameter_mm"),
    ({"fixtures": {"items": [{"type": "box", "min_mm": [0, 0, 0], "max_mm": [0, 1, 1]}]}}, "must be below"),
    ({"fixtures": {"items": [{"type": "cone"}]}}, "fixtures.items.0"),
    ({"fixtures": {"items": [{"type": "cylinder", "base_mm": [0, 0, 0], "radius_mm": 0, "height_mm": 1}]}},
     "radius_mm"),
    ({"fixtures": {"items": [{"type": "cylinder", "base_mm": [0, 0, 0], "axis": [0, 0, 0], "radius_mm": 1,
                              "height_mm": 1}]}}, "zero vector"),
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


def test_an_unknown_parameter_names_the_nearest_known_one_in_its_group():
    """A misspelt name gets "did you mean" with the name as it would be written (group path, public
    alias); a group misspelt gets the group; a name near nothing gets no guess."""
    cases = {
        "tool.diamter_mm=6": "tool.diamter_mm: unknown parameter (did you mean tool.diameter_mm?)",
        "paths.finishing.scalop_mm=0.01": "(did you mean paths.finishing.scallop_mm?)",
        "setup.coverage=0.9": "setup: unknown parameter (did you mean setups?)",
        "visibility.globl=true": "(did you mean visibility.global?)",
    }
    for item, expect in cases.items():
        with pytest.raises(ParameterError) as e:
            parse_config(apply_overrides({}, [item]))
        assert expect in str(e.value), (item, str(e.value))
    with pytest.raises(ParameterError) as e:
        parse_config(apply_overrides({}, ["tool.zzz=1"]))
    assert "tool.zzz: unknown parameter" in str(e.value) and "did you mean" not in str(e.value)


def test_a_percentage_where_a_fraction_is_asked_says_so():
    with pytest.raises(ParameterError) as e:
        parse_config(apply_overrides({}, ["setups.coverage=95"]))
    assert "setups.coverage = 95" in str(e.value) and "(a fraction: 95 % is 0.95)" in str(e.value)
    with pytest.raises(ParameterError) as e:           # beyond 100: no percentage reading of it
        parse_config(apply_overrides({}, ["setups.coverage=950"]))
    assert "a fraction" not in str(e.value)
