"""Guardrail standards as YAML profiles: the rail-top range, post spacing and tolerances a run
is checked against.

A profile is a YAML mapping of these keys (lengths in metres, angles in degrees)::

    name: mgs                      # how it is asked for
    title: Midwest Guardrail System (MASH TL-3), US
    source: where each figure comes from (citations)
    notes: what could not be verified, in words
    verified: true                 # false: a figure rests on no primary source that was read
    rail_top_nominal_m: 0.787      # rail top above the road
    rail_top_min_m: 0.762
    rail_top_max_m: 0.813
    rail_height_tolerance_m: 0.0254   # the construction tolerance about the nominal height
    post_spacing_m: 1.905
    post_spacing_tolerance_m: null  # null: the standard states none (ConditionParams' fallback)
    max_post_lean_deg: null        # likewise
    dent_depth_tolerance_m: null   # likewise

Shipped profiles lie in ``standards/`` beside this module (:func:`shipped_standards`); users
add their own by passing a YAML file's path to :func:`load_standard`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from guardrail_core.errors import StandardError

#: The folder of the shipped profiles (package data).
STANDARDS_DIR = Path(__file__).resolve().parent / "standards"

_TEXT_KEYS = ("name", "title", "source", "notes")
_NUMBER_KEYS = (
    "rail_top_nominal_m",
    "rail_top_min_m",
    "rail_top_max_m",
    "rail_height_tolerance_m",
    "post_spacing_m",
)
#: Numbers a standard may leave open (null): the checks then use ConditionParams' fallbacks.
_OPTIONAL_NUMBER_KEYS = ("post_spacing_tolerance_m", "max_post_lean_deg", "dent_depth_tolerance_m")
_KEYS = (*_TEXT_KEYS, "verified", *_NUMBER_KEYS, *_OPTIONAL_NUMBER_KEYS)


@dataclass(frozen=True)
class Standard:
    """One guardrail standard (see the module docstring for the YAML keys).

    Attributes
    ----------
    name, title : str
    source : str, the citations of the figures
    notes : str, what could not be verified
    verified : bool, every figure was read in a source that states it
    rail_top_nominal_m, rail_top_min_m, rail_top_max_m : float, metres above the road;
        min <= nominal <= max
    rail_height_tolerance_m : float, metres, >= 0: the construction tolerance about the nominal
    post_spacing_m : float, metres, > 0
    post_spacing_tolerance_m : float, metres, >= 0, or None (not stated)
    max_post_lean_deg : float in [0, 90) degrees from vertical, or None (not stated)
    dent_depth_tolerance_m : float, metres, >= 0, or None (not stated)
    """

    name: str
    title: str
    source: str
    notes: str
    verified: bool
    rail_top_nominal_m: float
    rail_top_min_m: float
    rail_top_max_m: float
    rail_height_tolerance_m: float
    post_spacing_m: float
    post_spacing_tolerance_m: float | None
    max_post_lean_deg: float | None
    dent_depth_tolerance_m: float | None

    def rail_top_in_range(self, height_m: float) -> bool:
        """Whether a rail-top height (metres above the road) lies in [min, max]."""
        return self.rail_top_min_m <= height_m <= self.rail_top_max_m


def shipped_standards() -> list[str]:
    """The names of the shipped profiles, sorted."""
    return sorted(p.stem for p in STANDARDS_DIR.glob("*.yaml"))


def load_standard(name_or_path: str | Path) -> Standard:
    """A shipped standard by name (``"mgs"``), or a user's profile by its YAML file's path.

    Raises
    ------
    StandardError
        An unknown name (naming the shipped ones), a file that cannot be read or is no YAML
        mapping, a missing or unknown key (named), a value of the wrong type, a number that is
        not finite or out of range, a minimum above its maximum.
    """
    path = _profile_path(name_or_path)
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise StandardError(f"{path}: cannot read the standard ({exc})") from exc
    except yaml.YAMLError as exc:
        raise StandardError(f"{path}: not valid YAML ({exc})") from exc
    return standard_from_mapping(data, where=str(path))


def standard_from_mapping(data: Any, where: str = "standard") -> Standard:
    """A :class:`Standard` from a parsed profile (see :func:`load_standard` for the errors)."""
    if not isinstance(data, dict):
        raise StandardError(f"{where}: expected a mapping of keys, got {type(data).__name__}")
    missing = [k for k in _KEYS if k not in data]
    if missing:
        raise StandardError(f"{where}: missing key(s) {', '.join(missing)}")
    unknown = sorted(str(k) for k in data if k not in _KEYS)
    if unknown:
        raise StandardError(f"{where}: unknown key(s) {', '.join(unknown)}")
    values: dict[str, Any] = {}
    for key in _TEXT_KEYS:
        if not isinstance(data[key], str) or not data[key].strip():
            raise StandardError(f"{where}: {key} must be non-empty text, got {data[key]!r}")
        values[key] = data[key].strip()
    if not isinstance(data["verified"], bool):
        raise StandardError(f"{where}: verified must be true or false, got {data['verified']!r}")
    values["verified"] = data["verified"]
    for key in _NUMBER_KEYS:
        values[key] = _number(where, key, data[key])
    for key in _OPTIONAL_NUMBER_KEYS:
        values[key] = None if data[key] is None else _number(where, key, data[key])
    standard = Standard(**values)
    _check_ranges(where, standard)
    return standard


def _profile_path(name_or_path: str | Path) -> Path:
    """The YAML file of a shipped name or a user's path (see :func:`load_standard`)."""
    text = str(name_or_path)
    if isinstance(name_or_path, Path) or text.endswith((".yaml", ".yml")) or "/" in text:
        path = Path(name_or_path)
        if not path.is_file():
            raise StandardError(f"no standard profile file {path}")
        return path
    path = STANDARDS_DIR / f"{text}.yaml"
    if not path.is_file():
        raise StandardError(
            f"unknown standard {text!r} (shipped: {', '.join(shipped_standards())}; or give a "
            "YAML file's path)"
        )
    return path


