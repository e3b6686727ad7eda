"""What is being reviewed, and where the 3D scene is."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, Request

from app.dependencies import get_session
from app.schemas import Info
from app.session import ReviewSession

router = APIRouter(prefix="/api", tags=["info"])
Session = Annotated[ReviewSession, Depends(get_session)]


@router.get("/info", response_model=Info, response_model_exclude_unset=True)
def get_info(session: Session, request: Request) -> dict[str, Any]:
    """The drive, the run, the active model and the URL of the 3D scene (viser)."""
    info = session.describe()
    version = session.models.active_version
    try:
        model = session.models.info(version)
    except KeyError:
        model = {"version": version}
    host = request.url.hostname or "127.0.0.1"
    scene_port = request.app.state.scene_port
    info.update(
        model={**model, "metrics": {"held_out": model.get("held_out")}},
        scene_url=f"http://{host}:{scene_port}" if scene_port else None,
        scene_clients=request.app.state.scene_clients(),
        token_required=request.app.state.token is not None,
    )
    return info
