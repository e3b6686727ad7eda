"""The REST API's responses as pydantic models: what ``/openapi.json`` tells the pages.

Every JSON route names one of these as its ``response_model``; the routes still build plain dicts
and FastAPI checks them against the model on the way out. The models forbid fields they do not
name, so a field a route adds without its model fails the app's tests instead of vanishing from
the answer. Routes whose objects leave a field out where it does not apply (an older model
folder's metrics, the run's model with no folder) answer with ``response_model_exclude_unset``,
so a field the route did not set stays absent rather than becoming ``null``.

The fields are in the order of the dicts the routes build: the JSON is what it was before the
models (compared route by route, with a drive, a run, labels, a training and a reconstruction).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from app.params_models import NOT_A_SWITCH, stages_model
from guardrail_core.reconstruct.pipeline import ReconstructionParams

#: An operator's or a model's label of a segment.
LabelName = Literal["guardrail", "other"]
#: Why a segment has a crop or not (:data:`guardrail_core.formats.run_folder.CROP_STATUS_NAMES`).
CropStatusName = Literal["ok", "no_image", "too_small"]


class ResponseModel(BaseModel):
    """Base of the responses: unknown fields are an error (see the module docstring)."""

    model_config = ConfigDict(extra="forbid")


class ErrorDetail(BaseModel):
    """An error's answer (401, 404, 409, 422 from a route): what went wrong, in words."""

    detail: str


def file_response(media_types: Iterable[str], description: str) -> dict[int | str, Any]:
    """``responses=`` of a route that sends a file: its 200 answer's media types, a file each."""
    file = {"schema": {"type": "string", "format": "binary"}}
    return {200: {"description": description, "content": dict.fromkeys(media_types, file)}}


def error_response(status: int, description: str) -> dict[int | str, Any]:
    """``responses=`` of a route that answers ``status`` with an :class:`ErrorDetail`."""
    return {status: {"model": ErrorDetail, "description": description}}


#: The largest segment id a request may carry: 2**53, the largest integer a JSON number (a double)
#: holds exactly, so the schema states its bound exactly too; far inside int64 (a larger id is a
#: 422, not an overflow; one the run does not have is a 404).
MAX_SEGMENT_ID = 2**53
#: ``true`` is not segment 1.
SegmentId = Annotated[int, Field(ge=-MAX_SEGMENT_ID, le=MAX_SEGMENT_ID), NOT_A_SWITCH]

JPEG = file_response(["image/jpeg"], "The image (JPEG)")
PNG = file_response(["image/png"], "The image (PNG)")
NOT_FOUND = error_response(404, "No such object (the detail names it)")
CONFLICT = error_response(409, "The state does not allow it now (the detail says why)")
UNAUTHORIZED = error_response(401, "The server needs its token (Authorization: Bearer or ?token=)")
#: What app.request_guard answers before a route runs (state changes: 403, 413, 415).
GUARDED = {
    **error_response(400, "The request addressed a host name this server does not answer"),
    **error_response(403, "A state change from a page of another origin"),
    **error_response(413, "The body is over the size limit"),
    **error_response(415, "A state change without Content-Type: application/json"),
}


# -- info ---------------------------------------------------------------------------------------


class LabelCounts(ResponseModel):
    """Operator labels in the label store, by drive point."""

    labelled_points: int
    guardrail_points: int
    other_points: int
    batches: int = Field(description="label batches of both kinds (labellings and undos)")


class StoredMetrics(BaseModel):
    """Figures read from model folders of any version: fields this version does not know are
    kept, and those an older version did not write stay absent."""

    model_config = ConfigDict(extra="allow")


class ClassMetrics(StoredMetrics):
    """One class's figures on the held-out segments; a ratio without a denominator is null."""

    recall: float | None = None
    precision: float | None = None
    f1: float | None = None
    n: int | None = Field(default=None, description="held-out segments of this class")


