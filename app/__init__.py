"""The review app (FastAPI + viser); arrives with the review issue."""
