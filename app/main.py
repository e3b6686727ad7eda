"""The FastAPI application: assembles the routers, the token check and the static pages."""

from __future__ import annotations

from collections.abc import Callable, Collection
from pathlib import Path

from fastapi import Depends, FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import RedirectResponse
from fastapi.staticfiles import StaticFiles

from app.auth import require_token
from app.jobs import JobRunner
from app.request_guard import RequestGuard
from app.routers import (
    images,
    info,
    labels,
    overview,
    queue,
    reconstruction,
    runs,
    segments,
    training,
)
from app.schemas import GUARDED, UNAUTHORIZED
from app.session import ReviewSession
from app.validation_errors import validation_error_response

#: The pages (``static/`` at the repository root, beside ``app/``).
STATIC_DIR = Path(__file__).resolve().parent.parent / "static"


def create_app(
    session: ReviewSession,
    *,
    token: str | None = None,
    jobs: JobRunner | None = None,
    scene_port: int | None = None,
    scene_clients: Callable[[], int] = lambda: 0,
    allowed_hosts: Collection[str] | None = None,
) -> FastAPI:
    """The review app for one session.

    Parameters
    ----------
    session : the drive, run and labels under review
    token : when set, every ``/api`` call must carry it
    jobs : the background job runner (a new one by default)
    scene_port : the viser server's port, for the pages' 3D view
    scene_clients : how many browsers the 3D scene has connected (for ``/api/info``)
    allowed_hosts : the host names requests may address (:mod:`app.request_guard`); None
        answers any name (tests)
    """
    app = FastAPI(
        title="Guardrail review",
        description="Review guardrail detections, fix labels, fine-tune the classifier and "
        "tune the reconstruction (Matsumoto et al. 2019).",
        version="1",
    )
    app.state.session = session
    app.state.token = token
    app.state.jobs = jobs or JobRunner()
    app.state.scene_port = scene_port
    app.state.scene_clients = scene_clients
    app.add_middleware(RequestGuard, allowed_hosts=allowed_hosts)
    app.add_exception_handler(RequestValidationError, validation_error_response)
    guarded = [Depends(require_token)]
    for module in (info, segments, images, labels, queue, training, reconstruction, runs, overview):
        app.include_router(
            module.router, dependencies=guarded, responses={**UNAUTHORIZED, **GUARDED}
        )
    if STATIC_DIR.is_dir():
        app.mount("/static", StaticFiles(directory=STATIC_DIR), name="static")

    def page(name: str) -> Callable[[Request], RedirectResponse]:
        def redirect(request: Request) -> RedirectResponse:
            query = request.url.query  # keeps ?token= for the page's API calls
            return RedirectResponse(f"/static/{name}" + (f"?{query}" if query else ""))

        return redirect

    app.get("/", include_in_schema=False)(page("index.html"))
    app.get("/gallery", include_in_schema=False)(page("gallery.html"))

    return app