class HeldOutMetrics(StoredMetrics):
    """A model's figures on held-out segments (§3.3)."""

    guardrail: ClassMetrics | None = None
    other: ClassMetrics | None = None
    accuracy: float | None = None
    n_train: int | None = None
    n_held_out: int | None = Field(default=None, description="segments measured")
    n_groups_held_out: int | None = None
    threshold: float | None = Field(default=None, description="probability cut, 0..1")
    n_reviewed_held_out: int | None = Field(
        default=None, description="measured segments an operator reviewed (app training only)"
    )
    against: str | None = Field(
        default=None, description="which labels the figures are measured against"
    )
    note: str | None = None
    model: str | None = Field(default=None, description="the model measured (current model)")


class ModelRow(ResponseModel):
    """One model an operator can activate."""

    version: str
    created: str | None = Field(description="ISO 8601; null for the run's model without folder")
    mode: str | None = Field(description="'fast' (head on embeddings) or 'full'")
    held_out: HeldOutMetrics | None
    held_out_current: HeldOutMetrics | None = Field(
        description="the model it was compared with, measured on the same segments"
    )
    trained_on: dict[str, Any] | None = Field(
        default=None, description="what it was trained on; absent when its folder is not known"
    )
    active: bool = Field(description="its predictions are the run's")
    folder_known: bool = Field(description="its folder is known, so it can be activated again")


class ModelMetrics(ResponseModel):
    held_out: HeldOutMetrics | None


class ActiveModel(ResponseModel):
    """The model whose predictions the run holds (a :class:`ModelRow` and its metrics)."""

    version: str
    created: str | None = None
    mode: str | None = None
    held_out: HeldOutMetrics | None = None
    held_out_current: HeldOutMetrics | None = None
    trained_on: dict[str, Any] | None = None
    active: bool | None = None
    folder_known: bool | None = None
    metrics: ModelMetrics


class Info(ResponseModel):
    """What is being reviewed, by whom, and where the 3D scene is."""

    drive: str = Field(description="the drive folder")
    run: str = Field(description="the run folder")
    n_points: int = Field(description="points of the drive")
    n_segments: int
    reviewed_segments: int = Field(description="segments with an operator label")
    label_counts: LabelCounts
    operator: str = Field(description="the name recorded with each label by default")
    model: ActiveModel
    scene_url: str | None = Field(description="the viser 3D scene; null without one")
    scene_clients: int = Field(description="browsers connected to the 3D scene")
    token_required: bool


# -- segments and labels ------------------------------------------------------------------------


class HistoryEntry(ResponseModel):
    """One label batch's change of one (old, new) pair of labels."""

    batch: int
    at: str = Field(description="ISO 8601, UTC")
    who: str
    model_version: str | None = Field(description="the model whose proposal was reviewed")
    kind: Literal["label", "undo"]
    old: LabelName | None = Field(description="null: the points were unlabelled")
    new: LabelName | None = Field(description="null: the points became unlabelled (an undo)")
    n_points: int = Field(description="points changed (of the segment asked for, when one was)")
    segments: list[int] = Field(description="the segments the operator selected")
    note: str
    undone: bool
    undoes: int | None = Field(description="for an undo, the batch it reverted")


class Segment(ResponseModel):
    """A segment of the run (a slice of a connected wireframe run, §3.1) and its labels."""

    id: int
    n_points: int
    centroid: list[float] = Field(description="x, y, z in metres, drive frame")
    slice_index: int
    component: int = Field(description="the connected run it belongs to")
    crop_status: CropStatusName
    crop_url: str | None = Field(description="its crop (JPEG); null when it has none")
    probability: float | None = Field(
        description="the model's guardrail probability, 0..1; null without a crop"
    )
    raw_label: LabelName = Field(description="the model's label before correction")
    model_label: LabelName = Field(description="the model's label after correction (§3.3)")
    label: LabelName = Field(description="the operator's label where reviewed, else model_label")
    reviewed: bool
    truth: LabelName | None = Field(description="the simulated truth; null for real drives")


class SegmentDetail(Segment):
    """One segment with its camera image, rectangle and latest label history."""

    image: str | None = Field(description="the camera image of its crop")
    image_id: int | None = Field(
        description="that image's id (GET /api/images/{image_id}/overlay); null without one"
    )
    rect: list[int] = Field(description="x0, y0, x1, y1 of its crop in that image, pixels")
    history: list[HistoryEntry] = Field(description="newest first, at most 20")


