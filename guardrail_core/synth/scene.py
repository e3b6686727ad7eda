"""Scene specs (YAML) and the scenes built from them: meshes with truth, the road, the vehicle.

A spec is a mapping with the keys ``road``, ``vehicle``, ``guardrails`` and ``objects`` (see
``docs/scene-spec.md`` and ``data_samples/scenes/``).
:func:`~guardrail_core.synth.random_scene.random_scene_spec` writes one from a seed;
:func:`plan_scene` reads and checks one into parts (:mod:`.scene_parts`: stretches of road,
guardrail runs, street objects) that :func:`build_scene` builds into meshes and
``truth/objects.json`` records all at once, and the simulator a window of the drive at a time.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from guardrail_core.errors import SceneSpecError, SourceFormatError
from guardrail_core.params import ParameterError
from guardrail_core.sensors.lidar_models import lidar_model
from guardrail_core.sensors.scanner import (
    AZIMUTH_BINS,
    DEFAULT_MOUNT_POSITION_M,
    DEFAULT_MOUNT_RPY_DEG,
    DRIVE_JSON_KEYS,
    MULTIBEAM,
    PROFILE,
    ScannerParams,
    scanner_mounting,
)
from guardrail_core.synth.mesh import MeshBuilder, SceneMesh
from guardrail_core.synth.multibeam import MultibeamParams
from guardrail_core.synth.road import Road, Roadside, RoadSpec
from guardrail_core.synth.scanner import ReturnModel
from guardrail_core.synth.scene_parts import ScenePart, guardrail_parts, object_parts, road_parts
from guardrail_core.synth.spec_values import spec_value
from guardrail_core.synth.vehicle import VehicleParams

SCENES_DIR = Path(__file__).resolve().parents[2] / "data_samples" / "scenes"

#: Japan Plane Rectangular CS IX (JGD2011), where Tokyo's streets are mapped.
DEFAULT_CRS = "EPSG:6677"
DEFAULT_ORIGIN = (-7400.0, -34700.0, 40.0)


@dataclass(frozen=True)
class Scene:
    """A built scene.

    Attributes
    ----------
    spec : dict, the spec it was built from (normalised)
    road : Road
    vehicle : VehicleParams
    scanner : ScannerParams, the scanner on the vehicle (``t0_s`` set when the drive starts)
    multibeam : MultibeamParams for a multi-beam scanner (its beams and frame spacing), else None
    drive_span : (s_start, s_end) metres along the road that the vehicle drives
    mesh : SceneMesh, every surface with its truth
    objects : list of dict, truth records (``truth/objects.json``)
    crs : str; origin : (3,) float64 map coordinates of the local frame's origin
    """

    spec: dict
    road: Road
    vehicle: VehicleParams
    scanner: ScannerParams
    drive_span: tuple[float, float]
    mesh: SceneMesh
    objects: list[dict]
    crs: str
    origin: np.ndarray
    multibeam: MultibeamParams | None = None


# ----------------------------------------------------------------------------- reading specs


def load_scene_spec(path: str | os.PathLike) -> dict:
    """Read a scene spec YAML file (a bare name resolves in ``data_samples/scenes``)."""
    p = Path(path)
    if not p.exists() and (SCENES_DIR / f"{p}.yaml").exists():
        p = SCENES_DIR / f"{p}.yaml"
    if not p.is_file():
        raise SceneSpecError(f"{path}: no such scene spec (shipped: {', '.join(list_scenes())})")
    try:
        spec = yaml.safe_load(p.read_text())
    except yaml.YAMLError as exc:
        raise SceneSpecError(f"{p}: not valid YAML ({exc})") from exc
    if not isinstance(spec, dict):
        raise SceneSpecError(
            f"{p}: a scene spec is a mapping with road, vehicle, guardrails, objects"
        )
    spec.setdefault("name", p.stem)
    return spec


def list_scenes() -> list[str]:
    return sorted(p.stem for p in SCENES_DIR.glob("*.yaml"))


def _road_spec(data: object) -> RoadSpec:
    where = "road"
    if not isinstance(data, dict):
        raise SceneSpecError("road: expected a mapping")
    pieces = spec_value(data, "centreline", list, where)
    segments = []
    for i, piece in enumerate(pieces):
        w = f"road.centreline[{i}]"
        if isinstance(piece, dict) and "straight" in piece:
            length = spec_value(piece, "straight", float, w)
            segments.append(("straight", length, 0.0))
        elif isinstance(piece, dict) and "arc" in piece:
            arc = spec_value(piece, "arc", dict, w)
            radius = spec_value(arc, "radius", float, w + ".arc")
            if radius < 20:
                raise SceneSpecError(
                    f"{w}.arc.radius: {radius} m is tighter than any road (>= 20 m)"
                )
            if "angle_deg" in arc:
                angle = np.deg2rad(spec_value(arc, "angle_deg", float, w + ".arc"))
            else:
                angle = spec_value(arc, "length", float, w + ".arc") / radius
            segments.append(("arc", abs(angle) * radius, float(np.sign(angle) / radius)))
        else:
            raise SceneSpecError(
                f"{w}: expected {{straight: LENGTH}} or {{arc: {{radius, angle_deg}}}}"
            )
        if segments[-1][1] <= 0:
            raise SceneSpecError(f"{w}: length must be positive")
    if not segments:
        raise SceneSpecError("road.centreline: needs at least one piece")
    curb = spec_value(data, "curb", dict, where, {})
    sidewalk = spec_value(data, "sidewalk", dict, where, {})
    roadside = spec_value(data, "roadside", dict, where, {})
    lanes = int(spec_value(data, "lanes", int, where, 2))
    if lanes < 1:
        raise SceneSpecError("road.lanes: at least one lane")
    return RoadSpec(
        segments=tuple(segments),
        heading_deg=spec_value(data, "heading_deg", float, where, 0.0),
        lanes=lanes,
        lane_width=spec_value(data, "lane_width", float, where, 3.25),
        crown_slope=spec_value(data, "crown_percent", float, where, 2.0) / 100,
        grade=spec_value(data, "grade_percent", float, where, 1.0) / 100,
        undulation_m=spec_value(data, "undulation_m", float, where, 0.3),
        curb_height=spec_value(curb, "height", float, "road.curb", 0.15),
        curb_width=spec_value(curb, "width", float, "road.curb", 0.18),
        sidewalk_left=spec_value(sidewalk, "left", float, "road.sidewalk", 2.5),
        sidewalk_right=spec_value(sidewalk, "right", float, "road.sidewalk", 2.5),
        verge=spec_value(data, "verge", float, where, 6.0),
        roadside_left=_roadside(roadside, "left"),
        roadside_right=_roadside(roadside, "right"),
    )


def _roadside(data: dict, side: str) -> Roadside:
    """``road.roadside.<side>``: ``slope_percent`` (rise away from the road; negative falls) and
    an optional ``ditch: {depth, width}`` along the sidewalk's outer edge."""
    where = f"road.roadside.{side}"
    item = spec_value(data, side, dict, "road.roadside", {})
    slope = spec_value(item, "slope_percent", float, where, 0.0)
    if not -100 <= slope <= 100:
        raise SceneSpecError(f"{where}.slope_percent: {slope} is steeper than 45 degrees")
    ditch = spec_value(item, "ditch", dict, where, {})
    depth = spec_value(ditch, "depth", float, where + ".ditch", 0.0)
    width = spec_value(ditch, "width", float, where + ".ditch", 1.0)
    if not 0 <= depth <= 3 or not 0.2 <= width <= 10:
        raise SceneSpecError(
            f"{where}.ditch: depth {depth} m must lie in 0..3 and width {width} m in 0.2..10"
        )
    return Roadside(slope=slope / 100, ditch_depth_m=depth, ditch_width_m=width)


