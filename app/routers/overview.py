"""The route overview: the trajectory and every guardrail run with its review progress."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends

from app.dependencies import get_session
from app.route_overview import route_overview
from app.schemas import RouteOverview
from app.session import ReviewSession

router = APIRouter(prefix="/api/overview", tags=["overview"])
Session = Annotated[ReviewSession, Depends(get_session)]


@router.get("", response_model=RouteOverview)
def get_overview(session: Session) -> dict[str, Any]:
    """The trajectory (local metres, thinned for a map) and every reconstructed guardrail run in
    order along the drive: its inventory facts, its poles' line, and how many of its segments
    the operators reviewed and changed, with the segment to fly to."""
    return route_overview(session)
