"""Segments as the API shows them: JSON rows, filters, sort orders and the review queue."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from app.route_overview import counted_segments, run_places, segment_runs
from app.session import ReviewSession
from guardrail_core.formats.run_folder import CROP_OK, CROP_STATUS_NAMES
from guardrail_core.review.queue import (
    MIN_QUEUE_POINTS,
    asked_segments,
    queue_order,
    segment_queue_scores,
    uncertainty,
    unchecked_runs,
)

SORTS = ("id", "uncertainty", "probability", "-probability")


def _name(flag: bool) -> str:
    return "guardrail" if flag else "other"


def segment_rows(session: ReviewSession, ids: np.ndarray) -> list[dict[str, Any]]:
    """The API's segment objects (see the REST contract in the README)."""
    seg = session.run.segments
    label = session.effective_label()
    ids = np.asarray(ids, np.int64)
    truth = session.truth(ids)  # read from the segments' tiles (synthetic drives)
    rows = []
    for k, s in enumerate(ids):
        s = int(s)
        probability = float(seg["probability"][s])
        ok = int(seg["crop_status"][s]) == CROP_OK
        rows.append(
            {
                "id": s,
                "n_points": int(seg["n_points"][s]),
                "centroid": [round(float(v), 3) for v in seg["centroid"][s]],
                "slice_index": int(seg["slice_index"][s]),
                "component": int(seg["component"][s]),
                "crop_status": CROP_STATUS_NAMES[int(seg["crop_status"][s])],
                "crop_url": f"/api/segments/{s}/crop.jpg" if ok else None,
                "probability": None if math.isnan(probability) else round(probability, 4),
                "raw_label": _name(bool(seg["raw_label"][s])),
                "model_label": _name(bool(seg["label"][s])),
                "label": _name(bool(label[s])),
                "reviewed": bool(session.operator_label[s] >= 0),
                "truth": None if truth is None else _name(bool(truth[k])),
            }
        )
    return rows


def filter_segments(
    session: ReviewSession,
    *,
    label: str | None = None,
    reviewed: bool | None = None,
    crop: bool | None = None,
    min_probability: float | None = None,
    max_probability: float | None = None,
    sort: str = "id",
) -> np.ndarray:
    """(K,) int64 ids of the segments that pass the filters, in the asked order."""
    seg = session.run.segments
    keep = np.ones(session.n_segments, bool)
    if label is not None:
        keep &= session.effective_label() == (label == "guardrail")
    if reviewed is not None:
        keep &= (session.operator_label >= 0) == reviewed
    if crop is not None:
        keep &= (seg["crop_status"] == CROP_OK) == crop
    p = seg["probability"].astype(np.float64)
    if min_probability is not None:
        keep &= np.nan_to_num(p, nan=-1.0) >= min_probability
    if max_probability is not None:
        keep &= np.nan_to_num(p, nan=2.0) <= max_probability
    ids = np.flatnonzero(keep)
    if sort == "uncertainty":
        ids = ids[np.argsort(-uncertainty(p[ids]), kind="stable")]
    elif sort == "probability":
        ids = ids[np.argsort(np.nan_to_num(p[ids], nan=-1.0), kind="stable")]
    elif sort == "-probability":
        ids = ids[np.argsort(-np.nan_to_num(p[ids], nan=-1.0), kind="stable")]
    return ids.astype(np.int64)


def review_queue(
    session: ReviewSession, limit: int, run: int | None = None, *, off_runs: bool = False
) -> dict[str, Any]:
    """The segments the review queue asks about, best first, and how far the review is.

    The queue asks about an unreviewed segment of ``MIN_QUEUE_POINTS`` points or more whose
    raw prediction and corrected label disagree (§3.3's correction changed it), that stands for
    a guardrail run no operator has looked at yet, or whose P(guardrail) lies between 5 % and
    95 % (:func:`guardrail_core.review.queue.asked_segments`); nothing else. Those that disagree
    or stand for a run come first; then the change a decision is expected to make orders them:
    the model's uncertainty (1 at p = 0.5), weighted by the points it moves and by half again
    where it would join or split a guardrail run
    (:func:`guardrail_core.review.queue.segment_queue_scores`). With ``run``, those of that
    guardrail run in order along the road, as they were scanned. With ``off_runs``, every
    unreviewed segment of ``MIN_QUEUE_POINTS`` points or more that the model or an operator
    calls guardrail and that lies on no reconstructed run (a run without poles, a rail beyond
    its end poles, a mistake), along the road: the route table cannot reach those.

    Returns ``items`` (the first ``limit``), ``asked`` (how many the queue holds), ``reviewed``
    (segments an operator labelled, in the same scope) and ``done`` (nothing left to ask).

    Raises
    ------
    KeyError
        ``run`` is not a reconstructed run with poles (the router answers 404).
    """
    seg = session.run.segments
    disagrees = seg["raw_label"] != seg["label"]
    reviewed = session.operator_label >= 0
    score = segment_queue_scores(seg)  # the change a decision is expected to make
    unchecked = unchecked_runs(seg["component"], seg["label"], seg["n_points"], reviewed, score)
    score = score + unchecked  # as segment_queue_scores(seg, reviewed)
    asked = asked_segments(seg, reviewed, unchecked=unchecked)
    if off_runs:
        in_scope = counted_segments(session) & (segment_runs(session, run_places(session)) < 0)
        mine = np.flatnonzero(in_scope & ~reviewed & (seg["n_points"] >= MIN_QUEUE_POINTS))
        order = mine[np.argsort(seg["time"][mine].mean(axis=1), kind="stable")].astype(np.int64)
    elif run is None:
        order = queue_order(np.where(asked, score, -np.inf), ~asked)
        in_scope = np.ones(len(asked), bool)
    else:
        places = run_places(session)
        found = [k for k, place in enumerate(places) if place.row.run_id == run]
        if not found:
            raise KeyError(f"no guardrail run {run} with poles")
        in_scope = segment_runs(session, places) == found[0]
        mine = np.flatnonzero(in_scope & asked)
        scanned = seg["time"][mine].mean(axis=1)
        order = mine[np.argsort(scanned, kind="stable")].astype(np.int64)
    rows = segment_rows(session, order[:limit])
    for row, s in zip(rows, order, strict=False):
        row["reason"] = (
            "disagrees" if disagrees[s] else "unchecked" if unchecked[s] else "uncertain"
        )
        row["score"] = round(float(score[s]), 4)
    return {
        "items": rows,
        "asked": len(order),
        "reviewed": int((reviewed & in_scope).sum()),
        "done": len(order) == 0,
    }
