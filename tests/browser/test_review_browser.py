"""The review app in a real browser (Debian's Chromium, driven by Playwright).

Opens the app, sees the 3D scene connect, relabels with the keyboard, kills and restarts the
server and finds the label still there, fine-tunes a model and activates it, and uses the crop
gallery's keys. Screenshots go to the test's folder (and to ``$GUARDRAIL_SCREENSHOTS`` when set).
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path

import pytest

CHROMIUM = Path("/usr/bin/chromium")
# Headless Chromium: software WebGL (SwiftShader) for the 3D scene; no calls to the outside.
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--ignore-gpu-blocklist",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _get(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=10) as response:
        return json.loads(response.read())


class Server:
    """``guardrail serve`` in a subprocess."""

    def __init__(self, drive: Path, run: Path, review: Path, model: Path, log: Path) -> None:
        self.args = [
            sys.executable,
            "-m",
            "guardrail_core.cli",
            "serve",
            str(drive),
            "--run",
            str(run),
            "--review-dir",
            str(review),
            "--model",
            str(model),
            "--operator",
            "browser-test",
            "--window",
            "40",
        ]
        self.log = log
        self.process: subprocess.Popen | None = None

    def start(self) -> None:
        self.port, scene_port = _free_port(), _free_port()
        args = [*self.args, "--port", str(self.port), "--scene-port", str(scene_port)]
        with self.log.open("a") as log:
            self.process = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(f"the server exited: {self.log.read_text()[-2000:]}")
            try:
                _get(f"{self.url}/api/info")
                return
            except OSError:
                time.sleep(0.5)
        raise TimeoutError(f"the server did not answer: {self.log.read_text()[-2000:]}")

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def kill(self) -> None:
        """SIGKILL: no clean shutdown, as in a crash."""
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGKILL)
            self.process.wait(timeout=30)


@pytest.fixture()
def shots(tmp_path: Path) -> Iterator[Path]:
    folder = tmp_path / "screenshots"
    folder.mkdir()
    yield folder
    target = os.environ.get("GUARDRAIL_SCREENSHOTS")
    if target:
        shutil.copytree(folder, target, dirs_exist_ok=True)


@pytest.fixture()
def server(drive_path: Path, run_path: Path, model_path: Path, tmp_path: Path) -> Iterator[Server]:
    run = tmp_path / "run"
    shutil.copytree(run_path, run)
    s = Server(drive_path, run, tmp_path / "review", model_path, tmp_path / "server.log")
    s.start()
    yield s
    s.kill()


def test_review_app_in_the_browser(server: Server, shots: Path) -> None:
    from playwright.sync_api import expect, sync_playwright

    assert CHROMIUM.is_file(), "browser tests need Debian's chromium (make test installs it)"
    segments = _get(f"{server.url}/api/segments?crop=true&sort=-probability&limit=1")["items"]
    s = segments[0]["id"]
    flipped = "other" if segments[0]["label"] == "guardrail" else "guardrail"
    key = flipped[0]

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))

        # Open the app on a segment; the 3D scene (viser, in the iframe) connects.
        page.goto(f"{server.url}/?segment={s}")
        expect(page.locator("#selected-id")).to_have_text(str(s), timeout=30_000)
        _wait_for(lambda: _get(f"{server.url}/api/info")["scene_clients"] >= 1, "3D scene")
        assert _get(f"{server.url}/api/selection")["segments"] == [s]

        # Relabel with the keyboard (focus on the page, not on the 3D iframe).
        page.locator("#selected-id").click()
        page.keyboard.press(key)
        expect(page.locator("#selected-label")).to_have_attribute("data-label", flipped)
        row = _get(f"{server.url}/api/segments/{s}")
        assert row["label"] == flipped and row["reviewed"] is True
        assert row["history"][0]["who"] == "browser-test"
        page.wait_for_timeout(1500)  # let the 3D view draw the new colours
        page.screenshot(path=shots / "review.png")

        # A crash of the server loses no label: kill it, start it again, reload.
        server.kill()
        server.start()
        page.goto(f"{server.url}/?segment={s}")
        expect(page.locator("#selected-label")).to_have_attribute(
            "data-label", flipped, timeout=30_000
        )
        expect(page.locator("#selected-reviewed")).to_have_attribute("data-reviewed", "true")

        # Fine-tune from the labels, see the new model beside the current one, activate it.
        before = _get(f"{server.url}/api/models")["active"]
        page.locator("#train").click()
        expect(page.locator("#activate")).to_be_visible(timeout=240_000)
        expect(page.locator("#compare-table")).to_contain_text("guardrail")
        page.screenshot(path=shots / "fine-tune.png")
        page.locator("#activate").click()
        _wait_for(lambda: _get(f"{server.url}/api/models")["active"] != before, "activation")
        active = _get(f"{server.url}/api/models")["active"]
        expect(page.locator("#header-model")).to_contain_text(active[:15], timeout=30_000)
        row = _get(f"{server.url}/api/segments/{s}")
        assert row["label"] == flipped, "an operator's label outlives a model change"

        # The gallery: crops, keyboard labelling, a link back to the 3D view.
        page.goto(f"{server.url}/gallery")
        crops = page.locator('#gallery-grid .crop[data-reviewed="false"]')
        expect(crops.first).to_be_visible(timeout=30_000)
        first_id = int(crops.first.get_attribute("data-id") or -1)
        first = page.locator(f'#gallery-grid .crop[data-id="{first_id}"]')
        first.click()
        page.keyboard.press("o")
        expect(first).to_have_attribute("data-label", "other")
        assert _get(f"{server.url}/api/segments/{first_id}")["label"] == "other"
        page.keyboard.press("z")
        _wait_for(
            lambda: not _get(f"{server.url}/api/segments/{first_id}")["reviewed"], "undo in gallery"
        )
        page.screenshot(path=shots / "gallery.png")
        browser.close()
    assert not errors, errors


def _wait_for(condition, what: str, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return
        time.sleep(0.25)
    raise TimeoutError(f"waited {timeout} s for {what}")
