"""Where the real KITTI scans live (../shared/realdata, outside the repository), and the skip
that says so when a machine lacks them."""

from __future__ import annotations

from pathlib import Path

import pytest

REALDATA = Path(__file__).resolve().parents[1].parent / "shared" / "realdata"
KITTI_SEQUENCES = REALDATA / "kitti-odometry" / "sequences"
#: A German motorway: a W-beam guardrail on the right shoulder and a median barrier (frame 280).
KITTI_SEQ01 = KITTI_SEQUENCES / "01"
#: A street in Karlsruhe with its colour image (frame 0); no guardrail.
KITTI_RAW = KITTI_SEQUENCES / "raw_2011_09_26_f0000"


def require_kitti(sequence: Path) -> None:
    """Skip, naming the folder, where the real KITTI data is not on this machine."""
    if not (sequence / "calib.txt").is_file():
        pytest.skip(f"real KITTI data not found at {sequence} (see ../shared/realdata/README.md)")
