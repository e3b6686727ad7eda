"""One way to state a stage's parameters: each field's unit and allowed range, checked once.

Every stage has one frozen dataclass of parameters derived from :class:`StageParams`, whose
fields are declared with :func:`param`::

    @dataclass(frozen=True)
    class PoleParams(StageParams):
        section_step_m: float = param(0.05, unit="m", gt=0, le=0.5, doc="§4.1: section spacing")

Names carry their unit as a suffix (``_m`` metres, ``_deg`` degrees, ``_s`` seconds, ``_px``
pixels, ``_mm`` millimetres, ``_hz`` per second); counts, ratios and switches have none. The
unit is also in the field's metadata, where ``--help`` texts, the docs and the review app's
sliders read it. Construction checks every field (type, finiteness, range, choices) and then the
class's own :meth:`StageParams.check_relations`, and raises :class:`ParameterError` naming the
class, the field, what is allowed and what came.
"""

from __future__ import annotations

import dataclasses
import json
import math
import typing
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from guardrail_core.errors import InvalidOptionError

P = TypeVar("P", bound="StageParams")

_UNIT_SUFFIXES = ("_m", "_deg", "_s", "_px", "_mm", "_hz")

#: The largest integer parameter: 2**53, the largest integer a JSON number (a double) holds
#: exactly (parameters are saved as JSON), far inside numpy's int64.
MAX_INTEGER = 2**53


class ParameterError(InvalidOptionError):
    """A parameter is of the wrong type, not finite, outside its range, or unknown."""


@dataclass(frozen=True)
class Slider:
    """How the review app offers a parameter on a slider: its label, and the part of the
    allowed range worth sliding through (a test checks it lies within that range)."""

    label: str
    low: float
    high: float
    step: float


@dataclass(frozen=True)
class ParamSpec:
    """What a parameter field allows (read from the metadata :func:`param` stores)."""

    name: str
    unit: str
    ge: float | None
    gt: float | None
    le: float | None
    lt: float | None
    choices: tuple[Any, ...] | None
    finite: bool
    doc: str
    slider: Slider | None

    def range_text(self) -> str:
        """The allowed range as text, e.g. ``(0, 0.5] m``."""
        if self.choices is not None:
            return "one of " + ", ".join(repr(c) for c in self.choices)
        low = (
            f"({self.gt:g}"
            if self.gt is not None
            else f"[{self.ge:g}"
            if self.ge is not None
            else "(-inf"
        )
        high = (
            f"{self.lt:g})"
            if self.lt is not None
            else f"{self.le:g}]"
            if self.le is not None
            else "inf)"
        )
        return f"{low}, {high}" + (f" {self.unit}" if self.unit else "")


def param(
    default: Any,
    *,
    unit: str = "",
    ge: float | None = None,
    gt: float | None = None,
    le: float | None = None,
    lt: float | None = None,
    choices: Sequence[Any] | None = None,
    finite: bool = True,
    doc: str = "",
    slider: Slider | None = None,
) -> Any:
    """A parameter field: its default, unit and allowed range (``ge``/``gt`` below, ``le``/``lt``
    above; ``choices`` for strings). ``finite=False`` lets a float be infinite ("no limit");
    ``slider`` puts it on the review app's tuning panel."""
    metadata = {
        "unit": unit,
        "ge": ge,
        "gt": gt,
        "le": le,
        "lt": lt,
        "choices": tuple(choices) if choices is not None else None,
        "finite": finite,
        "doc": doc,
        "slider": slider,
    }
    return dataclasses.field(default=default, metadata=metadata)


