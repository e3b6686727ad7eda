"""The reconstruction: its files to download, its parameters, and re-running it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException
from fastapi.responses import FileResponse
from pydantic import BaseModel, Field

from app import review_jobs
from app.dependencies import get_jobs, get_session
from app.jobs import JobRunner
from app.session import ReviewSession
from guardrail_core.errors import InvalidOptionError
from guardrail_core.reconstruction import RECONSTRUCTION_DIR, ReconstructionParams

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


def downloadable(run_root: Path) -> dict[str, Path]:
    """Name -> file of everything the reconstruction offers for download (the only files the
    download route serves: a request names a key of this table, never a path)."""
    folder = run_root / RECONSTRUCTION_DIR
    files = {}
    for pattern in ("inventory.*", "meshes/*"):
        for path in sorted(folder.glob(pattern)):
            if path.is_file() and path.suffix in MEDIA_TYPES:
                files[path.relative_to(folder).as_posix()] = path
    return files


@router.get("/downloads")
def list_downloads(session: Session) -> dict[str, Any]:
    """The meshes (GLB, PLY, OBJ) and the inventory (GeoJSON, CSV) of the reconstruction."""
    return {
        "items": [
            {"name": name, "bytes": path.stat().st_size, "url": f"/api/downloads/{name}"}
            for name, path in downloadable(session.run.root).items()
        ]
    }


@router.get("/downloads/{name:path}", response_class=FileResponse)
def get_download(session: Session, name: str) -> FileResponse:
    path = downloadable(session.run.root).get(name)
    if path is None:
        raise HTTPException(404, detail=f"no download {name!r}; see /api/downloads")
    return FileResponse(path, media_type=MEDIA_TYPES[path.suffix], filename=Path(name).name)


@router.get("/reconstruction")
def get_reconstruction(session: Session) -> dict[str, Any]:
    """The reconstruction's parameters and, per run, its type, units and notes."""
    path = session.run.root / RECONSTRUCTION_DIR / "models.json"
    if not path.is_file():
        return {"params": ReconstructionParams().to_json(), "runs": [], "present": False}
    data = json.loads(path.read_text())
    runs = [
        {
            "run_id": r["run_id"],
            "type": (r.get("model") or {}).get("type"),
            "poles": len(r["poles"]),
            "units": len(r["units"]),
            "notes": r.get("notes", []),
        }
        for r in data["runs"]
    ]
    return {"params": data["params"], "runs": runs, "present": True}


class ApplyBody(BaseModel):
    params: dict[str, dict[str, Any]] = Field(default_factory=dict)


@router.post("/reconstruction/apply", status_code=202)
def post_apply(session: Session, jobs: Jobs, body: ApplyBody) -> dict[str, Any]:
    """Reconstruct every guardrail again from the current labels with these parameters (by
    stage, as in ``models.json``; missing ones keep their defaults); poll the job."""
    try:
        params = ReconstructionParams.from_json(body.params)
    except InvalidOptionError as exc:
        raise HTTPException(422, detail=str(exc)) from exc
    return {"job": jobs.submit("reconstruct", review_jobs.reconstruct(session, params)).id}