class Picked(ResponseModel):
    """The segment at a pixel of a camera image."""

    image: int = Field(description="the image's id")
    segment: int | None = Field(
        description="the segment whose point nearest the camera lies within a few pixels; null "
        "where none does"
    )


class HistogramPipe(ResponseModel):
    """A pipe of the re-run unit model, by where it lies along the unit."""

    kind: str = Field(description="horizontal, vertical, diagonal or curved")
    x_min_m: float = Field(description="its axis's smallest x, metres along the unit")
    x_max_m: float = Field(description="its axis's largest x, metres along the unit")
    radius_m: float


class RunHistogram(ResponseModel):
    """The numbers behind a run's unit-model thresholds (§4.3, Fig. 14): the x histogram of the
    superimposed points with its threshold and the pipes found, or a beam's section curve."""

    run_id: int
    type: str = Field(description="pipe or beam")
    histogram_factor: float = Field(description="the threshold's factor of the median count")
    bin_m: float = Field(description="the bins' width, metres")
    x_m: list[float] | None = Field(description="bin centres, metres along the unit (pipes)")
    counts: list[int] | None = Field(description="superimposed points per bin, poles left out")
    threshold: float | None = Field(description="points per bin above which vertical pipes lie")
    pipes: list[HistogramPipe] = Field(description="the pipes found with these thresholds")
    section: list[list[float]] | None = Field(
        description="the beam's section curve, [z, y] metres (beams)"
    )


class RouteRun(ResponseModel):
    """A reconstructed guardrail run on the route, with the operators' progress on it."""

    run_id: int
    status: str = Field(description="reconstructed, poles only (the inventory's status)")
    type: str = Field(description="pipe, beam or unknown")
    signature: str | None = Field(description="the design in words (pipes or beam section)")
    length_m: float | None = Field(description="metres between its first and last pole")
    poles: int
    station_m: float = Field(description="metres along the drive where it starts")
    path: list[list[float]] = Field(description="its poles in order, [x, y] local metres")
    segments: int = Field(
        description="segments on it that the model or an operator calls guardrail, or reviewed"
    )
    reviewed: int = Field(description="of them, those an operator labelled")
    changed: int = Field(description="of the reviewed, those whose label the operator changed")
    asked: int = Field(description="of them, those the review queue still asks about")
    progress: float = Field(
        description="reviewed / (reviewed + asked): the share of what the queue asks or asked "
        "about that is labelled (1 when it asks nothing)"
    )
    state: Literal["unreviewed", "started", "done"] = Field(
        description="'done': the queue asks nothing more about it; 'started': some of it is "
        "labelled; 'unreviewed': none"
    )
    segment: int | None = Field(
        description="the segment to fly to: its most doubtful unreviewed one, else its first"
    )


class RouteOverview(ResponseModel):
    """The route at a glance: the trajectory and every reconstructed run along it."""

    trajectory: list[list[float]] = Field(description="[x, y] local metres, thinned for a map")
    length_m: float = Field(description="metres driven")
    runs: list[RouteRun] = Field(description="in order along the drive")
    segments_off_runs: int = Field(
        description="segments the model or an operator calls guardrail, or reviewed, that lie "
        "on no reconstructed run (runs without poles, rails beyond their end poles, mistakes)"
    )
    asked: int = Field(description="segments the review queue asks about, in the whole drive")
    reviewed: int = Field(description="segments an operator labelled, in the whole drive")


class SegmentPage(ResponseModel):
    """One page of the filtered, sorted segments."""

    total: int = Field(description="segments passing the filters")
    offset: int
    limit: int
    items: list[Segment]


class Relabelled(ResponseModel):
    """What a labelling or an undo changed."""

    batch: int | None = Field(description="the batch recorded; null when nothing was undone")
    undone_batch: int | None = Field(description="for an undo, the batch it reverted")
    changed_points: int
    segments: list[Segment] = Field(description="segments whose label may have changed")


class History(ResponseModel):
    items: list[HistoryEntry]


# -- review queue and selection -----------------------------------------------------------------