def _vehicle(data: dict, road: Road) -> tuple[VehicleParams, tuple[float, float]]:
    where = "vehicle"
    speed = spec_value(data, "speed_mps", list, where, [8.0, 12.0])
    if len(speed) != 2 or not 1.0 <= float(speed[0]) <= float(speed[1]) <= 40.0:
        raise SceneSpecError(
            f"vehicle.speed_mps: expected [min, max] within 1..40 m/s, got {speed}"
        )
    lane = int(spec_value(data, "lane", int, where, 0))
    if not 0 <= lane < road.spec.lanes:
        raise SceneSpecError(f"vehicle.lane: {lane} is not a lane of a {road.spec.lanes}-lane road")
    start = spec_value(data, "start", float, where, min(20.0, road.length / 4))
    end = spec_value(data, "end", float, where, road.length - min(20.0, road.length / 4))
    if not 0 <= start < end <= road.length:
        raise SceneSpecError(
            f"vehicle: start {start} and end {end} must lie on the road (0..{road.length:.1f} m)"
        )
    params = VehicleParams(speed_mps=(float(speed[0]), float(speed[1])), lane=lane)
    return params, (start, end)


#: The KITTI car's Velodyne: 1.73 m above the road, level.
MULTIBEAM_HEIGHT_M = 1.73


