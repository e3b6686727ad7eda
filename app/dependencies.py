"""Shared state handed to the routers (FastAPI dependencies)."""

from __future__ import annotations

from fastapi import Request

from app.jobs import JobRunner
from app.session import ReviewSession


def get_session(request: Request) -> ReviewSession:
    return request.app.state.session


def get_jobs(request: Request) -> JobRunner:
    return request.app.state.jobs
