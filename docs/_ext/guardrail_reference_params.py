"""The parameters reference, written from every :class:`~guardrail_core.params.StageParams`.

The classes are found, not listed: every module of ``guardrail_core`` is imported and the
subclasses of ``StageParams`` collected, so that a new stage appears without an edit here.
A class whose fields are stages (``ExtractionParams``, ``ReconstructionParams``) is a set of
*sections*: its field names are the SECTION of ``--set SECTION.NAME=VALUE``. Every other class
goes under the part of the library that uses it.
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import pkgutil
import typing
from typing import Any

from guardrail_reference_markdown import code, first_paragraph, heading, join, prose, table

#: Where the sections of each class of sections are set; a class missing here still gets its
#: own part of the page, naming only the class.
SECTION_USERS = {
    "ExtractionParams": "`guardrail process --set SECTION.NAME=VALUE`; saved in the run "
    "folder's `run.json`",
    "ReconstructionParams": "`guardrail process --set`, `guardrail reconstruct --set` and "
    "`guardrail evaluate --set`, or a JSON file `{section: {name: value}}` given to "
    "`--params`; saved in the run folder's `reconstruction/models.json`, and tuned in the "
    "review app's reconstruction panel",
}

#: Where the classes that are no section are used, by the package they are defined in.
PACKAGE_USERS = {
    "guardrail_core.synth": (
        "Simulator",
        "The simulator (`guardrail simulate`) builds these from a {doc}`scene spec "
        "</scene-spec>` and its own options; what the spec does not name keeps the default.",
    ),
    "guardrail_core.sensors": (
        "Scanner",
        "A drive's scanner, stored in `drive.json` (see {doc}`/drive-format`): written by "
        "`guardrail simulate` from the scene spec's `scanner` section and by `guardrail import`.",
    ),
    "guardrail_core.extract": (
        "Model training",
        "How `guardrail train` and the review app's training fit a model; saved in the "
        "model folder's `model.json`.",
    ),
    "guardrail_core.reconstruct": (
        "Reconstruction, fixed",
        "Used by the reconstruction with these defaults; not settable.",
    ),
}


def import_all(package: str = "guardrail_core") -> list[str]:
    """Import every module of ``package`` (``__main__`` modules left out: they run a command).
    Returns the names of the modules imported."""
    root = importlib.import_module(package)
    names = [package]
    for module in pkgutil.walk_packages(root.__path__, package + "."):
        if module.name.rsplit(".", 1)[-1] != "__main__":
            importlib.import_module(module.name)
            names.append(module.name)
    return names


def stage_classes() -> list[type]:
    """Every subclass of ``StageParams`` (subclasses of subclasses too), after importing every
    module of ``guardrail_core``, in a stable order (module, then name)."""
    from guardrail_core.params import StageParams

    import_all()
    found: dict[type, None] = {}
    pending = list(StageParams.__subclasses__())
    while pending:
        cls = pending.pop()
        if cls not in found:
            found[cls] = None
            pending.extend(cls.__subclasses__())
    return sorted(found, key=lambda c: (c.__module__, c.__qualname__))


def nested_stages(cls: type) -> dict[str, type]:
    """The fields of ``cls`` that are stages themselves: {field name: class}."""
    from guardrail_core.params import StageParams

    hints = typing.get_type_hints(cls)
    return {
        f.name: hints[f.name]
        for f in dataclasses.fields(cls)
        if isinstance(hints[f.name], type) and issubclass(hints[f.name], StageParams)
    }


def default_of(field: dataclasses.Field) -> Any:
    """The field's default, made by its factory where it has one."""
    if field.default is not dataclasses.MISSING:
        return field.default
    if field.default_factory is not dataclasses.MISSING:
        return field.default_factory()
    return dataclasses.MISSING


def value_text(value: Any) -> str:
    """A value as ``--set`` and the JSON files take it: ``true``, ``0.25``, ``[8.0, 12.0]``."""
    if hasattr(value, "tolist"):  # numpy arrays and scalars
        value = value.tolist()
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value + 0.0)  # -0.0 (of a rotation matrix) reads as 0.0
    if isinstance(value, list | tuple):
        return "[" + ", ".join(value_text(v) for v in value) + "]"
    if isinstance(value, str):
        return value if value else '""'
    if value is dataclasses.MISSING:
        return "(required)"
    return repr(value)


