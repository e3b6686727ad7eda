"""The embedded LocalCluster: its workers keep glibc's own memory management (Dask's nanny would
set a 64 KiB trim threshold, which made every tile about 30 % slower) and Dask's single-threaded
numerical libraries, do not run Dask's profiler, and are warmed up with the model before their
first tile."""

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


def _profiling() -> bool:
    import dask

    return bool(dask.config.get("distributed.worker.profile.enabled"))


def test_the_workers_do_not_sample_their_own_stacks() -> None:
    # Dask's profiler (for the dashboard's profile page) costs the tiles about 1 % of a worker.
    with dask_client(ClusterSpec(workers=1)) as client:
        assert list(client.run(_profiling).values()) == [False]


def _loaded() -> tuple[int, int, bool]:
    """What this worker holds: models loaded for tiles, CNN sessions (or torch networks) made,
    and whether the reconstruction's modules are imported."""
    import sys

    tile_task = sys.modules.get("guardrail_core.process.tile_task")
    backbone = sys.modules.get("guardrail_core.extract.classify.backbone")
    models = 0 if tile_task is None else tile_task._load_model.cache_info().currsize
    networks = 0 if backbone is None else len(backbone._EMBEDDERS)
    return models, networks, "guardrail_core.reconstruct.pipeline" in sys.modules


def test_every_worker_is_warmed_up_with_the_model_before_its_first_tile() -> None:
    """``guardrail process`` starts each worker on its model (and the CNN's session) while the
    command itself is still importing the pipeline."""
    from guardrail_core.distributed import on_every_worker

    with dask_client(ClusterSpec(workers=2)) as client:
        assert list(client.run(_loaded).values()) == [(0, 0, False)] * 2
        futures = on_every_worker(client, "guardrail_core.process.tile_task:warm_up", None)
        assert len(futures) == 2 and client.gather(futures) == [None, None]
        # The default model (the fast one: its backbone embeds for it), on both workers.
        assert list(client.run(_loaded).values()) == [(1, 1, True)] * 2