def _number(where: str, key: str, value: Any) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise StandardError(f"{where}: {key} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise StandardError(f"{where}: {key} must be a finite number, got {value!r}")
    return float(value)


def _check_ranges(where: str, s: Standard) -> None:
    """Raise :class:`StandardError` for a value out of range or a minimum above its maximum."""
    if s.rail_top_min_m > s.rail_top_max_m:
        raise StandardError(
            f"{where}: rail_top_min_m ({s.rail_top_min_m} m) exceeds rail_top_max_m "
            f"({s.rail_top_max_m} m)"
        )
    if not s.rail_top_min_m <= s.rail_top_nominal_m <= s.rail_top_max_m:
        raise StandardError(
            f"{where}: rail_top_nominal_m ({s.rail_top_nominal_m} m) must lie within "
            f"rail_top_min_m .. rail_top_max_m ({s.rail_top_min_m} .. {s.rail_top_max_m} m)"
        )
    checks = [
        ("rail_top_min_m", s.rail_top_min_m, 0.0, 5.0),
        ("rail_top_max_m", s.rail_top_max_m, 0.0, 5.0),
        ("rail_height_tolerance_m", s.rail_height_tolerance_m, 0.0, 1.0),
        ("post_spacing_m", s.post_spacing_m, 1e-3, 50.0),
    ]
    if s.post_spacing_tolerance_m is not None:
        checks.append(("post_spacing_tolerance_m", s.post_spacing_tolerance_m, 0.0, 50.0))
    if s.max_post_lean_deg is not None:
        checks.append(("max_post_lean_deg", s.max_post_lean_deg, 0.0, 89.0))
    if s.dent_depth_tolerance_m is not None:
        checks.append(("dent_depth_tolerance_m", s.dent_depth_tolerance_m, 0.0, 1.0))
    for key, value, low, high in checks:
        if not low <= value <= high:
            raise StandardError(f"{where}: {key} must lie within [{low:g}, {high:g}], got {value}")