class QueueItem(Segment):
    """An unreviewed segment worth a look."""

    reason: Literal["disagrees", "unchecked", "uncertain"] = Field(
        description="'disagrees': the correction changed the model's label; 'unchecked': the "
        "segment stands for a guardrail run (5 or more guardrail segments of a wireframe "
        "piece) no operator has looked at yet; 'uncertain': the model's P(guardrail) lies "
        "between 5 % and 95 %"
    )
    score: float = Field(
        description="the change a decision is expected to make: uncertainty (1 at p = 0.5) "
        "weighted by the points it moves and by 1.5 where it joins or splits a guardrail run, "
        "+ 1 when it disagrees, + 1 for an unchecked run"
    )


class Queue(ResponseModel):
    """What the review queue asks, and how far the review is (in the whole drive, or in one
    guardrail run with ``?run=``)."""

    items: list[QueueItem] = Field(description="the first ``limit`` segments to ask about")
    asked: int = Field(
        description="segments the queue asks about: unreviewed, 10 points or more, and "
        "disagreeing, unchecked, or with P(guardrail) between 5 % and 95 %"
    )
    reviewed: int = Field(description="segments an operator has labelled")
    done: bool = Field(description="nothing is left to ask: the review is done")


class Selection(ResponseModel):
    segments: list[int] = Field(description="the selected segment ids, shared with the 3D view")
    lasso_points: int = Field(
        description="the points a lasso in the 3D view took (0: whole segments are selected); "
        "POST /api/labels/lasso labels them"
    )
    version: int = Field(
        description="counts the changes of the selection: GET /api/selection?after=VERSION "
        "answers when it moves"
    )


# -- jobs and models ----------------------------------------------------------------------------


class JobStarted(ResponseModel):
    job: str = Field(description="the job id: poll /api/jobs/{job}")


class TrainResult(ResponseModel):
    """A fine-tuning job's result: the new model (saved, not active) against the current one."""

    version: str
    metrics_new: HeldOutMetrics | None
    metrics_current: HeldOutMetrics | None
    current_version: str
    held_out_segments: int
    seconds: float


class ReconstructionSummary(ResponseModel):
    """Guardrail runs by status, and the files written."""

    runs: int
    reconstructed: int
    poles_only: int
    not_reconstructed: int
    files: list[str] = Field(description="paths inside the run's reconstruction folder")
    seconds: float


class ReconstructResult(ResponseModel):
    summary: ReconstructionSummary


class Job(ResponseModel):
    """A background job of this server."""

    id: str
    kind: Literal["train", "reconstruct"]
    status: Literal["queued", "running", "done", "failed", "cancelled"]
    progress: float = Field(description="0..1")
    message: str
    error: str | None = Field(description="what failed, as the program says it")
    advice: str | None = Field(
        default=None, description="what failed and what to do, in an operator's words"
    )
    result: TrainResult | ReconstructResult | None = Field(description="when done")


class JobList(ResponseModel):
    items: list[Job] = Field(description="newest first")


class ModelList(ResponseModel):
    active: str = Field(description="the active model's version")
    models: list[ModelRow] = Field(description="newest first")


class Activated(ResponseModel):
    active: str
    changed_segments: int = Field(description="segments whose label changed")


# -- reconstruction -----------------------------------------------------------------------------


class Download(ResponseModel):
    name: str
    bytes: int
    url: str


class Downloads(ResponseModel):
    items: list[Download]


class ReconstructionRun(ResponseModel):
    """One reconstructed guardrail run."""

    run_id: int
    type: str | None = Field(description="the guardrail type; null when not reconstructed")
    poles: int
    units: int
    notes: list[str] = Field(description="what could not be reconstructed, in words")


if TYPE_CHECKING:  # built at run time from the stages' declarations
    ReconstructionStages = BaseModel
else:
    ReconstructionStages = stages_model(
        "ReconstructionStages",
        ReconstructionParams.stage_classes(),
        "The reconstruction's parameters by stage, as in models.json; each field's description "
        "gives its unit and range.",
    )


class Reconstruction(ResponseModel):
    params: ReconstructionStages = Field(description="the parameters by stage, as in models.json")
    runs: list[ReconstructionRun]
    present: bool = Field(description="false: not reconstructed yet (params are the defaults)")