def _scanner(
    data: object, reference_height_m: float
) -> tuple[ScannerParams, MultibeamParams | None]:
    """The optional ``scanner`` section: a profile scanner's rates, noise and mounting (RIEGL
    VQ-250 defaults), or ``kind: multibeam``, a spinning LiDAR (``sensor``: a preset of
    :data:`~guardrail_core.sensors.lidar_models.LIDAR_MODELS`, default the Velodyne HDL-64E)
    taking one frame every ``frame_every_m`` metres (default 60), level at ``height_m`` (1.73)
    above the road."""
    if not isinstance(data, dict):
        raise SceneSpecError("scanner: expected a mapping")
    where = "scanner"
    kind = spec_value(data, "kind", str, where, PROFILE)
    if kind == MULTIBEAM:
        frame_every = spec_value(data, "frame_every_m", float, where, MultibeamParams.frame_every_m)
        height = spec_value(data, "height_m", float, where, MULTIBEAM_HEIGHT_M)
        if not frame_every > 0 or not height > 0:
            raise SceneSpecError(
                f"scanner: frame_every_m and height_m must be positive, got {frame_every} and "
                f"{height}"
            )
        mount = scanner_mounting((0.0, 0.0, height - reference_height_m), 0.0, 0.0, 0.0)
        sensor = spec_value(data, "sensor", str, where, "hdl64e")
        try:
            model = lidar_model(sensor)
        except SourceFormatError as exc:
            raise SceneSpecError(f"scanner.sensor: {exc}") from exc
        try:
            params = MultibeamParams(
                frame_every_m=frame_every,
                elevations_deg=model.elevations_deg,
                firings_per_rotation=model.firings_per_rotation,
            )
            scanner = ScannerParams(
                rotation_rate_hz=model.rotation_hz,
                measurement_rate_hz=model.rotation_hz * AZIMUTH_BINS,
                range_noise_m=spec_value(data, "range_noise_m", float, where, 0.02),
                min_range_m=2.5,  # the car's own body
                max_range_m=spec_value(data, "max_range_m", float, where, 120.0),
                T_vehicle_scanner=mount,
                kind=MULTIBEAM,
                rings=len(params.elevations_deg),
            )
        except ParameterError as exc:
            raise SceneSpecError(f"scanner: {exc}") from exc
        return scanner, params
    if kind != PROFILE:
        raise SceneSpecError(f"scanner.kind: expected {PROFILE} or {MULTIBEAM}, got {kind!r}")
    mount = spec_value(data, "mounting", dict, where, {})
    position = spec_value(
        mount, "position_m", list, "scanner.mounting", list(DEFAULT_MOUNT_POSITION_M)
    )
    if len(position) != 3 or not all(isinstance(v, int | float) for v in position):
        raise SceneSpecError(
            f"scanner.mounting.position_m: expected [x, y, z] metres, got {position}"
        )
    defaults = ScannerParams()
    # A spec ignores keys it does not know, but drive.json's names of the rates (a drive's
    # scanner block copied into a spec) would silently leave the defaults: refused instead.
    for key in ("rotations_per_second", "measurements_per_second"):
        if key in data:
            raise SceneSpecError(f"scanner.{key}: a scene spec names it {DRIVE_JSON_KEYS[key]}")
    try:
        return ScannerParams(
            rotation_rate_hz=spec_value(
                data, "rotation_rate_hz", float, where, defaults.rotation_rate_hz
            ),
            measurement_rate_hz=spec_value(
                data, "measurement_rate_hz", float, where, defaults.measurement_rate_hz
            ),
            range_noise_m=spec_value(data, "range_noise_m", float, where, defaults.range_noise_m),
            max_range_m=spec_value(data, "max_range_m", float, where, defaults.max_range_m),
            T_vehicle_scanner=scanner_mounting(
                (float(position[0]), float(position[1]), float(position[2])),
                roll_deg=spec_value(
                    mount, "roll_deg", float, "scanner.mounting", DEFAULT_MOUNT_RPY_DEG[0]
                ),
                pitch_deg=spec_value(
                    mount, "pitch_deg", float, "scanner.mounting", DEFAULT_MOUNT_RPY_DEG[1]
                ),
                yaw_deg=spec_value(
                    mount, "yaw_deg", float, "scanner.mounting", DEFAULT_MOUNT_RPY_DEG[2]
                ),
            ),
        ), None
    except ParameterError as exc:
        raise SceneSpecError(f"scanner: {exc}") from exc


