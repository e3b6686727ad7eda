"""The embedded LocalCluster: its workers keep glibc's own memory management (Dask's nanny would
set a 64 KiB trim threshold, which made every tile about 30 % slower) and Dask's single-threaded
numerical libraries."""

from __future__ import annotations

import os

from guardrail_core.distributed import ClusterSpec, dask_client


def _environment(*names: str) -> dict[str, str | None]:
    return {name: os.environ.get(name) for name in names}


def test_the_workers_run_without_dasks_malloc_trim_threshold() -> None:
    names = ("MALLOC_TRIM_THRESHOLD_", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS")
    before = _environment("MALLOC_TRIM_THRESHOLD_")
    with dask_client(ClusterSpec(workers=2)) as client:
        seen = client.run(_environment, *names)
    assert len(seen) == 2
    for environment in seen.values():
        assert environment == {
            "MALLOC_TRIM_THRESHOLD_": before["MALLOC_TRIM_THRESHOLD_"],
            "OMP_NUM_THREADS": "1",
            "OPENBLAS_NUM_THREADS": "1",
        }
    # Dask sets its pre-spawn variables in the spawning process too: this one stays as it was.
    assert _environment("MALLOC_TRIM_THRESHOLD_") == before
