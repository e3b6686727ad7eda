"""Runs closed as the parts arrive are the runs of the whole drive (points, ground, direction,
numbers), are handed out before the last part, and only open runs' points are held."""

from __future__ import annotations

import numpy as np

from guardrail_core.process.run_stream import RunStream
from guardrail_core.reconstruct.pipeline import ReconstructionParams, split_runs

PART_M = 10.0
PARTS = 10


def street(seed: int = 5) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Guardrail points (G, 3) with the part that scans each (G,), ground points (R, 3) with
    theirs (R,): a 100 m street scanned in time order along x, in parts of 10 m; part 5 also
    scans the gap between the first two guardrails, at x = 12-14 m (as a vehicle passing
    there again would), so that they are one run."""
    rng = np.random.default_rng(seed)
    pieces = []
    for x0, x1, y in ((0, 12, 5), (14, 40, 5), (45, 46, 5), (50, 80, 5), (20, 70, -5)):
        x = np.arange(x0, x1, 0.05)
        for z in (0.4, 0.7):
            pieces.append(np.stack([x, np.full_like(x, y), np.full_like(x, z)], axis=1))
    rail = np.concatenate(pieces)
    rail += rng.normal(0, 0.01, rail.shape)
    rail_part = np.clip((rail[:, 0] // PART_M).astype(int), 0, PARTS - 1)
    back = np.arange(11.9, 14.1, 0.05)
    revisit = np.stack([back, np.full_like(back, 5.0), np.full_like(back, 0.55)], axis=1)
    rail = np.concatenate([rail, revisit])
    rail_part = np.concatenate([rail_part, np.full(len(revisit), 5)])
    gx, gy = np.meshgrid(np.arange(0, 100, 0.5), np.arange(-6, 6.01, 0.5))
    ground = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1)
    ground_part = np.minimum((ground[:, 0] // PART_M).astype(int), PARTS - 1)
    return rail, rail_part, ground, ground_part


def drive_order(part: np.ndarray) -> np.ndarray:
    """Drive-wide index of each point: part by part (time order), in the given order within."""
    order = np.argsort(part, kind="stable")
    index = np.empty(len(part), np.int64)
    index[order] = np.arange(len(part))
    return index


def test_streamed_runs_are_the_whole_drives_runs_handed_out_before_the_end() -> None:
    rail, rail_part, ground, ground_part = street()
    rail_index = drive_order(rail_part)
    ground_index = drive_order(ground_part) + len(rail)
    trajectory = np.stack([np.arange(-5, 105, 1.0), np.zeros(110), np.full(110, 2.0)], axis=1)
    params = ReconstructionParams()
    # Each part's points come from its own drive tile; a part's window reads its neighbours.
    boxes = np.array(
        [
            [*np.concatenate([rail[rail_part == k], ground[ground_part == k]])[:, :2].min(0)]
            + [*np.concatenate([rail[rail_part == k], ground[ground_part == k]])[:, :2].max(0)]
            for k in range(PARTS)
        ]
    )
    last_reader = np.minimum(np.arange(PARTS) + 1, PARTS - 1)

    stream = RunStream(trajectory, params)
    handed: list = []
    open_points = []
    for k in range(PARTS):
        r, g = rail_part == k, ground_part == k
        stream.add(rail_index[r], rail[r], ground_index[g], ground[g])
        handed_before = len(handed)
        still_open = boxes[last_reader >= k + 1] if k + 1 < PARTS else None
        handed += stream.close(still_open) if still_open is not None else []
        open_points.append(stream.open_points)
        if k == PARTS - 2:
            closed_before_last = len(handed)
        assert all(run.run_id == i for i, run in enumerate(handed[handed_before:], handed_before))
    handed += stream.close()
    assert stream.open_points == 0
    # Before the last part: the first two guardrails, joined once part 5 came back to them,
    # and the one at y = -5 (x 20-70 m), beyond the reach of the last drive tile's points.
    assert closed_before_last == 2
    # Their points are let go: fewer held after part 6 than after part 5.
    assert open_points[6] < open_points[5]

    in_drive_order = np.argsort(rail_index)
    whole = split_runs(rail[in_drive_order], ground[np.argsort(ground_index)], trajectory, params)
    assert len(whole) == len(handed) == 3  # the returned-to pair joined; the 1 m piece is none
    final = stream.final_ids()
    assert sorted(final) == list(range(len(whole)))
    for provisional, run in enumerate(handed):
        expected = whole[final[provisional]]
        np.testing.assert_array_equal(run.xyz, expected.xyz)
        np.testing.assert_array_equal(run.ground, expected.ground)
        np.testing.assert_array_equal(run.toward_road, expected.toward_road)
