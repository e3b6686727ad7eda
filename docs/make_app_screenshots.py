"""Screenshots of the review app for the README: the 3D scene with a selected segment, the
selected segment's panel with its camera image, the route panel, the tuning panel with a run's
histogram, a lasso's points, and the crop gallery.

Serves a drive (default: the demo's) with ``guardrail serve`` on free ports, drives Debian's
Chromium with Playwright and writes PNGs into ``docs/images/``. Labels go to a temporary review
folder, so the drive is left as it was.

    .venv/bin/python docs/make_app_screenshots.py [--drive D] [--run R] [--model M] [--segment S]
"""

from __future__ import annotations

import argparse
import json
import re
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

from playwright.sync_api import sync_playwright

ROOT = Path(__file__).resolve().parent.parent
IMAGES = ROOT / "docs" / "images"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--ignore-gpu-blocklist",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def wait_for(url: str, timeout: float = 180.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            urllib.request.urlopen(url, timeout=5).read()
            return
        except OSError:
            time.sleep(0.5)
    raise TimeoutError(url)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    demo = ROOT / "demo_output"
    parser.add_argument("--drive", type=Path, default=demo / "sample_drive")
    parser.add_argument("--run", type=Path, default=demo / "run")
    parser.add_argument("--model", type=Path, default=demo / "model")
    parser.add_argument(
        "--segment", type=int, help="segment to select (default: a large, sure guardrail one)"
    )
    args = parser.parse_args()

    port, scene_port = free_port(), free_port()
    with tempfile.TemporaryDirectory() as review:
        server = subprocess.Popen(
            [sys.executable, "-m", "guardrail_core.cli", "serve", str(args.drive)]
            + ["--run", str(args.run), "--model", str(args.model), "--review-dir", review]
            + ["--port", str(port), "--scene-port", str(scene_port), "--operator", "docs"],
            stdout=subprocess.DEVNULL,
        )
        try:
            url = f"http://127.0.0.1:{port}"
            wait_for(f"{url}/api/info")
            segment = args.segment
            if segment is None:  # the largest of the surest guardrail segments: it shows well
                query = "/api/segments?label=guardrail&crop=true&sort=-probability&limit=50"
                with urllib.request.urlopen(url + query) as response:
                    items = json.loads(response.read())["items"]
                segment = max(items, key=lambda item: item["n_points"])["id"]
            shoot(url, segment)
        finally:
            server.terminate()
            server.wait(timeout=30)


def shoot(url: str, segment: int) -> None:
    IMAGES.mkdir(parents=True, exist_ok=True)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        page.goto(f"{url}/?segment={segment}")
        page.wait_for_selector("#selected-crop", timeout=30_000)
        scene = page.frame_locator("#scene")
        scene.get_by_text("Connected").wait_for(timeout=60_000)
        time.sleep(8)  # software WebGL draws 400,000 points slowly
        close = scene.locator(".mantine-Notification-closeButton")
        if close.count():
            close.first.click()
        page.wait_for_selector('#camera-overlay[data-loaded="true"]', timeout=30_000)
        page.screenshot(path=IMAGES / "app_review.png")
        page.locator("#selection-panel").screenshot(path=IMAGES / "app_camera.png")

        # The route panel with some review done: one run reviewed as it was, one changed.
        runs = page.evaluate("fetch('/api/overview').then((r) => r.json())")["runs"]
        done = [r for r in runs if r["segment"] is not None][:2]
        for run, label in zip(done, ("guardrail", "other"), strict=False):
            page.evaluate(
                "(body) => fetch('/api/labels/batch', {method: 'POST', headers: "
                "{'Content-Type': 'application/json'}, body: JSON.stringify(body)})",
                {"segments": [run["segment"]], "label": label, "expand": "none"},
            )
        page.reload()
        page.wait_for_selector("#route-table tbody tr", timeout=30_000)
        page.locator("body").press("]")  # fly to the first run along the drive
        page.wait_for_selector("#route-table tbody tr.current", timeout=30_000)
        page.locator("#route-panel").scroll_into_view_if_needed()
        page.locator("#route-panel").screenshot(path=IMAGES / "app_route.png")

        # The tuning panel: a pipe run with vertical pipes, its histogram and threshold.
        scene.get_by_text("Connected").wait_for(timeout=60_000)  # again, after the reload
        panel = scene.get_by_text("Reconstruction", exact=True)
        panel.click()
        scene.locator('input[aria-haspopup="listbox"][value^="run "]').click()
        runs = page.evaluate("fetch('/api/overview').then((r) => r.json())")["runs"]
        verticals = [r for r in runs if r["signature"] and "vertical" in r["signature"]]
        wanted = f"run {verticals[0]['run_id']} " if verticals else "(pipe,"
        scene.get_by_role("option", name=re.compile(re.escape(wanted))).first.click()
        scene.get_by_text(re.compile(r"threshold [0-9.]+ points/bin")).wait_for(timeout=30_000)
        folder = scene.locator(".mantine-Paper-root").filter(has_text="Apply to the whole drive")
        folder.last.screenshot(path=IMAGES / "app_tuning.png")

        # A lasso around points in the 3D view (the panel stands beside it), closed: the points
        # taken turn magenta and the page says what g and o will label.
        scene.get_by_role("button", name="Lasso points").click()
        canvas = scene.locator("canvas[data-engine]")
        box = canvas.bounding_box()
        assert box is not None
        for fx, fy in ((0.30, 0.55), (0.50, 0.50), (0.56, 0.80), (0.36, 0.88)):
            canvas.click(position={"x": fx * box["width"], "y": fy * box["height"]})
        scene.get_by_role("button", name="Close the lasso").click()
        page.wait_for_selector("#lasso-line:not([hidden])", timeout=30_000)
        page.evaluate("document.querySelector('.side-scroll').scrollTop = 0")
        time.sleep(4)  # software WebGL redraws the new colours slowly
        page.screenshot(path=IMAGES / "app_lasso.png")

        page.goto(f"{url}/gallery")
        page.wait_for_selector("#gallery-grid .crop", timeout=30_000)
        time.sleep(3)
        page.screenshot(path=IMAGES / "app_gallery.png")
        browser.close()
    names = ("app_review", "app_camera", "app_route", "app_tuning", "app_lasso", "app_gallery")
    print(f"wrote {', '.join(name + '.png' for name in names)} into {IMAGES}")


if __name__ == "__main__":
    main()
