"""The work of the app's background jobs: fine-tuning from the label store, activating a model,
re-running the reconstruction with the operator's labels and thresholds."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from app.jobs import JobFailed
from app.session import ReviewSession
from guardrail_core.errors import GuardrailError, IncompatibleModelError, TrainingDataError
from guardrail_core.extract.classify.crop_classifier_params import ClassifierParams
from guardrail_core.formats.drive import drive_parts
from guardrail_core.reconstruct.drive_input import gather_reconstruction_points
from guardrail_core.reconstruct.pipeline import ReconstructionParams
from guardrail_core.reconstruct.writing import reconstruct_into
from guardrail_core.review.predictions import predict_run, write_predictions
from guardrail_core.review.training import train_from_run

Report = Callable[[float, str], None]


def fine_tune(
    session: ReviewSession, *, mode: str = "fast", include_unreviewed: bool = True
) -> Callable[[Report], dict[str, Any]]:
    """A job that trains a model from the store's labels and saves it (not activated): the model
    that made the run fine-tuned (:meth:`~app.model_registry.ModelRegistry.fine_tuning_start`),
    or, where its folder is not known, a new one."""
    operator_label = session.operator_label.copy()  # a snapshot: labelling goes on meanwhile
    run = session.run

    def work(report: Report) -> dict[str, Any]:
        report(0.0, "collecting labels")
        try:
            start = session.models.fine_tuning_start()
            trained = train_from_run(
                run,
                operator_label=operator_label,
                params=ClassifierParams(mode=mode),
                include_unreviewed=include_unreviewed,
                progress_fn=lambda f, m: report(0.95 * f, m),
                drive_root=session.drive.root,
                start_from=start,
            )
        except GuardrailError as exc:
            raise JobFailed(training_advice(exc)) from exc
        report(0.96, "saving the model")
        session.models.add(trained.model)
        return {
            "version": trained.model.version,
            "metrics_new": trained.metrics_new,
            "metrics_current": trained.metrics_current,
            "current_version": run.info.model.version,
            "held_out_segments": int(trained.held_out.sum()),
            "seconds": round(trained.seconds, 2),
        }

    return work


def training_advice(exc: GuardrailError) -> str:
    """What a failed fine-tuning means to an operator, and what to do; the labels given so far
    are in the label store whatever failed."""
    if isinstance(exc, TrainingDataError):
        return (
            "Not enough labels to learn from yet: fine-tuning needs segments of both kinds. "
            "Label more segments (g guardrail, o other), then press Fine-tune again."
        )
    if isinstance(exc, IncompatibleModelError):
        return (
            "This run was made by an older version of the program, and its model cannot learn "
            "from it. Process the drive again (guardrail process DRIVE --out RUN) and open the "
            "new run: your labels are kept, they belong to the drive."
        )
    return (
        "The model that made this run cannot be fine-tuned here. Your labels are kept. "
        "Activate another model under Model, or process the drive with a model trained by "
        "guardrail train, then press Fine-tune again."
    )


def activate(session: ReviewSession, version: str) -> dict[str, Any]:
    """Re-predict the run with the model ``version`` and write its predictions into the run.

    Raises
    ------
    app.model_registry.UnknownModelError
        No folder of that version is known.
    """
    model = session.models.load(version)
    before = session.effective_label().copy()
    with session.lock:
        predictions = predict_run(session.run, model, drive_root=session.drive.root)
        write_predictions(session.run.root, predictions, model)
    session.reload_run()
    return {
        "active": session.models.active_version,
        "changed_segments": int((session.effective_label() != before).sum()),
    }


def reconstruct(
    session: ReviewSession, params: ReconstructionParams
) -> Callable[[Report], dict[str, Any]]:
    """A job that reconstructs every guardrail again from the effective labels, with ``params``
    (saved in ``reconstruction/models.json``)."""
    label = session.effective_label().copy()

    def work(report: Report) -> dict[str, Any]:
        report(0.02, "reading the guardrail points")
        drive = session.drive
        # Only the guardrail points and the road near them, a tile at a time: a survey never whole.
        xyz, point_segment = gather_reconstruction_points(
            drive, session.folder, label, params.runs.ground_reach_m
        )
        report(0.05, "reconstructing")
        summary = reconstruct_into(
            session.run.root,
            xyz,
            point_segment,
            label,
            drive.trajectory.position,
            origin=drive.origin,
            crs=drive.crs,
            params=params,
            inputs=drive_parts(drive.root),
            on_run=lambda done, runs: report(
                0.05 + 0.9 * done / max(runs, 1), f"reconstructing: run {done} of {runs}"
            ),
        )
        session.notify("reconstruction", np.zeros(0, np.int64))
        return {"summary": summary.to_json()}

    return work
