"""Segments: paged and filtered lists, one segment with its history, its crop."""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Query
from fastapi.responses import Response

from app.dependencies import get_session
from app.schemas import JPEG, NOT_FOUND, SegmentDetail, SegmentPage
from app.segment_views import filter_segments, segment_rows
from app.session import ReviewSession
from guardrail_core.errors import MissingDriveFileError

router = APIRouter(prefix="/api/segments", tags=["segments"])
Session = Annotated[ReviewSession, Depends(get_session)]


def _segment(session: ReviewSession, segment_id: int) -> int:
    if not 0 <= segment_id < session.n_segments:
        raise HTTPException(
            404, detail=f"no segment {segment_id} (the run has {session.n_segments})"
        )
    return segment_id


@router.get("", response_model=SegmentPage)
def list_segments(
    session: Session,
    offset: Annotated[int, Query(ge=0)] = 0,
    limit: Annotated[int, Query(ge=1, le=1000)] = 100,
    label: Literal["guardrail", "other"] | None = None,
    reviewed: bool | None = None,
    crop: bool | None = None,
    min_probability: Annotated[float | None, Query(ge=0, le=1)] = None,
    max_probability: Annotated[float | None, Query(ge=0, le=1)] = None,
    sort: Literal["id", "uncertainty", "probability", "-probability"] = "id",
) -> dict[str, Any]:
    """Segments of the run, filtered, sorted and paged."""
    ids = filter_segments(
        session,
        label=label,
        reviewed=reviewed,
        crop=crop,
        min_probability=min_probability,
        max_probability=max_probability,
        sort=sort,
    )
    page = ids[offset : offset + limit]
    return {
        "total": len(ids),
        "offset": offset,
        "limit": limit,
        "items": segment_rows(session, page),
    }


@router.get("/{segment_id}", response_model=SegmentDetail, responses=NOT_FOUND)
def get_segment(session: Session, segment_id: int) -> dict[str, Any]:
    """One segment with its image, rectangle and label history."""
    s = _segment(session, segment_id)
    row = segment_rows(session, np.array([s]))[0]
    image = int(session.run.segments["image"][s])
    points = session.tiles.points_of([s])
    row.update(
        image=session.run.info.images[image] if image >= 0 else None,
        image_id=image if image >= 0 else None,
        rect=[int(v) for v in session.run.segments["rect"][s]],
        history=session.store.history(points=points, limit=20),
    )
    return row


@router.get("/{segment_id}/crop.jpg", response_class=Response, responses={**JPEG, **NOT_FOUND})
def get_crop(session: Session, segment_id: int) -> Response:
    """The crop the classifier sees (JPEG), cut from the drive's image; 404 for a segment
    without one."""
    s = _segment(session, segment_id)
    if not session.crops.has_crop(s):
        raise HTTPException(404, detail=f"segment {s} has no crop")
    try:
        data = session.crop_jpeg(s)
    except MissingDriveFileError as exc:  # the drive's image went away while serving
        raise HTTPException(404, detail=f"segment {s}: {exc}") from exc
    return Response(data, media_type="image/jpeg")
