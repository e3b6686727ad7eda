"""Operator labels: one segment, a batch (or whole connected runs), a lasso's points, undo."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, HTTPException, Path
from pydantic import BaseModel, Field

from app.dependencies import get_session
from app.schemas import CONFLICT, MAX_SEGMENT_ID, NOT_FOUND, History, Relabelled, SegmentId
from app.segment_views import segment_rows
from app.session import Relabel, ReviewSession
from guardrail_core.errors import InvalidOptionError

router = APIRouter(prefix="/api", tags=["labels"])
Session = Annotated[ReviewSession, Depends(get_session)]
LabelName = Literal["guardrail", "other"]


class LabelBody(BaseModel):
    label: LabelName
    who: str | None = Field(default=None, max_length=100)


class BatchBody(BaseModel):
    segments: list[SegmentId] = Field(min_length=1, max_length=100_000)
    label: LabelName
    expand: Literal["none", "component"] = "none"
    who: str | None = Field(default=None, max_length=100)


class UndoBody(BaseModel):
    who: str | None = Field(default=None, max_length=100)


def _answer(session: ReviewSession, done: Relabel) -> dict[str, Any]:
    change = done.change
    return {
        "batch": None if change is None else change.batch,
        "undone_batch": None if change is None else change.undone_batch,
        "changed_points": 0 if change is None else change.n_points,
        "segments": segment_rows(session, done.segments),
    }


def _relabel(session: ReviewSession, ids: list[int], body: LabelBody | BatchBody, expand: str):
    try:
        return _answer(session, session.relabel(ids, body.label, who=body.who, expand=expand))
    except KeyError as exc:
        raise HTTPException(404, detail=str(exc.args[0])) from exc


@router.put("/segments/{segment_id}/label", response_model=Relabelled, responses=NOT_FOUND)
def put_label(
    session: Session,
    segment_id: Annotated[int, Path(ge=-MAX_SEGMENT_ID, le=MAX_SEGMENT_ID)],
    body: LabelBody,
) -> dict[str, Any]:
    """Label every point of one segment."""
    return _relabel(session, [segment_id], body, "none")


@router.post("/labels/batch", response_model=Relabelled, responses=NOT_FOUND)
def post_batch(session: Session, body: BatchBody) -> dict[str, Any]:
    """Label many segments (or, with ``expand="component"``, their whole connected runs)."""
    return _relabel(session, body.segments, body, body.expand)


@router.post("/labels/lasso", response_model=Relabelled, responses=CONFLICT)
def post_lasso(session: Session, body: LabelBody) -> dict[str, Any]:
    """Label the points the last lasso in the 3D view took (not their whole segments); 409
    when no lasso is selected."""
    try:
        return _answer(session, session.relabel_lasso(body.label, who=body.who))
    except InvalidOptionError as exc:
        raise HTTPException(409, detail=str(exc)) from exc


@router.post("/labels/undo", response_model=Relabelled)
def post_undo(session: Session, body: UndoBody | None = None) -> dict[str, Any]:
    """Revert the last labelling (of ``who`` when given)."""
    return _answer(session, session.undo(who=body.who if body else None))


@router.get("/labels/history", response_model=History)
def get_history(session: Session, limit: int = 50) -> dict[str, Any]:
    """The latest label batches, newest first."""
    return {"items": session.store.history(limit=max(1, min(limit, 1000)))}
