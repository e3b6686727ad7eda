"""One parameters style: every stage's params derive from StageParams and refuse, by name, a value
just outside each field's range; the reconstruction's parameters refuse names of before 0.2.0 and
read --set."""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import math
import pkgutil
import typing
from functools import cache
from typing import Any

import pytest

import guardrail_core
from guardrail_core.params import ParameterError, ParamSpec, StageParams, has_unit_suffix
from guardrail_core.reconstruct.beams import BeamParams
from guardrail_core.reconstruct.inventory import InventoryParams
from guardrail_core.reconstruct.pipeline import ReconstructionParams
from guardrail_core.reconstruct.poles import PoleParams

#: Units that are also name suffixes (``_m``, ``_deg``, ...): a field in one carries its suffix.
SUFFIX_UNITS = {"m", "deg", "s", "px", "mm", "hz"}


@cache
def library_modules() -> tuple[Any, ...]:
    """Every module of guardrail_core, imported (``__main__`` modules run a command: skipped)."""
    names = [
        m.name
        for m in pkgutil.walk_packages(guardrail_core.__path__, "guardrail_core.")
        if not m.name.endswith("__main__")
    ]
    return tuple(importlib.import_module(name) for name in names)


@cache
def params_classes() -> tuple[type, ...]:
    """Every dataclass named ``*Params`` defined in guardrail_core."""
    found = {
        cls
        for module in library_modules()
        for name, cls in inspect.getmembers(module, inspect.isclass)
        if name.endswith("Params")
        and cls.__module__ == module.__name__
        and dataclasses.is_dataclass(cls)
    }
    return tuple(sorted(found, key=lambda c: f"{c.__module__}.{c.__qualname__}"))


def stage_params_classes() -> list[type[StageParams]]:
    return [c for c in params_classes() if issubclass(c, StageParams)]


def test_every_params_class_is_a_stage_params() -> None:
    classes = params_classes()
    assert {"PoleParams", "BeamParams", "ReconstructionParams"} <= {c.__name__ for c in classes}
    others = [f"{c.__module__}.{c.__qualname__}" for c in classes if not issubclass(c, StageParams)]
    assert others == []


def reconstruction_classes() -> list[type[StageParams]]:
    """The parameters of the reconstruction: its stages, itself and the inventory's."""
    stages = list(ReconstructionParams.stage_classes().values())
    return [*stages, ReconstructionParams, InventoryParams]


def test_every_field_is_a_param_or_a_stage() -> None:
    """Each field states its unit and range (``param``), or is a whole stage's parameters."""
    undeclared = []
    for cls in reconstruction_classes():
        for f in dataclasses.fields(cls):
            if "unit" in f.metadata:
                continue
            if not isinstance(getattr(cls(), f.name), StageParams):
                undeclared.append(f"{cls.__name__}.{f.name}")
    assert undeclared == []


def test_units_and_name_suffixes_agree() -> None:
    """A length is ``_m`` and says "m", an angle ``_deg`` and "deg"; counts and shares neither."""
    wrong = []
    for cls in stage_params_classes():
        for spec in cls.specs():
            unit = spec.unit.lower()
            if unit in SUFFIX_UNITS and not spec.name.endswith(f"_{unit}"):
                wrong.append(f"{cls.__name__}.{spec.name} is in {spec.unit} without its suffix")
            if has_unit_suffix(spec.name) and not spec.unit:
                wrong.append(f"{cls.__name__}.{spec.name} has a unit suffix and no unit")
    assert wrong == []


def _outside(spec: ParamSpec, kind: type) -> list[Any]:
    """Values just outside the range of ``spec``: the nearest number past each bound (for an
    integer, the next integer), and a word that is not one of ``choices``."""
    integer = kind is int
    values: list[Any] = []
    if spec.ge is not None:
        values.append(math.ceil(spec.ge) - 1 if integer else math.nextafter(spec.ge, -math.inf))
    if spec.gt is not None:
        values.append(math.floor(spec.gt) if integer else float(spec.gt))
    if spec.le is not None:
        values.append(math.floor(spec.le) + 1 if integer else math.nextafter(spec.le, math.inf))
    if spec.lt is not None:
        values.append(math.ceil(spec.lt) if integer else float(spec.lt))
    if spec.choices is not None:
        values.append("not one of the choices")
    return values


def test_a_value_just_outside_every_range_is_refused_by_name() -> None:
    checked, accepted, unnamed = 0, [], []
    for cls in stage_params_classes():
        hints = typing.get_type_hints(cls)
        for spec in cls.specs():
            for value in _outside(spec, hints[spec.name]):
                checked += 1
                where = f"{cls.__name__}.{spec.name}"
                try:
                    cls(**{spec.name: value})
                except ParameterError as exc:
                    if where not in str(exc):
                        unnamed.append(f"{where}={value!r}: {exc}")
                else:
                    accepted.append(f"{where}={value!r}")
    assert checked > 100  # every reconstruction stage's ranges at least
    assert accepted == []
    assert unnamed == []


def test_an_integer_beyond_2_to_the_53_is_refused_by_every_integer_field() -> None:
    """1e308 is an integral float: it once became a 309-digit count and was saved. Beyond 2^53
    a JSON number (where parameters are saved) no longer holds every integer."""
    checked = 0
    for cls in stage_params_classes():
        hints = typing.get_type_hints(cls)
        for spec in cls.specs():
            if hints[spec.name] is not int:
                continue
            for value in (1e308, 2**63, 2**53 + 1, -(2**53) - 1):
                checked += 1
                with pytest.raises(ParameterError, match=f"{cls.__name__}.{spec.name}"):
                    cls(**{spec.name: value})
    assert checked > 30


