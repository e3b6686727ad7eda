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


#: The longest a long poll of the selection waits (seconds): below the idle timeouts of
#: proxies, so that a page behind one keeps its connection.
MAX_WAIT_S = 25.0


class SelectionBody(BaseModel):
    segments: list[SegmentId] = Field(max_length=100_000)


@router.get("/queue", response_model=Queue, responses=NOT_FOUND)
def get_queue(
    session: Session,
    limit: Annotated[int, Query(ge=1, le=500)] = 20,
    run: Annotated[
        int | None,
        Query(
            ge=0,
            le=2**31 - 1,
            description="review this run: its doubtful unreviewed segments in order along the "
            "road (a run of GET /api/overview)",
        ),
    ] = None,
) -> dict[str, Any]:
    """The segments the queue asks about, most worth a look first (disagreement, then
    uncertainty), and how far the review is; with ``run``, that guardrail run's in order along
    the road."""
    try:
        return review_queue(session, limit, run)
    except KeyError as exc:
        raise HTTPException(404, detail=str(exc.args[0])) from exc


def _selection(session: ReviewSession) -> dict[str, Any]:
    with session.lock:
        return {
            "segments": [int(s) for s in session.selection],
            "lasso_points": len(session.lasso),
            "version": session.selection_watch.version,
        }


@router.get("/queue/off-runs", response_model=Queue)
def get_queue_off_runs(
    session: Session, limit: Annotated[int, Query(ge=1, le=500)] = 20
) -> dict[str, Any]:
    """The guardrail segments on no reconstructed run (a run without poles, a rail beyond its end
    poles, a mistake), unreviewed, of 10 points or more, in order along the road: what the route
    table cannot reach."""
    return review_queue(session, limit, off_runs=True)


@router.get("/selection", response_model=Selection)
async def get_selection(
    session: Session,
    after: Annotated[
        int | None,
        Query(
            ge=0,
            le=2**53,
            description="a long poll: answer when the selection's version is no longer this one "
            "(a click in the 3D view changed it), or after wait_s seconds",
        ),
    ] = None,
    wait_s: Annotated[float, Query(ge=0, le=MAX_WAIT_S)] = 0.0,
) -> dict[str, Any]:
    """The selected segments and, when a lasso in the 3D view made the selection, how many of
    their points it took."""
    if after is not None and wait_s > 0:
        await session.selection_watch.wait_past(after, wait_s)
    return _selection(session)


@router.put("/selection", response_model=Selection, responses=NOT_FOUND)
def put_selection(session: Session, body: SelectionBody) -> dict[str, Any]:
    """Select segments (the 3D view highlights them and flies to the first); a lasso's points
    are let go."""
    try:
        session.select(body.segments)
    except KeyError as exc:
        raise HTTPException(404, detail=str(exc.args[0])) from exc
    return _selection(session)


@router.post("/lasso/cancel", response_model=Selection)
def cancel_lasso(session: Session) -> dict[str, Any]:
    """Cancel a lasso: one being drawn in the 3D view stops taking clicks as corners, and the
    points one took are let go (their segments stay selected). The page sends it when it
    loads and on Escape."""
    session.cancel_lasso()
    return _selection(session)
