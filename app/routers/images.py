"""The drive's camera images with the run's points on them, and picking a segment there."""

from __future__ import annotations

from typing import Annotated

import numpy as np
from fastapi import APIRouter, Depends, HTTPException, Query
from fastapi.responses import Response

from app.dependencies import get_session
from app.image_overlay import PICK_RADIUS_PX, encode_png
from app.schemas import NOT_FOUND, PNG, Picked
from app.session import ReviewSession
from guardrail_core.errors import MissingDriveFileError

router = APIRouter(prefix="/api/images", tags=["images"])
Session = Annotated[ReviewSession, Depends(get_session)]


def _image(session: ReviewSession, image_id: int) -> int:
    n = len(session.overlay)
    if not 0 <= image_id < n:
        raise HTTPException(404, detail=f"no image {image_id} (the drive has {n})")
    return image_id


@router.get("/{image_id}/overlay", response_class=Response, responses={**PNG, **NOT_FOUND})
def get_overlay(
    session: Session,
    image_id: int,
    segment: Annotated[int | None, Query(description="the segment to outline")] = None,
) -> Response:
    """The camera image with every point a crop of it may hold, coloured by label (orange
    guardrail, blue other, grey road and off the road), the segment outlined in magenta (PNG)."""
    i = _image(session, image_id)
    if segment is not None and not 0 <= segment < session.n_segments:
        raise HTTPException(404, detail=f"no segment {segment} (the run has {session.n_segments})")
    try:
        picture = session.overlay.render(i, session.effective_label(), segment)
    except MissingDriveFileError as exc:  # the drive's image went away while serving
        raise HTTPException(404, detail=f"image {i}: {exc}") from exc
    return Response(encode_png(picture), media_type="image/png")


@router.get("/{image_id}/pick", response_model=Picked, responses=NOT_FOUND)
def pick(
    session: Session,
    image_id: int,
    x: Annotated[float, Query(ge=0, description="column, image pixels")],
    y: Annotated[float, Query(ge=0, description="row, image pixels")],
    radius: Annotated[
        float,
        Query(
            ge=0.5,
            le=200,
            description="image pixels a point may lie from (x, y): the page sends a few screen "
            "pixels' worth at the scale it shows the image",
        ),
    ] = PICK_RADIUS_PX,
) -> dict[str, int | None]:
    """The segment whose point, nearest the camera, lies within ``radius`` pixels of (x, y) on
    the image; null where none does."""
    i = _image(session, image_id)
    width, height = session.overlay.size(i)
    if not (np.isfinite(x) and np.isfinite(y) and x < width and y < height):
        # In the shape of FastAPI's own validation errors, as the schema says a 422 is.
        where = "x" if not (np.isfinite(x) and x < width) else "y"
        message = f"({x}, {y}) lies outside the {width} x {height} px image"
        raise HTTPException(
            422, detail=[{"loc": ["query", where], "msg": message, "type": "value_error"}]
        )
    return {"image": i, "segment": session.overlay.pick(i, x, y, radius)}
