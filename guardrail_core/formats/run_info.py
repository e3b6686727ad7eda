"""``run.json`` as typed values: what a run was made from and what it found.

``guardrail process`` writes it (:func:`guardrail_core.process.process_drive` returns it, with the
reconstruction's summary); :meth:`guardrail_core.formats.run_folder_paths.RunFolder.info` reads it
back, its format version checked. :meth:`RunInfo.to_json` gives the very keys run.json has::

    {"format_version": 4, "created": "...", "drive": {"path", "points", "tiles"},
     "model": {"version", "mode", "threshold"}, "params": {"road", "segments", "crops", "correction"},
     "counts": {...}, "images": [...], "reconstruction": {...} (optional),
     "predicted": {"at", "previous_model"} (optional, after a model was activated in the app),
     "processing": {"tile_m", "margin_m", "workers", "scheduler", "seconds", "tiles": [...]}}
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from guardrail_core.errors import RunFolderError


@dataclass(frozen=True)
class DriveRef:
    """The drive a run was made from: its folder (absolute, as it was then), its points and
    its point tiles (the run's ``points/`` has one file per tile)."""

    path: str
    points: int
    tiles: int = 1

    def to_json(self) -> dict[str, Any]:
        return {"path": self.path, "points": self.points, "tiles": self.tiles}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> DriveRef:
        return cls(
            path=str(data["path"]), points=int(data["points"]), tiles=int(data.get("tiles", 1))
        )


@dataclass(frozen=True)
class TileOutcome:
    """What became of one processing tile.

    Attributes
    ----------
    number : the tile's number (0, 1, ... along the drive)
    station_m : (first, last) metres along the trajectory it owns (±inf at the drive's ends)
    points : points it owns
    seconds : its wall-clock seconds on its worker
    error : None, or the named error that stopped it (``"DriveFormatError: ..."``)
    """

    number: int
    station_m: tuple[float, float]
    points: int
    seconds: float
    error: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "number": self.number,
            "station_m": [_finite_or_none(v) for v in self.station_m],
            "points": self.points,
            "seconds": self.seconds,
            "error": self.error,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> TileOutcome:
        lo, hi = data["station_m"]
        return cls(
            number=int(data["number"]),
            station_m=(
                -math.inf if lo is None else float(lo),
                math.inf if hi is None else float(hi),
            ),
            points=int(data["points"]),
            seconds=float(data["seconds"]),
            error=None if data.get("error") is None else str(data["error"]),
        )


def _finite_or_none(value: float) -> float | None:
    return None if math.isinf(value) else value


@dataclass(frozen=True)
class Processing:
    """How a run was processed: tiles along the trajectory, with a margin of their neighbours.

    Attributes
    ----------
    tile_m : metres of trajectory per processing tile (None: one tile for the whole drive)
    margin_m : metres of the neighbours each tile sees on either side
    workers : Dask workers (0: in this process)
    scheduler : the Dask scheduler's address, or ``"local"`` (an embedded LocalCluster) or
        ``"none"``
    seconds : wall-clock seconds of the whole run
    tiles : what became of every tile
    """

    tile_m: float | None
    margin_m: float
    workers: int
    scheduler: str
    seconds: float
    tiles: tuple[TileOutcome, ...]

    @property
    def failed(self) -> tuple[TileOutcome, ...]:
        return tuple(t for t in self.tiles if t.error is not None)

    def to_json(self) -> dict[str, Any]:
        return {
            "tile_m": self.tile_m,
            "margin_m": self.margin_m,
            "workers": self.workers,
            "scheduler": self.scheduler,
            "seconds": self.seconds,
            "tiles": [t.to_json() for t in self.tiles],
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Processing:
        tile_m = data.get("tile_m")
        return cls(
            tile_m=None if tile_m is None else float(tile_m),
            margin_m=float(data["margin_m"]),
            workers=int(data["workers"]),
            scheduler=str(data["scheduler"]),
            seconds=float(data["seconds"]),
            tiles=tuple(TileOutcome.from_json(t) for t in data["tiles"]),
        )


@dataclass(frozen=True)
class ModelRef:
    """The classifier whose predictions a run holds: its version, mode and threshold (0..1)."""

    version: str
    mode: str
    threshold: float

    def to_json(self) -> dict[str, Any]:
        return {"version": self.version, "mode": self.mode, "threshold": self.threshold}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ModelRef:
        return cls(
            version=str(data["version"]), mode=str(data["mode"]), threshold=float(data["threshold"])
        )


@dataclass(frozen=True)
class CropCounts:
    """Segments by crop status (``segments.npz`` ``crop_status``: 0 ok, 1 no_image, 2 too_small),
    and ``asked``: the ok crops the CNN looked at (the others' label the shape decided;
    :mod:`guardrail_core.extract.classify.segment_scores`)."""

    ok: int
    no_image: int
    too_small: int
    asked: int

    def to_json(self) -> dict[str, int]:
        return {
            "ok": self.ok,
            "no_image": self.no_image,
            "too_small": self.too_small,
            "asked": self.asked,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> CropCounts:
        return cls(
            ok=int(data["ok"]),
            no_image=int(data["no_image"]),
            too_small=int(data["too_small"]),
            asked=int(data.get("asked", data["ok"])),  # runs before shape-first asked every crop
        )


@dataclass(frozen=True)
class RunCounts:
    """What the extraction found: drive points by where they went, segments and their labels.

    ``points = road_points + off_road_points + segment_points``; the guardrail counts are after
    label correction, ``guardrail_segments_raw`` before it.
    """

    points: int
    road_points: int
    off_road_points: int
    segment_points: int
    segments: int
    crops: CropCounts
    guardrail_segments_raw: int
    guardrail_segments: int
    guardrail_points: int

    def to_json(self) -> dict[str, Any]:
        return {
            "points": self.points,
            "road_points": self.road_points,
            "off_road_points": self.off_road_points,
            "segment_points": self.segment_points,
            "segments": self.segments,
            "crops": self.crops.to_json(),
            "guardrail_segments_raw": self.guardrail_segments_raw,
            "guardrail_segments": self.guardrail_segments,
            "guardrail_points": self.guardrail_points,
        }

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> RunCounts:
        return cls(
            points=int(data["points"]),
            road_points=int(data["road_points"]),
            off_road_points=int(data["off_road_points"]),
            segment_points=int(data["segment_points"]),
            segments=int(data["segments"]),
            crops=CropCounts.from_json(data["crops"]),
            guardrail_segments_raw=int(data["guardrail_segments_raw"]),
            guardrail_segments=int(data["guardrail_segments"]),
            guardrail_points=int(data["guardrail_points"]),
        )


@dataclass(frozen=True)
class ReconstructionSummary:
    """What a reconstruction wrote (:func:`guardrail_core.reconstruct.writing.reconstruct_into`).

    Attributes
    ----------
    runs : guardrail runs found; each is ``reconstructed``, ``poles_only`` or
        ``not_reconstructed`` (the inventory's statuses)
    files : the files written, relative to ``reconstruction/`` (POSIX)
    seconds : wall time of the reconstruction (without writing), None where not measured
    outdated : why the reconstruction no longer matches the run's labels (a model was activated
        since), None while it does
    """

    runs: int
    reconstructed: int
    poles_only: int
    not_reconstructed: int
    files: tuple[str, ...]
    seconds: float | None
    outdated: str | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "runs": self.runs,
            "reconstructed": self.reconstructed,
            "poles_only": self.poles_only,
            "not_reconstructed": self.not_reconstructed,
            "files": list(self.files),
            "seconds": self.seconds,
        }
        if self.outdated is not None:
            out["outdated"] = self.outdated
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> ReconstructionSummary:
        seconds = data.get("seconds")
        return cls(
            runs=int(data["runs"]),
            reconstructed=int(data["reconstructed"]),
            poles_only=int(data["poles_only"]),
            not_reconstructed=int(data["not_reconstructed"]),
            files=tuple(str(f) for f in data["files"]),
            seconds=None if seconds is None else float(seconds),
            outdated=data.get("outdated"),
        )


@dataclass(frozen=True)
class Predicted:
    """When a run's predictions were replaced by another model's, and the model before."""

    at: str
    previous_model: ModelRef | None

    def to_json(self) -> dict[str, Any]:
        previous = self.previous_model
        return {"at": self.at, "previous_model": None if previous is None else previous.to_json()}

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Predicted:
        previous = data.get("previous_model")
        return cls(
            at=str(data["at"]),
            previous_model=None if previous is None else ModelRef.from_json(previous),
        )


@dataclass(frozen=True)
class RunInfo:
    """``run.json``: the run's format version, drive, model, extraction parameters and counts.

    Attributes
    ----------
    format_version : the run folder format it was written in
    created : local time the run started, ISO 8601 (``%Y-%m-%dT%H:%M:%S%z``)
    params : every extraction parameter by stage (``ExtractionParams.to_json()``)
    images : the drive's image files, in the order ``segments.npz`` ``image`` indexes them
    reconstruction : the reconstruction's summary, where one was recorded
    predicted : set when the app activated another model on the run
    processing : the tiles it was processed in and what became of each
    """

    format_version: int
    created: str
    drive: DriveRef
    model: ModelRef
    params: Mapping[str, Any]
    counts: RunCounts
    images: tuple[str, ...]
    reconstruction: ReconstructionSummary | None = None
    predicted: Predicted | None = None
    processing: Processing | None = None

    def to_json(self) -> dict[str, Any]:
        """The run.json document (optional members only where set)."""
        out: dict[str, Any] = {
            "format_version": self.format_version,
            "created": self.created,
            "drive": self.drive.to_json(),
            "model": self.model.to_json(),
            "params": dict(self.params),
            "counts": self.counts.to_json(),
            "images": list(self.images),
        }
        if self.reconstruction is not None:
            out["reconstruction"] = self.reconstruction.to_json()
        if self.predicted is not None:
            out["predicted"] = self.predicted.to_json()
        if self.processing is not None:
            out["processing"] = self.processing.to_json()
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any], *, where: str = "run.json") -> RunInfo:
        """Inverse of :meth:`to_json` (the format version is not checked here: see
        :meth:`~guardrail_core.formats.run_folder_paths.RunFolder.info`).

        Raises
        ------
        RunFolderError
            A member is missing or of the wrong kind; the message names it and ``where``.
        """
        try:
            reconstruction = data.get("reconstruction")
            predicted = data.get("predicted")
            processing = data.get("processing")
            return cls(
                format_version=int(data["format_version"]),
                created=str(data["created"]),
                drive=DriveRef.from_json(data["drive"]),
                model=ModelRef.from_json(data["model"]),
                params=dict(data["params"]),
                counts=RunCounts.from_json(data["counts"]),
                images=tuple(str(name) for name in data["images"]),
                reconstruction=None
                if reconstruction is None
                else ReconstructionSummary.from_json(reconstruction),
                predicted=None if predicted is None else Predicted.from_json(predicted),
                processing=None if processing is None else Processing.from_json(processing),
            )
        except KeyError as exc:
            raise RunFolderError(f"{where}: expected a member {exc.args[0]!r}, found none") from exc
        except (TypeError, ValueError, AttributeError) as exc:
            raise RunFolderError(f"{where}: not a run description ({exc})") from exc