def test_defaults_round_trip_through_json() -> None:
    for cls in reconstruction_classes():
        params = cls()
        assert cls.from_json(params.to_json()) == params


def test_pole_radii_must_be_in_order() -> None:
    with pytest.raises(ParameterError, match=r"PoleParams: min_radius_m .* max_radius_m"):
        PoleParams(min_radius_m=0.5, max_radius_m=0.01)
    with pytest.raises(ParameterError, match=r"PoleParams: min_height_m .* max_height_m"):
        PoleParams(min_height_m=2.0, max_height_m=1.0)


@pytest.mark.parametrize(
    ("setting", "message"),
    [
        ("poles.min_radius_m=-1", r"poles: PoleParams\.min_radius_m must lie within \(0, 0\.5\] m"),
        ("poles.min_radius_m=0.5", r"poles: PoleParams: min_radius_m \(0\.5 m\) must not exceed"),
        ("pipes.slice_interval_m=abc", r"pipes\.slice_interval_m must be a number, got 'abc'"),
        ("runs.min_points=many", r"runs\.min_points must be an integer"),
        ("runs.min_points=2.5", r"RunParams\.min_points must be an integer, got 2\.5"),
        ("sweep.caps=yes please", r"sweep\.caps must be true or false"),
        ("sweep.rail_color=[1, 2]", r"SweepParams\.rail_color must be 4 finite integers"),
        ("poles.no_such_name=1", r"unknown reconstruction parameter poles\.no_such_name"),
        ("pole.min_radius_m=0.1", r"unknown reconstruction stage 'pole'"),
        ("poles.min_radius_m", r"expected STAGE\.NAME=VALUE"),
    ],
)
def test_bad_settings_are_refused_by_name(setting: str, message: str) -> None:
    with pytest.raises(ParameterError, match=message):
        ReconstructionParams().with_settings([setting])


def test_settings_are_read_as_their_fields_types() -> None:
    params = ReconstructionParams().with_settings(
        [
            "poles.section_step_m=0.04",
            "runs.min_points=200",
            "register.passes=2",
            "poles.shared_radius=false",
            "sweep.pole_color=[1, 2, 3, 4]",
            # a stage is checked after all its settings: the order of a min and a max is free
            "poles.min_radius_m=0.2",
            "poles.max_radius_m=0.3",
        ]
    )
    assert params.poles.section_step_m == 0.04
    assert params.runs.min_points == 200 and isinstance(params.runs.min_points, int)
    assert params.register.passes == 2
    assert params.poles.shared_radius is False
    assert params.sweep.pole_color == (1, 2, 3, 4)
    assert (params.poles.min_radius_m, params.poles.max_radius_m) == (0.2, 0.3)
    assert ReconstructionParams.from_json(params.to_json()) == params


@pytest.mark.parametrize(
    ("stage", "old", "cls"),
    [
        ("beams", "slice_interval", "BeamParams"),
        ("sweep", "beam_thickness", "SweepParams"),
        ("pipes", "vertical_angle", "PipeParams"),
    ],
)
def test_names_of_before_0_2_0_are_unknown(stage: str, old: str, cls: str) -> None:
    # 0.2.0 is the first release: a name an unreleased version used is refused, not read.
    with pytest.raises(ParameterError, match=rf"{stage}: unknown parameter {cls}\.{old} \(known:"):
        ReconstructionParams.from_json({stage: {old: 0.02}})
    with pytest.raises(ParameterError, match=rf"unknown reconstruction parameter {stage}\.{old}"):
        ReconstructionParams().with_settings([f"{stage}.{old}=0.02"])


def test_stored_params_are_refused_by_name() -> None:
    with pytest.raises(ParameterError, match=r"unknown reconstruction stage 'pipez'"):
        ReconstructionParams.from_json({"pipez": {}})
    with pytest.raises(ParameterError, match=r"poles: unknown parameter PoleParams\.radius"):
        ReconstructionParams.from_json({"poles": {"radius": 0.1}})
    with pytest.raises(ParameterError, match=r"poles: PoleParams\.ground_k must be an integer"):
        ReconstructionParams.from_json({"poles": {"ground_k": "16"}})
    with pytest.raises(ParameterError, match="expected an object of stages"):
        ReconstructionParams.from_json([1, 2])  # type: ignore[arg-type]
    with pytest.raises(ParameterError, match="poles must be PoleParams, got BeamParams"):
        ReconstructionParams(poles=BeamParams())  # type: ignore[arg-type]


def test_every_slider_lies_within_its_parameters_range() -> None:
    sliders = [
        (cls, spec)
        for cls in stage_params_classes()
        for spec in cls.specs()
        if spec.slider is not None
    ]
    assert len(sliders) >= 5  # the review app's tuning panel
    for cls, spec in sliders:
        slider = spec.slider
        assert slider is not None and slider.low < slider.high and slider.step > 0
        default = getattr(cls(), spec.name)
        assert slider.low <= default <= slider.high, f"{cls.__name__}.{spec.name}"
        for end in (slider.low, slider.high):  # both ends are values the stage accepts
            value = int(end) if isinstance(default, int) else float(end)
            assert getattr(dataclasses.replace(cls(), **{spec.name: value}), spec.name) == value
