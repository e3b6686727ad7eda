"""The review queue and the selection shared with the 3D scene."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Query
from pydantic import BaseModel, Field

from app.dependencies import get_session
from app.schemas import NOT_FOUND, Queue, SegmentId, Selection
from app.segment_views import review_queue
from app.session import ReviewSession

router = APIRouter(prefix="/api", tags=["review"])
Session = Annotated[ReviewSession, Depends(get_session)]


class SelectionBody(BaseModel):
    segments: list[SegmentId] = Field(max_length=100_000)


@router.get("/queue", response_model=Queue)
def get_queue(session: Session, limit: Annotated[int, Query(ge=1, le=500)] = 20) -> dict[str, Any]:
    """Unreviewed segments, most worth a look first (disagreement, then uncertainty)."""
    return {"items": review_queue(session, limit)}


@router.get("/selection", response_model=Selection)
def get_selection(session: Session) -> dict[str, Any]:
    return {"segments": [int(s) for s in session.selection]}


@router.put("/selection", response_model=Selection, responses=NOT_FOUND)
def put_selection(session: Session, body: SelectionBody) -> dict[str, Any]:
    """Select segments (the 3D view highlights them and flies to the first)."""
    try:
        ids = session.select(body.segments)
    except KeyError as exc:
        raise HTTPException(404, detail=str(exc.args[0])) from exc
    return {"segments": [int(s) for s in ids]}
