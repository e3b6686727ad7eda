"""Request and answer models of the stages' parameters, built from their declarations.

A stage's parameters are declared once, as a :class:`~guardrail_core.params.StageParams`
dataclass with each field's type, unit and range. Here each becomes a pydantic model with the
same fields, defaults and ranges, so that ``/openapi.json`` states exactly what a route accepts
(a client, or a fuzzer, can build a valid body from the schema alone) and FastAPI refuses a value
out of range before the route runs. Rules between fields (``check_relations``) cannot be said
in JSON Schema; the route refuses them with a 422 of the same shape.
"""

from __future__ import annotations

import dataclasses
import typing
from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, create_model

from guardrail_core.params import MAX_INTEGER, ParamSpec, StageParams


def _not_a_switch(value: Any) -> Any:
    """Refuse ``true``/``false`` where a number belongs (pydantic would read them as 1 and 0),
    and let an integral number such as ``3.0`` through (JSON Schema counts it an integer)."""
    if isinstance(value, bool):
        raise ValueError("expected a number, not true or false")
    return value


#: A number field that refuses ``true``/``false``.
NOT_A_SWITCH = BeforeValidator(_not_a_switch)


def _item_type(kind: Any, spec: ParamSpec) -> Any:
    """The annotation of one number (or switch, or word) of the field ``spec``."""
    if spec.choices is not None:
        return Literal[spec.choices]
    if kind is bool:
        return Annotated[bool, Field(strict=True)]
    bounds: dict[str, Any] = {"ge": spec.ge, "gt": spec.gt, "le": spec.le, "lt": spec.lt}
    if kind is int:
        if spec.ge is None and spec.gt is None:
            bounds["ge"] = -MAX_INTEGER
        if spec.le is None and spec.lt is None:
            bounds["le"] = MAX_INTEGER
        return Annotated[int, Field(**bounds), NOT_A_SWITCH]
    if kind is float:
        return Annotated[float, Field(allow_inf_nan=False, **bounds), NOT_A_SWITCH]
    return kind


def _field_type(kind: Any, spec: ParamSpec) -> Any:
    """The annotation of the field ``spec`` of type ``kind`` (tuples item by item)."""
    if typing.get_origin(kind) is not tuple:
        return _item_type(kind, spec)
    items = typing.get_args(kind)
    if len(items) == 2 and items[1] is Ellipsis:
        return Annotated[list[_item_type(items[0], spec)], Field(min_length=1)]  # type: ignore[misc]
    return tuple[tuple(_item_type(item, spec) for item in items)]  # type: ignore[misc]


def stage_model(cls: type[StageParams]) -> type[BaseModel]:
    """A pydantic model of ``cls``'s parameters: the same names, defaults, ranges and docs;
    unknown names refused."""
    hints = typing.get_type_hints(cls)
    defaults = {f.name: f.default for f in dataclasses.fields(cls)}
    fields: dict[str, Any] = {}
    for spec in cls.specs():
        description = " ".join(part for part in (spec.doc, spec.range_text()) if part)
        fields[spec.name] = (
            _field_type(hints[spec.name], spec),
            Field(defaults[spec.name], description=description),
        )
    return create_model(
        cls.__name__,
        __config__=ConfigDict(extra="forbid"),
        __doc__=(cls.__doc__ or "").strip().splitlines()[0] if cls.__doc__ else None,
        **fields,
    )


def stages_model(name: str, stages: dict[str, type[StageParams]], doc: str) -> type[BaseModel]:
    """A model with one optional member per stage (``{stage: {name: value}}``)."""
    fields: dict[str, Any] = {}
    for stage, cls in stages.items():
        model = stage_model(cls)
        # A stage named like a BaseModel attribute ("register") is held under another name.
        fields[f"{stage}_"] = (model, Field(default_factory=model, alias=stage))
    config = ConfigDict(extra="forbid", serialize_by_alias=True)
    return create_model(name, __config__=config, __doc__=doc, **fields)


def given_values(model: BaseModel) -> dict[str, Any]:
    """The values a client sent, by stage (what it left out keeps its default)."""
    return model.model_dump(mode="json", exclude_unset=True, by_alias=True)