def allowed_text(spec: Any, kind: Any) -> str:
    """What a field allows, in words: its type and ``ParamSpec.range_text()``."""
    if kind is bool:
        return "`true` or `false`"
    if spec.choices is not None:
        return prose(spec.range_text())
    if kind is str:
        return "any text"
    words = {int: "integer", float: "number"}
    if typing.get_origin(kind) is tuple:
        args = typing.get_args(kind)
        many = "one or more" if args[-1] is Ellipsis else str(len(args))
        what = "integers" if args[0] is int else "numbers"
        text = f"{many} {what}, each in {code(spec.range_text())}"
    else:
        text = f"{words.get(kind, 'value')} in {code(spec.range_text())}"
    if kind is float and not spec.finite:
        text += " (`inf` allowed)"
    return text


def class_table(cls: type) -> str:
    """One row per field of ``cls``: name, default, unit, allowed range, meaning."""
    hints = typing.get_type_hints(cls)
    specs = {s.name: s for s in cls.specs()}
    stages = nested_stages(cls)
    rows = []
    for field in dataclasses.fields(cls):
        name = code(field.name)
        if field.name in stages:
            target = stages[field.name]
            link = f"{{ref}}`{target.__name__} <{label(target)}>`"
            rows.append([name, code(f"{target.__name__}()"), "", f"a section: {link}", ""])
        elif field.name in specs:
            spec = specs[field.name]
            default = code(value_text(default_of(field)))
            allowed = allowed_text(spec, hints[field.name])
            unit = code(spec.unit) if spec.unit else ""
            rows.append([name, default, unit, allowed, prose(spec.doc)])
        else:  # a field without param(): no range to state (a scanner's mounting matrix)
            value = default_of(field)
            kind = getattr(hints[field.name], "__name__", str(hints[field.name]))
            shape = getattr(value, "shape", None)
            allowed = f"{kind} of shape {code(shape)}" if shape is not None else kind
            rows.append([name, code(value_text(value)), "", allowed, ""])
    return table(["Name", "Default", "Unit", "Allowed", "Meaning"], rows)


def class_section(cls: type, level: int, section: str | None = None, note: str = "") -> str:
    """A class's heading (its section name first where it has one), docstring, and table."""
    title = f"`{section}`: {cls.__name__}" if section else cls.__name__
    blocks = [heading(level, title, label=label(cls))]
    blocks.append(f"{first_paragraph(inspect.getdoc(cls))} ({code(cls.__module__)})\n")
    blocks.append(note)
    blocks.append(class_table(cls))
    return join(blocks)


def label(cls: type) -> str:
    """The MyST target of a class's section."""
    return "param-" + cls.__name__.lower()


def parameters_reference(level: int = 2) -> str:
    """The Markdown of every parameters class: each class of sections of ``--set`` with its
    sections, then the classes used elsewhere, by package."""
    classes = stage_classes()
    containers = [c for c in classes if nested_stages(c)]
    in_sections = {s for c in containers for s in nested_stages(c).values()}
    blocks = []
    for container in containers:
        users = SECTION_USERS.get(container.__name__, f"the sections of `{container.__name__}`")
        note = f"Its fields are the sections of `--set SECTION.NAME=VALUE`, set with {users}.\n"
        blocks.append(class_section(container, level, note=note))
        for section, cls in nested_stages(container).items():
            blocks.append(class_section(cls, level + 1, section=section))
    others = [c for c in classes if c not in in_sections and c not in containers]
    packages: dict[str, list[type]] = {}
    for cls in others:
        packages.setdefault(".".join(cls.__module__.split(".")[:2]), []).append(cls)
    for package, members in packages.items():
        title, where = PACKAGE_USERS.get(package, (package, f"Used in `{package}`."))
        blocks.append(heading(level, f"{title}: not settable with `--set`"))
        blocks.append(f"{where}\n")
        blocks.extend(class_section(cls, level + 1) for cls in members)
    return join(blocks)