def _returns(data: dict) -> ReturnModel:
    """The ``scanner`` section's ``dropout`` (probability of losing any return, 0..1) and
    ``intensity_gain`` (factor on every intensity: a scanner calibrated differently)."""
    defaults = ReturnModel()
    dropout = spec_value(data, "dropout", float, "scanner", defaults.base_dropout)
    gain = spec_value(data, "intensity_gain", float, "scanner", defaults.intensity_gain)
    if not 0 <= dropout <= 1:
        raise SceneSpecError(f"scanner.dropout: a probability lies in 0..1, got {dropout}")
    if not 0 < gain <= 100:
        raise SceneSpecError(f"scanner.intensity_gain: expected a factor in (0, 100], got {gain}")
    return ReturnModel(base_dropout=dropout, intensity_gain=gain)


# ----------------------------------------------------------------------------- building


@dataclass(frozen=True)
class SceneLayout:
    """A scene spec read and checked, its meshes not yet built: the parts to build them from.

    Attributes
    ----------
    spec, road, vehicle, scanner, multibeam, drive_span, crs, origin : as in :class:`Scene`
    returns : how surfaces answer the scanner's pulses (dropouts, intensity calibration)
    parts : the road in stretches, then the guardrail runs and street objects in object-id order
        (:mod:`~guardrail_core.synth.scene_parts`)
    """

    spec: dict
    road: Road
    vehicle: VehicleParams
    scanner: ScannerParams
    drive_span: tuple[float, float]
    parts: tuple[ScenePart, ...]
    crs: str
    origin: np.ndarray
    multibeam: MultibeamParams | None = None
    returns: ReturnModel = ReturnModel()


def plan_scene(spec: dict, *, seed: int = 0) -> SceneLayout:
    """Read and check a scene spec; its parts are built later, all at once (:func:`build_scene`)
    or a stretch at a time (:class:`~guardrail_core.synth.scene_window.SceneWindows`).

    ``seed`` drives what the spec leaves open (paints not given, tree and car shapes), each
    object from its own stream, so a part is the same whichever parts are built with it.
    """
    if not isinstance(spec, dict):
        raise SceneSpecError("a scene spec is a mapping with road, vehicle, guardrails, objects")
    road = Road(_road_spec(spec.get("road")))
    vehicle, span = _vehicle(spec.get("vehicle") or {}, road)
    scanner, multibeam = _scanner(spec.get("scanner") or {}, vehicle.reference_height_m)
    returns = _returns(spec.get("scanner") or {})
    rails = guardrail_parts(list(spec.get("guardrails") or []), road, seed, first_id=1)
    objects = object_parts(list(spec.get("objects") or []), road, seed, first_id=1 + len(rails))
    origin = np.asarray(spec.get("origin", DEFAULT_ORIGIN), np.float64)
    if origin.shape != (3,) or not np.all(np.isfinite(origin)):
        raise SceneSpecError(
            f"origin: expected three finite map coordinates, got {spec.get('origin')}"
        )
    return SceneLayout(
        spec=spec,
        road=road,
        vehicle=vehicle,
        scanner=scanner,
        drive_span=span,
        parts=(*road_parts(road), *rails, *objects),
        crs=str(spec.get("crs", DEFAULT_CRS)),
        origin=origin,
        multibeam=multibeam,
        returns=returns,
    )


def build_scene(spec: dict, *, seed: int = 0) -> Scene:
    """Build the whole scene's meshes and truth from a scene spec (see :func:`plan_scene`)."""
    layout = plan_scene(spec, seed=seed)
    builder = MeshBuilder()
    objects = [record for part in layout.parts if (record := part.build(builder)) is not None]
    return Scene(
        spec=spec,
        road=layout.road,
        vehicle=layout.vehicle,
        scanner=layout.scanner,
        drive_span=layout.drive_span,
        mesh=builder.build(),
        objects=objects,
        crs=layout.crs,
        origin=layout.origin,
        multibeam=layout.multibeam,
    )
