"""Guardrail standards as YAML profiles: the shipped ones load, a user's file loads, and every
malformed profile raises StandardError naming what is wrong."""

from __future__ import annotations

import math

import pytest
import yaml

from guardrail_core.errors import GuardrailError, StandardError
from guardrail_core.reconstruct.condition import load_standard, shipped_standards
from guardrail_core.reconstruct.condition.standards import STANDARDS_DIR


def test_the_shipped_standards_all_load_with_their_sources():
    names = shipped_standards()
    assert {"mgs", "g4-1s", "uk-tcb"} <= set(names)
    for name in names:
        s = load_standard(name)
        assert s.name == name
        assert s.source and s.notes
        assert s.rail_top_min_m <= s.rail_top_nominal_m <= s.rail_top_max_m
        assert s.post_spacing_m > 0


def test_the_mgs_profile_holds_the_published_figures():
    mgs = load_standard("mgs")
    assert mgs.rail_top_nominal_m == pytest.approx(0.787)  # 31 in
    assert mgs.post_spacing_m == pytest.approx(1.905)  # 6 ft 3 in
    assert mgs.rail_top_in_range(0.787) and not mgs.rail_top_in_range(0.747)
    g4 = load_standard("g4-1s")
    assert g4.rail_top_min_m == pytest.approx(27.75 * 0.0254, abs=5e-4)
    assert not load_standard("uk-tcb").verified  # its heights rest on no source that was read


def _profile(**changes):
    data = yaml.safe_load((STANDARDS_DIR / "mgs.yaml").read_text())
    data.update(changes)
    return data


def _write(tmp_path, data, name="mine.yaml"):
    path = tmp_path / name
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    return path


def test_a_users_profile_loads_from_its_path(tmp_path):
    path = _write(tmp_path, _profile(name="county", rail_top_nominal_m=0.79, max_post_lean_deg=4))
    s = load_standard(path)
    assert (s.name, s.rail_top_nominal_m, s.max_post_lean_deg) == ("county", 0.79, 4.0)
    assert load_standard(str(path)).name == "county"


def test_an_unknown_name_or_path_raises_naming_the_shipped_ones(tmp_path):
    with pytest.raises(StandardError, match="unknown standard 'nope'.*mgs"):
        load_standard("nope")
    with pytest.raises(StandardError, match="no standard profile file"):
        load_standard(tmp_path / "absent.yaml")
    assert issubclass(StandardError, GuardrailError)


@pytest.mark.parametrize(
    ("data", "message"),
    [
        ("rail_top_min_m: [unclosed", "not valid YAML"),
        ("- a list\n- not a mapping\n", "expected a mapping"),
        (
            {k: v for k, v in _profile().items() if k != "post_spacing_m"},
            "missing key.*post_spacing_m",
        ),
        (_profile(colour="red"), "unknown key.*colour"),
        (_profile(rail_top_min_m=0.9), "rail_top_min_m .* exceeds rail_top_max_m"),
        (_profile(rail_top_nominal_m=0.7), "rail_top_nominal_m .* must lie within"),
        (_profile(post_spacing_m=math.inf), "post_spacing_m must be a finite number"),
        (_profile(rail_top_max_m=float("nan")), "rail_top_max_m must be a finite number"),
        (_profile(post_spacing_m="six feet"), "post_spacing_m must be a number"),
        (_profile(max_post_lean_deg=-1), "max_post_lean_deg must lie within"),
        (_profile(verified="yes please"), "verified must be true or false"),
        (_profile(source=""), "source must be non-empty text"),
    ],
)
def test_a_malformed_profile_raises_naming_the_key(tmp_path, data, message):
    path = _write(tmp_path, data)
    with pytest.raises(StandardError, match=message):
        load_standard(path)
