"""``guardrail simulate --night``: the same street, its images taken at night."""

from __future__ import annotations

import json
from pathlib import Path

import cv2

from guardrail_core.cli import main


def test_a_night_drive_is_the_day_drive_in_the_dark(tmp_path: Path) -> None:
    common = ["--seed", "7", "--length", "30", "--image-every", "15", "--image-size", "320x240"]
    assert main(["simulate", str(tmp_path / "day"), *common, "--quiet"]) == 0
    assert main(["simulate", str(tmp_path / "night"), *common, "--night", "--quiet"]) == 0
    day = json.loads((tmp_path / "day" / "drive.json").read_text())["source"]
    night = json.loads((tmp_path / "night" / "drive.json").read_text())["source"]
    assert "night" not in day and night["night"] is True
    images = sorted(p.relative_to(tmp_path / "day") for p in (tmp_path / "day").rglob("*.jpg"))
    assert len(images) >= 6
    for name in ("points", "truth"):  # the same scan and truth
        for a in sorted((tmp_path / "day" / name).rglob("*.*")):
            b = tmp_path / "night" / a.relative_to(tmp_path / "day")
            assert a.read_bytes() == b.read_bytes(), a
    for image in images:
        lit = cv2.imread(str(tmp_path / "day" / image)).mean()
        dark = cv2.imread(str(tmp_path / "night" / image)).mean()
        assert dark < 0.75 * lit, (image, dark, lit)
