"""The reconstruction: its files to download, its parameters, and re-running it."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse
from pydantic import BaseModel, ConfigDict, Field

from app import review_jobs
from app.dependencies import get_jobs, get_session
from app.jobs import JobBusyError, JobRunner
from app.params_models import given_values
from app.schemas import (
    CONFLICT,
    NOT_FOUND,
    Downloads,
    JobStarted,
    Reconstruction,
    ReconstructionStages,
    file_response,
)
from app.session import ReviewSession
from guardrail_core.errors import InvalidOptionError, NoReconstructionError, RunFolderError
from guardrail_core.formats.run_folder_paths import RunFolder
from guardrail_core.reconstruct.pipeline import ReconstructionParams
from guardrail_core.reconstruct.run_models import load_run_models

router = APIRouter(prefix="/api", tags=["reconstruction"])
Session = Annotated[ReviewSession, Depends(get_session)]
Jobs = Annotated[JobRunner, Depends(get_jobs)]

MEDIA_TYPES = {
    ".glb": "model/gltf-binary",
    ".ply": "application/octet-stream",
    ".obj": "text/plain",
    ".geojson": "application/geo+json",
    ".csv": "text/csv",
}


def downloadable(run: RunFolder) -> dict[str, Path]:
    """Name -> file of everything the reconstruction offers for download (the only files the
    download route serves: a request names a key of this table, never a path)."""
    files = run.reconstruction.output_files()
    return {name: path for name, path in files.items() if path.suffix in MEDIA_TYPES}


@router.get("/downloads", response_model=Downloads)
def list_downloads(session: Session) -> dict[str, Any]:
    """The meshes (GLB, PLY, OBJ) and the inventory (GeoJSON, CSV) of the reconstruction."""
    return {
        "items": [
            {"name": name, "bytes": path.stat().st_size, "url": f"/api/downloads/{name}"}
            for name, path in downloadable(session.folder).items()
        ]
    }


@router.get(
    "/downloads/{name:path}",
    response_class=FileResponse,
    responses={**file_response(MEDIA_TYPES.values(), "the file"), **NOT_FOUND},
)
def get_download(session: Session, name: str) -> FileResponse:
    """One file of ``/api/downloads``: a mesh or the inventory, by its name there."""
    path = downloadable(session.folder).get(name)
    if path is None:
        raise HTTPException(404, detail=f"no download {name!r}; see /api/downloads")
    return FileResponse(path, media_type=MEDIA_TYPES[path.suffix], filename=Path(name).name)


@router.get("/reconstruction", response_model=Reconstruction, responses=CONFLICT)
def get_reconstruction(session: Session) -> dict[str, Any]:
    """The reconstruction's parameters and, per run, its type, units and notes; 409 when the
    run's reconstruction cannot be read (another format version, damaged: reconstruct again)."""
    try:
        models = load_run_models(session.folder)
    except NoReconstructionError:
        return {"params": ReconstructionParams().to_json(), "runs": [], "present": False}
    except RunFolderError as exc:
        raise HTTPException(409, detail=str(exc)) from exc
    runs = [
        {
            "run_id": r.run_id,
            "type": None if r.model is None else r.model.type,
            "poles": len(r.poles),
            "units": len(r.units),
            "notes": list(r.notes),
        }
        for r in models.runs
    ]
    return {"params": models.params.to_json(), "runs": runs, "present": True}


class ApplyBody(BaseModel):
    model_config = ConfigDict(extra="forbid")

    params: ReconstructionStages = Field(
        default_factory=ReconstructionStages,
        description="the stages and names to change; the others keep their defaults",
    )


@router.post(
    "/reconstruction/apply", status_code=202, response_model=JobStarted, responses=CONFLICT
)
def post_apply(session: Session, jobs: Jobs, body: ApplyBody) -> dict[str, Any]:
    """Reconstruct every guardrail again from the current labels with these parameters (by
    stage, as in ``models.json``; missing ones keep their defaults); poll the job."""
    given = given_values(body.params)
    try:
        params = ReconstructionParams.from_json(given)
    except InvalidOptionError as exc:  # a rule between fields, which the schema cannot state
        error = {"loc": ("body", "params"), "msg": str(exc), "type": "value_error", "input": given}
        raise RequestValidationError([error]) from exc
    try:
        return {"job": jobs.submit("reconstruct", review_jobs.reconstruct(session, params)).id}
    except JobBusyError as exc:
        raise HTTPException(409, detail=str(exc)) from exc
