"""A reconstructed guardrail run's unit model: the numbers behind its thresholds."""

from __future__ import annotations

from typing import Annotated, Any

from fastapi import APIRouter, Depends, HTTPException, Query

from app.dependencies import get_session
from app.run_tuning import TUNABLE, RunTuner, unit_numbers, with_value
from app.schemas import NOT_FOUND, RunHistogram
from app.session import ReviewSession
from guardrail_core.errors import ReconstructionError, RunFolderError

router = APIRouter(prefix="/api/runs", tags=["reconstruction"])
Session = Annotated[ReviewSession, Depends(get_session)]

#: The tuning slider's range of the threshold's factor.
FACTOR_RANGE = TUNABLE[("pipes", "histogram_factor")][1:3]


@router.get("/{run_id}/histogram", response_model=RunHistogram, responses=NOT_FOUND)
def get_histogram(
    session: Session,
    run_id: int,
    histogram_factor: Annotated[
        float | None,
        Query(
            ge=FACTOR_RANGE[0],
            le=FACTOR_RANGE[1],
            description="the threshold's factor of the median count (the tuning slider); "
            "default: the reconstruction's",
        ),
    ] = None,
) -> dict[str, Any]:
    """The x histogram of the run's superimposed points with its threshold and the pipes found
    with it (§4.3, Fig. 14), or the beam's section curve: the unit model re-run from the stored
    points, nothing written."""
    try:
        tuner = RunTuner(session.folder)  # read afresh: "apply" may have redone it
    except RunFolderError as exc:
        raise HTTPException(404, detail=f"the run has no reconstruction ({exc})") from exc
    try:
        run = tuner.run(run_id)
    except KeyError as exc:
        raise HTTPException(404, detail=f"no guardrail run {run_id}") from exc
    if run.model is None:
        raise HTTPException(404, detail=f"run {run_id} has no unit model (see its notes)")
    params = tuner.params
    if histogram_factor is not None:
        params = with_value(params, "pipes", "histogram_factor", histogram_factor)
    try:
        unit = tuner.unit(run_id, params)
    except ReconstructionError as exc:
        raise HTTPException(404, detail=f"run {run_id}: {exc}") from exc
    return unit_numbers(run_id, unit, params)
