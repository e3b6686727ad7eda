"""Fine-tuning from the labels, background jobs, and the models an operator can activate."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Depends, HTTPException
from pydantic import BaseModel

from app import review_jobs
from app.dependencies import get_jobs, get_session
from app.jobs import JobBusyError, JobRunner
from app.model_registry import UnknownModelError
from app.schemas import CONFLICT, NOT_FOUND, Activated, Job, JobList, JobStarted, ModelList
from app.session import ReviewSession
from guardrail_core.errors import IncompatibleModelError

router = APIRouter(prefix="/api", tags=["training"])
Session = Annotated[ReviewSession, Depends(get_session)]
Jobs = Annotated[JobRunner, Depends(get_jobs)]


class TrainBody(BaseModel):
    mode: Literal["fast", "full"] = "fast"
    include_unreviewed: bool = True


@router.post("/train", status_code=202, response_model=JobStarted, responses=CONFLICT)
def post_train(session: Session, jobs: Jobs, body: TrainBody | None = None) -> dict[str, Any]:
    """Start fine-tuning a model from the label store; poll ``/api/jobs/{job}``.

    Segments an operator labelled take the operator's label; with ``include_unreviewed`` the
    others take the run's corrected label, but for those labelled otherwise than an operator
    labelled a segment of their component, which are left out
    (:func:`guardrail_core.review.training_labels.contradicted_labels`).
    """
    body = body or TrainBody()
    work = review_jobs.fine_tune(
        session, mode=body.mode, include_unreviewed=body.include_unreviewed
    )
    try:
        return {"job": jobs.submit("train", work).id}
    except JobBusyError as exc:
        raise HTTPException(409, detail=str(exc)) from exc


# exclude_unset: metrics of older model folders lack some fields (see app.schemas)
@router.get("/jobs", response_model=JobList, response_model_exclude_unset=True)
def list_jobs(jobs: Jobs, kind: str | None = None) -> dict[str, Any]:
    """Jobs of this server (of one ``kind`` when given: train, reconstruct), newest first; a
    reloaded page finds a training still running here."""
    return {"items": [job.to_json() for job in jobs.list(kind)]}


@router.get(
    "/jobs/{job_id}", response_model=Job, response_model_exclude_unset=True, responses=NOT_FOUND
)
def get_job(jobs: Jobs, job_id: str) -> dict[str, Any]:
    """One job: its state, its progress, and its result or error when it has ended."""
    job = jobs.get(job_id)
    if job is None:
        raise HTTPException(404, detail=f"no job {job_id}")
    return job.to_json()


@router.delete(
    "/jobs/{job_id}",
    response_model=Job,
    response_model_exclude_unset=True,
    responses={**NOT_FOUND, **CONFLICT},
)
def delete_job(jobs: Jobs, job_id: str) -> dict[str, Any]:
    """Cancel a job: a queued one never starts, a running one stops at its next progress report
    (its status turns ``cancelled``; what it was writing is thrown away); 409 once it ended."""
    job = jobs.get(job_id)
    if job is None:
        raise HTTPException(404, detail=f"no job {job_id}")
    if job.status not in ("queued", "running"):
        raise HTTPException(409, detail=f"job {job_id} already ended ({job.status})")
    return jobs.cancel(job_id).to_json()


@router.get("/models", response_model=ModelList, response_model_exclude_unset=True)
def get_models(session: Session) -> dict[str, Any]:
    """Every model known to the app, newest first; ``active`` made the run's predictions."""
    return {"active": session.models.active_version, "models": session.models.list()}


@router.post(
    "/models/{version}/activate", response_model=Activated, responses={**NOT_FOUND, **CONFLICT}
)
def post_activate(session: Session, version: str) -> dict[str, Any]:
    """Re-predict the run with this model and make it the active one (409, the run unchanged,
    when the model cannot read the run's segment features: a run processed by another version
    of guardrail)."""
    try:
        return review_jobs.activate(session, version)
    except UnknownModelError as exc:
        raise HTTPException(404, detail=f"no model folder of version {version} is known") from exc
    except IncompatibleModelError as exc:
        raise HTTPException(409, detail=str(exc)) from exc
