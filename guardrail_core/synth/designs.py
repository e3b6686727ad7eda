"""Guardrail designs: YAML specs of one unit shape in unit coordinates, and their loader.

A guardrail is a row of poles with identical *unit shapes* between consecutive poles (Matsumoto
et al. 2019, §4.1, Fig. 10). A design describes one unit in a 2-D frame: ``x`` metres along the
unit from its first pole (``0 <= x <= unit_length``) and ``y`` metres above the ground. Pipe
guardrails (§4.3) are sets of horizontal, vertical, diagonal and curved pipes swept by circles;
beam guardrails (§4.4) are a bent-plate section curve swept along the whole run.

YAML schema (``data_samples/designs/NAME.yaml``)::

    name: pipe_simple_2              # optional, defaults to the file stem
    description: two horizontal rails
    type: pipe                       # pipe | beam
    unit_length: 2.0                 # metres between pole axes
    pole: {radius: 0.0305, height: 0.8, cap: true}
    pipes:                           # each one of:
      - {points: [[0, 0.76], [2, 0.76]], radius: 0.0243}
      - {arc: {centre: [1, 0.2], radius: 0.5, from_deg: 0, to_deg: 180}, radius: 0.014}
      - {wave: {x: [0, 2], y: 0.5, amplitude: 0.15, periods: 2, phase_deg: 0}, radius: 0.0135}
    beams:                           # type beam only
      - {section: w_beam, height: 0.6, offset: 0.1, thickness: 0.0023}

A pipe may carry ``kind`` (horizontal | vertical | diagonal | curved); it must agree with the
geometry, which decides it otherwise. Arc angles are measured from +x towards +y (up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from guardrail_core.errors import SceneSpecError

DESIGNS_DIR = Path(__file__).resolve().parents[2] / "data_samples" / "designs"

PIPE_KINDS = ("horizontal", "vertical", "diagonal", "curved")
DESIGN_TYPES = ("pipe", "beam")

#: Arcs are sampled at most this many degrees apart (a 12-sided tube then looks smooth).
ARC_STEP_DEG = 5.0
#: Tolerance (m) for "constant x", "constant y" and "straight" in kind inference and bounds.
_GEOM_TOL = 1e-6


@dataclass(frozen=True)
class PoleSpec:
    """A post: a vertical cylinder of ``radius`` (m) and ``height`` (m) above ground.

    ``cap`` adds a hemispherical dome on top (pipe fences) or, for beams, a post cap.
    """

    radius: float
    height: float
    cap: bool


@dataclass(frozen=True, eq=False)
class PipeSpec:
    """One pipe of a unit.

    Attributes
    ----------
    points : (K, 2) float64, read-only
        Axis polyline in unit coordinates (x along the unit in [0, unit_length], y above ground).
    radius : float, metres
    kind : str, one of :data:`PIPE_KINDS`
    """

    points: np.ndarray
    radius: float
    kind: str


@dataclass(frozen=True, eq=False)
class BeamSpec:
    """A beam swept continuously along the run (§4.4).

    Attributes
    ----------
    section : (M, 2) float64, read-only
        Mid-surface section curve in (across, up) metres: across measured horizontally from the
        post axis toward the road, up above ground.
    thickness : float, metres (plate thickness, the sheet is offset by +-thickness/2)
    """

    section: np.ndarray
    thickness: float


@dataclass(frozen=True, eq=False)
class Design:
    """A guardrail design: the unit shape between two poles."""

    name: str
    type: str
    unit_length: float
    pole: PoleSpec
    pipes: tuple[PipeSpec, ...]
    beams: tuple[BeamSpec, ...]
    description: str


# --------------------------------------------------------------------------------------------
# Standard beam sections
# --------------------------------------------------------------------------------------------


def _corrugated_section(height: float, depth: float, waves: int, n: int) -> np.ndarray:
    """A smooth corrugated plate of ``waves`` ridges: (n, 2) (across, up) centred on up = 0.

    ``across = depth * sin^2(pi * waves * t)``: the edges and the valleys between ridges sit at
    across = 0 (the bolting plane against the blockout), the ridges bulge ``depth`` toward the road.
    """
    t = np.linspace(0.0, 1.0, n)
    across = depth * np.sin(np.pi * waves * t) ** 2
    up = (t - 0.5) * height
    return np.stack([across, up], axis=1)


def w_beam_section(height: float = 0.35, depth: float = 0.085, n: int = 49) -> np.ndarray:
    """The W-beam (two ridges, ~310-350 mm tall, ~85 mm deep): (n, 2) (across, up), up centred."""
    return _corrugated_section(height, depth, 2, n)


def thrie_beam_section(height: float = 0.5, depth: float = 0.085, n: int = 73) -> np.ndarray:
    """The thrie beam (three ridges, ~500 mm tall): (n, 2) (across, up), up centred on 0."""
    return _corrugated_section(height, depth, 3, n)


BEAM_SECTIONS = {"w_beam": w_beam_section, "thrie_beam": thrie_beam_section}


# --------------------------------------------------------------------------------------------
# Loader
# --------------------------------------------------------------------------------------------


def list_designs() -> list[str]:
    """Names of the designs shipped in :data:`DESIGNS_DIR`, sorted."""
    return sorted(p.stem for p in DESIGNS_DIR.glob("*.yaml"))


def load_design(name_or_path: str | Path) -> Design:
    """Load and validate a design by name (``DESIGNS_DIR/NAME.yaml``) or by path.

    Raises
    ------
    SceneSpecError
        The file is missing, is not YAML, or a key is missing, unknown or out of range; the
        message names the file and the key.
    """
    text = str(name_or_path)
    if isinstance(name_or_path, Path) or text.endswith((".yaml", ".yml")) or "/" in text:
        path = Path(name_or_path)
    else:
        path = DESIGNS_DIR / f"{text}.yaml"
        if not path.is_file():
            raise SceneSpecError(
                f"unknown design {text!r}: no {path}; known designs: {', '.join(list_designs())}"
            )
    if not path.is_file():
        raise SceneSpecError(f"design file {path} does not exist")
    try:
        raw = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise SceneSpecError(f"{path}: not valid YAML: {exc}") from exc
    return parse_design(raw, source=str(path), default_name=path.stem)


class _Ctx:
    """Where a value came from, for error messages: ``file: key.path: problem``."""

    def __init__(self, source: str) -> None:
        self.source = source

    def error(self, key: str, problem: str) -> SceneSpecError:
        return SceneSpecError(f"{self.source}: {key or '(top level)'}: {problem}")

    def mapping(self, value: Any, key: str, allowed: set[str], required: set[str]) -> dict:
        if not isinstance(value, dict):
            raise self.error(key, f"expected a mapping, got {type(value).__name__}")
        unknown = sorted(set(map(str, value)) - allowed)
        if unknown:
            raise self.error(
                f"{key}.{unknown[0]}" if key else unknown[0],
                f"unknown key (allowed: {', '.join(sorted(allowed))})",
            )
        missing = sorted(required - set(value))
        if missing:
            raise self.error(f"{key}.{missing[0]}" if key else missing[0], "missing required key")
        return value

    def number(self, value: Any, key: str, *, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise self.error(key, f"expected a number, got {value!r}")
        v = float(value)
        if not math.isfinite(v):
            raise self.error(key, f"must be finite, got {value!r}")
        if positive and v <= 0:
            raise self.error(key, f"must be positive, got {value!r}")
        return v

    def points(self, value: Any, key: str, min_len: int = 2) -> np.ndarray:
        if not isinstance(value, list) or len(value) < min_len:
            raise self.error(key, f"expected a list of at least {min_len} [x, y] pairs")
        out = np.empty((len(value), 2))
        for i, p in enumerate(value):
            if not isinstance(p, list | tuple) or len(p) != 2:
                raise self.error(f"{key}[{i}]", f"expected an [x, y] pair, got {p!r}")
            out[i] = [self.number(p[0], f"{key}[{i}][0]"), self.number(p[1], f"{key}[{i}][1]")]
        return out


def parse_design(raw: Any, *, source: str = "<design>", default_name: str = "design") -> Design:
    """Validate a parsed YAML mapping and build a :class:`Design` (see the module docstring)."""
    ctx = _Ctx(source)
    top = ctx.mapping(
        raw,
        "",
        {"name", "description", "type", "unit_length", "pole", "pipes", "beams"},
        {"type", "unit_length", "pole"},
    )
    name = top.get("name", default_name)
    if not isinstance(name, str) or not name:
        raise ctx.error("name", f"expected a non-empty string, got {name!r}")
    description = top.get("description", "")
    if not isinstance(description, str):
        raise ctx.error("description", "expected a string")
    dtype = top["type"]
    if dtype not in DESIGN_TYPES:
        raise ctx.error("type", f"unknown type {dtype!r} (expected one of {DESIGN_TYPES})")
    unit_length = ctx.number(top["unit_length"], "unit_length", positive=True)

    p = ctx.mapping(top["pole"], "pole", {"radius", "height", "cap"}, {"radius", "height"})
    cap = p.get("cap", True)
    if not isinstance(cap, bool):
        raise ctx.error("pole.cap", f"expected true or false, got {cap!r}")
    pole = PoleSpec(
        radius=ctx.number(p["radius"], "pole.radius", positive=True),
        height=ctx.number(p["height"], "pole.height", positive=True),
        cap=cap,
    )

    raw_pipes = top.get("pipes", []) or []
    raw_beams = top.get("beams", []) or []
    for key, val in (("pipes", raw_pipes), ("beams", raw_beams)):
        if not isinstance(val, list):
            raise ctx.error(key, f"expected a list, got {type(val).__name__}")
    pipes = tuple(_parse_pipe(ctx, r, f"pipes[{i}]", unit_length) for i, r in enumerate(raw_pipes))
    beams = tuple(_parse_beam(ctx, r, f"beams[{i}]", pole) for i, r in enumerate(raw_beams))
    if dtype == "pipe":
        if not pipes:
            raise ctx.error("pipes", "a pipe design needs at least one pipe")
        if beams:
            raise ctx.error("beams", "a pipe design has no beams (use type: beam)")
    elif not beams:
        raise ctx.error("beams", "a beam design needs at least one beam")
    return Design(name, dtype, unit_length, pole, pipes, beams, description.strip())


#: The range of :func:`scaled_height` factors a scene spec may ask for.
HEIGHT_SCALE_RANGE = (0.5, 2.0)


def scaled_height(design: Design, factor: float) -> Design:
    """``design`` built ``factor`` times as tall: real guardrails of one design stand 0.7-1.2 m.

    Pipes: every axis point's height and the pole's height times ``factor`` (a horizontal rail
    stays horizontal, an arc becomes an elliptic arc). Beams: the pole times ``factor`` and each
    section lifted so that its mean height is ``factor`` times as high; the plate keeps its shape,
    as a beam of one profile is mounted higher or lower. ``factor`` 1 returns ``design`` itself.

    Raises
    ------
    SceneSpecError
        ``factor`` outside :data:`HEIGHT_SCALE_RANGE`.
    """
    lo, hi = HEIGHT_SCALE_RANGE
    if not (isinstance(factor, int | float) and lo <= factor <= hi):
        raise SceneSpecError(f"height_scale: {lo} to {hi}, got {factor!r}")
    if factor == 1.0:
        return design
    pipes = tuple(
        replace(p, points=_readonly(p.points * np.array([1.0, factor]))) for p in design.pipes
    )
    beams = tuple(
        replace(
            b,
            section=_readonly(b.section + [0.0, (factor - 1.0) * float(b.section[:, 1].mean())]),
        )
        for b in design.beams
    )
    pole = replace(design.pole, height=design.pole.height * factor)
    return replace(design, pole=pole, pipes=pipes, beams=beams)


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=np.float64)
    a.setflags(write=False)
    return a


def infer_pipe_kind(points: np.ndarray) -> str:
    """Kind of a pipe axis (K, 2): vertical (x constant), horizontal (y constant), diagonal
    (straight otherwise), curved (else); as the reconstruction of §4.3 classifies skeletons."""
    x, y = points[:, 0], points[:, 1]
    if np.ptp(x) <= _GEOM_TOL:
        return "vertical"
    if np.ptp(y) <= _GEOM_TOL:
        return "horizontal"
    d = points[-1] - points[0]
    rel = points - points[0]
    off_line = np.abs(rel[:, 0] * d[1] - rel[:, 1] * d[0]) / np.linalg.norm(d)
    return "diagonal" if off_line.max() <= _GEOM_TOL else "curved"


def _parse_pipe(ctx: _Ctx, raw: Any, key: str, unit_length: float) -> PipeSpec:
    spec = ctx.mapping(raw, key, {"points", "arc", "wave", "radius", "kind"}, {"radius"})
    forms = [f for f in ("points", "arc", "wave") if f in spec]
    if len(forms) != 1:
        raise ctx.error(key, f"give exactly one of points, arc, wave (got {forms or 'none'})")
    radius = ctx.number(spec["radius"], f"{key}.radius", positive=True)
    form = forms[0]
    if form == "points":
        pts = ctx.points(spec["points"], f"{key}.points")
    elif form == "arc":
        a = ctx.mapping(
            spec["arc"],
            f"{key}.arc",
            {"centre", "radius", "from_deg", "to_deg"},
            {"centre", "radius", "from_deg", "to_deg"},
        )
        centre = ctx.points([a["centre"]], f"{key}.arc.centre", min_len=1)[0]
        big_r = ctx.number(a["radius"], f"{key}.arc.radius", positive=True)
        a0 = ctx.number(a["from_deg"], f"{key}.arc.from_deg")
        a1 = ctx.number(a["to_deg"], f"{key}.arc.to_deg")
        if a0 == a1 or abs(a1 - a0) > 360:
            raise ctx.error(f"{key}.arc.to_deg", "sweep must be non-zero and at most 360 deg")
        n = int(math.ceil(abs(a1 - a0) / ARC_STEP_DEG)) + 1
        ang = np.radians(np.linspace(a0, a1, n))
        pts = centre + big_r * np.stack([np.cos(ang), np.sin(ang)], axis=1)
    else:
        w = ctx.mapping(
            spec["wave"],
            f"{key}.wave",
            {"x", "y", "amplitude", "periods", "phase_deg"},
            {"x", "y", "amplitude", "periods"},
        )
        xs = w["x"]
        if not isinstance(xs, list) or len(xs) != 2:
            raise ctx.error(f"{key}.wave.x", "expected [x_start, x_end]")
        x0 = ctx.number(xs[0], f"{key}.wave.x[0]")
        x1 = ctx.number(xs[1], f"{key}.wave.x[1]")
        if x1 <= x0:
            raise ctx.error(f"{key}.wave.x", "x_end must exceed x_start")
        y0 = ctx.number(w["y"], f"{key}.wave.y")
        amp = ctx.number(w["amplitude"], f"{key}.wave.amplitude", positive=True)
        periods = ctx.number(w["periods"], f"{key}.wave.periods", positive=True)
        phase = math.radians(ctx.number(w.get("phase_deg", 0.0), f"{key}.wave.phase_deg"))
        n = int(math.ceil(36 * periods)) + 1  # every 10 deg of phase
        x = np.linspace(x0, x1, n)
        pts = np.stack(
            [x, y0 + amp * np.sin(2 * np.pi * periods * (x - x0) / (x1 - x0) + phase)], 1
        )

    if np.any(np.linalg.norm(np.diff(pts, axis=0), axis=1) <= _GEOM_TOL):
        raise ctx.error(f"{key}.{form}", "consecutive axis points coincide")
    bad_x = (pts[:, 0] < -_GEOM_TOL) | (pts[:, 0] > unit_length + _GEOM_TOL)
    if bad_x.any():
        raise ctx.error(
            f"{key}.{form}",
            f"x = {pts[bad_x, 0][0]:.4g} lies outside [0, unit_length = {unit_length:g}]",
        )
    if (pts[:, 1] < 0).any():
        raise ctx.error(f"{key}.{form}", f"y = {pts[:, 1].min():.4g} is below the ground")
    pts[:, 0] = np.clip(pts[:, 0], 0.0, unit_length)

    inferred = infer_pipe_kind(pts)
    kind = spec.get("kind", inferred)
    if kind not in PIPE_KINDS:
        raise ctx.error(f"{key}.kind", f"unknown kind {kind!r} (expected one of {PIPE_KINDS})")
    if kind != inferred:
        raise ctx.error(f"{key}.kind", f"says {kind!r} but the geometry is {inferred!r}")
    return PipeSpec(points=_readonly(pts), radius=radius, kind=kind)


def _parse_beam(ctx: _Ctx, raw: Any, key: str, pole: PoleSpec) -> BeamSpec:
    spec = ctx.mapping(
        raw, key, {"section", "height", "offset", "thickness"}, {"section", "thickness"}
    )
    thickness = ctx.number(spec["thickness"], f"{key}.thickness", positive=True)
    section = spec["section"]
    if isinstance(section, str):
        if section not in BEAM_SECTIONS:
            raise ctx.error(
                f"{key}.section",
                f"unknown section {section!r} (expected one of {sorted(BEAM_SECTIONS)} "
                "or a list of [across, up] points)",
            )
        if "height" not in spec:
            raise ctx.error(f"{key}.height", "missing required key (centre height above ground)")
        height = ctx.number(spec["height"], f"{key}.height", positive=True)
        offset = ctx.number(spec.get("offset", pole.radius + 0.03), f"{key}.offset")
        sec = BEAM_SECTIONS[section]() + np.array([offset, height])
    else:
        sec = ctx.points(section, f"{key}.section")
        # A custom section is absolute unless a height/offset shift is given.
        sec = sec + np.array(
            [
                ctx.number(spec.get("offset", 0.0), f"{key}.offset"),
                ctx.number(spec.get("height", 0.0), f"{key}.height"),
            ]
        )
    if np.any(np.linalg.norm(np.diff(sec, axis=0), axis=1) <= _GEOM_TOL):
        raise ctx.error(f"{key}.section", "consecutive section points coincide")
    if sec[:, 1].min() - thickness / 2 < 0:
        raise ctx.error(f"{key}.height", "the beam reaches below the ground")
    if sec[:, 0].min() - thickness / 2 < pole.radius:
        raise ctx.error(
            f"{key}.offset",
            f"the beam (nearest across {sec[:, 0].min():.4g} m) would cut the post "
            f"(radius {pole.radius:g} m); increase the offset",
        )
    return BeamSpec(section=_readonly(sec), thickness=thickness)