@dataclass(frozen=True)
class StageParams:
    """Base of every stage's parameters: validated once, at construction.

    Subclasses declare fields with :func:`param` and may add cross-field rules in
    :meth:`check_relations`.
    """

    def __post_init__(self) -> None:
        hints = _type_hints(type(self))
        for f in dataclasses.fields(self):
            if "unit" not in f.metadata:
                continue  # a nested parameters object checks itself
            value = _checked(type(self).__name__, f, hints[f.name], getattr(self, f.name))
            object.__setattr__(self, f.name, value)
        self.check_relations()

    def check_relations(self) -> None:
        """Rules between fields (a minimum below its maximum); raise :class:`ParameterError`."""

    def fail(self, message: str) -> typing.NoReturn:
        """Raise :class:`ParameterError` for a rule of :meth:`check_relations`."""
        raise ParameterError(f"{type(self).__name__}: {message}")

    @classmethod
    def specs(cls) -> list[ParamSpec]:
        """Every parameter of the class with its unit and range, in declaration order."""
        return [
            ParamSpec(name=f.name, **{k: f.metadata[k] for k in _SPEC_KEYS})
            for f in dataclasses.fields(cls)
            if "unit" in f.metadata
        ]

    def to_json(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_json(cls: type[P], data: Mapping[str, Any]) -> P:
        """Parameters from :meth:`to_json` output; missing names keep their defaults.

        Raises
        ------
        ParameterError
            An unknown name, or a value the class refuses.
        """
        if not isinstance(data, Mapping):
            raise ParameterError(f"{cls.__name__}: expected an object of parameters, got {data!r}")
        names = {f.name: f for f in dataclasses.fields(cls)}
        values: dict[str, Any] = {}
        for key, value in data.items():
            if key not in names:
                raise ParameterError(
                    f"unknown parameter {cls.__name__}.{key} (known: {', '.join(sorted(names))})"
                )
            values[key] = value
        return cls(**values)


_SPEC_KEYS = ("unit", "ge", "gt", "le", "lt", "choices", "finite", "doc", "slider")


_HINTS: dict[type, dict[str, Any]] = {}


def _type_hints(cls: type) -> dict[str, Any]:
    """The class's field types, resolved once per class (annotations are strings here)."""
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _checked(owner: str, f: dataclasses.Field, kind: Any, value: Any) -> Any:
    """``value`` as the field's type, or :class:`ParameterError`."""
    meta = f.metadata
    where = f"{owner}.{f.name}"
    if kind is bool:
        if not isinstance(value, bool):
            raise ParameterError(f"{where} must be true or false, got {value!r}")
        return value
    if kind is int:
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            raise ParameterError(f"{where} must be an integer, got {value!r}")
        if not -MAX_INTEGER <= value <= MAX_INTEGER:
            raise ParameterError(f"{where} must lie within ±2^53, got {value:.3g}")
    elif kind is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ParameterError(f"{where} must be a number, got {value!r}")
        value = float(value)
        if math.isnan(value) or (meta["finite"] and math.isinf(value)):
            raise ParameterError(f"{where} must be a finite number, got {value!r}")
    elif kind is str and not isinstance(value, str):
        raise ParameterError(f"{where} must be a string, got {value!r}")
    elif typing.get_origin(kind) is tuple:
        return _checked_tuple(where, meta, typing.get_args(kind), value)
    if meta["choices"] is not None:
        if value not in meta["choices"]:
            choices = ", ".join(repr(c) for c in meta["choices"])
            raise ParameterError(f"{where} must be one of {choices}, got {value!r}")
        return value
    if isinstance(value, int | float) and not _in_range(value, meta):
        spec = ParamSpec(name=f.name, **{k: meta[k] for k in _SPEC_KEYS})
        raise ParameterError(f"{where} must lie within {spec.range_text()}, got {value!r}")
    return value


_ITEM_TYPES: dict[Any, Any] = {int: int, float: int | float}


def _checked_tuple(
    where: str, meta: Mapping[str, Any], kinds: tuple[Any, ...], value: Any
) -> tuple[Any, ...]:
    """A tuple of integers or numbers (fixed length, or ``tuple[float, ...]``: one or more),
    each item within the field's range."""
    if isinstance(value, list):
        value = tuple(value)  # JSON has lists where the parameters have tuples
    if isinstance(value, tuple) and int in kinds:  # 3.0 is the integer 3, as for a scalar
        value = tuple(int(v) if isinstance(v, float) and v.is_integer() else v for v in value)
    if len(kinds) == 2 and kinds[1] is Ellipsis:
        size = "one or more"
        kinds = (kinds[0],) * (len(value) if isinstance(value, tuple) and value else 1)
        fits = isinstance(value, tuple) and len(value) >= 1
    else:
        size = str(len(kinds))
        fits = isinstance(value, tuple) and len(value) == len(kinds)
    words = "integers" if all(k is int for k in kinds) else "numbers"
    if (
        not fits
        or any(
            isinstance(v, bool) or not isinstance(v, _ITEM_TYPES[k])
            for v, k in zip(value, kinds, strict=True)
        )
        or any(isinstance(v, float) and not math.isfinite(v) for v in value)
    ):
        raise ParameterError(f"{where} must be {size} finite {words}, got {value!r}")
    if not all(_in_range(v, meta) for v in value):
        spec = ParamSpec(name=where, **{k: meta[k] for k in _SPEC_KEYS})
        raise ParameterError(
            f"{where} must be {size} {words} within {spec.range_text()}, got {value!r}"
        )
    return tuple(float(v) if k is float else v for v, k in zip(value, kinds, strict=True))


def _in_range(value: float, meta: Mapping[str, Any]) -> bool:
    return not (
        (meta["ge"] is not None and value < meta["ge"])
        or (meta["gt"] is not None and value <= meta["gt"])
        or (meta["le"] is not None and value > meta["le"])
        or (meta["lt"] is not None and value >= meta["lt"])
    )


def has_unit_suffix(name: str) -> bool:
    """Whether a parameter's name ends in one of the unit suffixes."""
    return name.endswith(_UNIT_SUFFIXES)


G = TypeVar("G")


def apply_settings(
    params: G, stages: Mapping[str, type[StageParams]], settings: Sequence[str], what: str
) -> G:
    """``params`` (a frozen dataclass whose fields are ``stages``, each a :class:`StageParams`)
    with ``STAGE.NAME=VALUE`` settings applied (the CLI's ``--set``).

    NAME is a field of the stage's parameters; VALUE is read as the field's type: an integer, a
    number, ``true``/``false``, text, or JSON for a tuple. Each stage is checked once, after all
    its settings, so their order does not matter. ``what`` names the parameters in errors
    (``"reconstruction"``).

    Raises
    ------
    ParameterError
        A setting not of that form, an unknown stage or name, or a value of the wrong type or
        out of range; the message names ``STAGE.NAME``.
    """
    changes: dict[str, dict[str, Any]] = {}
    for setting in settings:
        key, sep, text = setting.partition("=")
        stage, dot, name = key.strip().partition(".")
        if not sep or not dot:
            raise ParameterError(f"expected STAGE.NAME=VALUE, got {setting!r}")
        if stage not in stages:
            raise ParameterError(
                f"unknown {what} stage {stage!r} in {setting!r} (known: {', '.join(stages)})"
            )
        kind = stages[stage]
        hints = typing.get_type_hints(kind)
        names = [f.name for f in dataclasses.fields(kind)]
        if name not in names:
            raise ParameterError(
                f"unknown {what} parameter {stage}.{name} (known: {', '.join(names)})"
            )
        value = _setting_value(f"{stage}.{name}", hints[name], text.strip())
        changes.setdefault(stage, {})[name] = value
    parts = {}
    for stage, values in changes.items():
        try:
            parts[stage] = dataclasses.replace(getattr(params, stage), **values)
        except ParameterError as exc:
            raise ParameterError(f"{stage}: {exc}") from exc
    return dataclasses.replace(params, **parts)  # type: ignore[type-var]


#: How each type of parameter is read from text, for the error that names what was expected.
_KIND_WORDS = {bool: "true or false", int: "an integer", float: "a number"}


def _setting_value(where: str, kind: Any, text: str) -> Any:
    """The text of a ``--set`` value as the parameter's type ``kind`` (its annotation).

    Raises
    ------
    ParameterError
        ``text`` is not a value of that type; names ``where`` (``STAGE.NAME``).
    """
    try:
        if kind is bool:
            word = text.lower()
            if word not in ("true", "false"):
                raise ValueError(text)
            return word == "true"
        if kind is int:
            try:
                return int(text)
            except ValueError:
                return float(text)  # 16.0 reads as 16; the stage refuses 16.5 by name
        if kind is float:
            return float(text)
        if kind is str:
            return text
        value = json.loads(text)  # a tuple (colours) as a JSON list
        return tuple(value) if isinstance(value, list) else value
    except ValueError as exc:
        what = _KIND_WORDS.get(kind, "a JSON value")
        raise ParameterError(f"{where} must be {what}, got {text!r}") from exc
