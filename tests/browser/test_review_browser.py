"""The review app in a real browser (Debian's Chromium, driven by Playwright).

Opens the app, sees the 3D scene connect, relabels with the keyboard, picks a segment on the
camera image, flies to guardrail runs from the route overview, moves a threshold's slider and sees the histogram
redrawn, lasso-labels points and undoes it, kills and restarts the server and
finds the label still there, fine-tunes a model and activates it, and uses the crop
gallery's keys. Screenshots go to the test's folder (and to ``$GUARDRAIL_SCREENSHOTS`` when set).

Every step waits on the state it then asserts, never on time: the page's ``<body data-state>``
("ready" once its first loads settled) and ``data-actions`` (actions finished), the API answer a
key or a click produces, the 3D scene's own panel. The timeouts below only bound how long a state
may take to appear before the test fails (a loaded CI machine renders the software-WebGL scene
slowly); no step ever lasts them when things work.
"""

from __future__ import annotations

import json
import math
import os
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import urlsplit

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
#: The most a state may take to appear (the test goes on as soon as it is there).
WAIT_MS = 120_000
#: The same for the server's slow work: fine-tuning a model, re-predicting the run with it.
JOB_MS = 300_000


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _get(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=10) as response:
        return json.loads(response.read())


class Server:
    """``guardrail serve`` in a subprocess."""

    def __init__(self, drive: Path, run: Path, review: Path, model: Path | None, log: Path) -> None:
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
            *(["--model", str(model)] if model is not None else []),
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
        deadline = time.monotonic() + 300
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


def _serve_a_copy(drive: Path, run: Path, model: Path | None, tmp_path: Path) -> Iterator[Server]:
    """``guardrail serve`` on a copy of ``run`` (the app writes into it), killed afterwards."""
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    s = Server(drive, copy, tmp_path / "review", model, tmp_path / "server.log")
    s.start()
    yield s
    s.kill()


@pytest.fixture()
def server(drive_path: Path, run_path: Path, model_path: Path, tmp_path: Path) -> Iterator[Server]:
    yield from _serve_a_copy(drive_path, run_path, model_path, tmp_path)


def test_review_app_in_the_browser(
    server: Server, shots: Path, drive_path: Path, run_path: Path
) -> None:
    from playwright.sync_api import expect, sync_playwright

    assert CHROMIUM.is_file(), "browser tests need Debian's chromium (make test installs it)"
    segments = _get(f"{server.url}/api/segments?crop=true&sort=-probability&limit=1")["items"]
    s = segments[0]["id"]
    flipped = "other" if segments[0]["label"] == "guardrail" else "guardrail"
    key = flipped[0]

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        page.set_default_timeout(WAIT_MS)  # clicks, waits for answers
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        body = page.locator("body")
        scene = page.frame_locator("#scene").locator("body")  # viser's page, in the iframe

        # Open the app on a segment: the page loads it (and has the server select it), and the
        # 3D scene (viser) connects and shows the selection in its own panel.
        page.goto(f"{server.url}/?segment={s}")
        expect(body).to_have_attribute("data-state", "ready", timeout=WAIT_MS)
        expect(page.locator("#selected-id")).to_have_text(str(s))
        assert _get(f"{server.url}/api/selection")["segments"] == [s]
        expect(scene).to_contain_text(re.compile(rf"Segment {s}\b"), timeout=WAIT_MS)
        assert _get(f"{server.url}/api/info")["scene_clients"] >= 1
        # One control for one action: labelling and the queue are the page's, not the scene's.
        for button in ("Guardrail (G)", "Other (O)", "Undo (Z)", "Next in queue"):
            expect(scene).not_to_contain_text(button)
        expect(scene).to_contain_text("label it on the page")

        # Relabel with the keyboard: one key labels and goes on to the segment that followed in
        # the queue. The keys must reach the page, not the 3D iframe (whose viser panel has no
        # labelling).
        page.locator("#selected-id").click()
        assert page.evaluate("document.activeElement.id") != "scene"
        done = int(body.get_attribute("data-actions") or 0)
        before = [x["id"] for x in _get(f"{server.url}/api/queue?limit=10")["items"]]
        with page.expect_response(_api("POST", "/api/labels/batch")) as answer:
            page.keyboard.press(key)
        assert answer.value.ok, answer.value.text()
        assert [(x["id"], x["label"]) for x in answer.value.json()["segments"]] == [(s, flipped)]
        # The action is over once the page has selected the next one and shown it.
        expect(body).to_have_attribute("data-actions", str(done + 1), timeout=WAIT_MS)
        after = [x["id"] for x in _get(f"{server.url}/api/queue?limit=10")["items"]]
        expect(page.locator("#selected-id")).to_have_text(str(_next_asked(before, after, s)))
        row = _get(f"{server.url}/api/segments/{s}")
        assert row["label"] == flipped and row["reviewed"] is True
        assert row["history"][0]["who"] == "browser-test"
        # Back to it: the 3D view has the new colours, as the scene's panel text, sent after
        # them, says. A reload starts the page afresh.
        page.goto(f"{server.url}/?segment={s}")
        expect(body).to_have_attribute("data-state", "ready", timeout=WAIT_MS)
        expect(page.locator("#selected-label")).to_have_attribute("data-label", flipped)
        expect(page.locator("#selected-reviewed")).to_have_attribute("data-reviewed", "true")
        expect(scene).to_contain_text(f"label {flipped} (reviewed)", timeout=WAIT_MS)
        page.screenshot(path=shots / "review.png")

        # The camera image with the labels on it: a click on another segment's point there
        # selects that segment; i hides the image and shows it again.
        image = _get(f"{server.url}/api/segments/{s}")["image_id"]
        camera = page.locator("#camera-overlay")
        expect(camera).to_have_attribute(
            "src", re.compile(rf"/api/images/{image}/overlay\?segment={s}&")
        )
        expect(camera).to_have_attribute("data-loaded", "true")
        # v enlarges it; the wheel zooms about the pointer (the image pixel under it stays).
        page.locator("#selected-id").click()
        page.keyboard.press("v")
        zoomed = page.locator("#zoom-image")
        expect(page.locator("#camera-zoom")).to_be_visible()
        expect(zoomed).to_have_attribute("src", re.compile(rf"segment={s}&"))
        view = page.locator("#zoom-view")
        expect(view).to_have_attribute("data-scale", "1.000")
        box = _box(zoomed)
        natural_w, natural_h = zoomed.evaluate("i => [i.naturalWidth, i.naturalHeight]")
        at = (box["x"] + 0.4 * box["width"], box["y"] + 0.6 * box["height"])
        page.mouse.move(*at)
        page.mouse.wheel(0, -100)
        expect(view).to_have_attribute("data-scale", "1.250")
        zoom_box = _box(zoomed)
        assert zoom_box["width"] == pytest.approx(1.25 * box["width"], rel=1e-3)
        for k in (0, 1):  # the pointer's image pixel: 40 % across, 60 % down, as before
            share = (at[k] - zoom_box["xy"[k]]) / zoom_box[("width", "height")[k]]
            assert share == pytest.approx((0.4, 0.6)[k], abs=1e-3)
        # A click picks the point within 8 screen pixels at this zoom (static/js/camera.js).
        radius = math.ceil(8 * natural_w / zoom_box["width"])
        target, (x, y) = _point_to_click(drive_path, run_path, image, s, radius)
        done = int(body.get_attribute("data-actions") or 0)
        click = (
            zoom_box["x"] + (x + 0.5) * zoom_box["width"] / natural_w,
            zoom_box["y"] + (y + 0.5) * zoom_box["height"] / natural_h,
        )
        view_box = _box(view)
        assert view_box["x"] <= click[0] <= view_box["x"] + view_box["width"], "off the view"
        assert view_box["y"] <= click[1] <= view_box["y"] + view_box["height"], "off the view"
        with page.expect_response(_api("GET", f"/api/images/{image}/pick")) as answer:
            page.mouse.click(*click)
        assert answer.value.ok and answer.value.json()["segment"] == target, answer.value.text()
        expect(body).to_have_attribute("data-actions", str(done + 1), timeout=WAIT_MS)
        expect(page.locator("#selected-id")).to_have_text(str(target))
        assert _get(f"{server.url}/api/selection")["segments"] == [target]
        expect(camera).to_have_attribute("src", re.compile(rf"segment={target}&"))
        expect(camera).to_have_attribute("data-loaded", "true")
        expect(zoomed).to_have_attribute("src", re.compile(rf"segment={target}&"))
        page.screenshot(path=shots / "camera-enlarged.png")
        page.keyboard.press("Escape")
        expect(page.locator("#camera-zoom")).to_be_hidden()
        page.screenshot(path=shots / "camera.png")
        page.locator("#selected-id").click()
        page.keyboard.press("i")
        expect(page.locator("#camera-figure")).to_be_hidden()
        page.keyboard.press("i")
        expect(page.locator("#camera-figure")).to_be_visible()

        # The route overview lists the runs in order along the drive, coloured by the share of
        # what the queue asks about each that is reviewed, and flies to one: a click on a row
        # selects that run's segment to look at, which the 3D scene follows; [ goes back.
        runs = _get(f"{server.url}/api/overview")["runs"]
        assert len(runs) >= 2
        rows = page.locator("#route-table tbody tr")
        expect(rows).to_have_count(len(runs))
        lines = page.locator("#route-map polyline.route-run")
        expect(lines).to_have_count(len(runs))
        for k, run in enumerate(runs):
            expect(rows.nth(k)).to_have_attribute("data-run", str(run["run_id"]))
            expect(rows.nth(k)).to_have_attribute("data-state", run["state"])
            expect(lines.nth(k)).to_have_attribute("data-progress", _js_number(run["progress"]))
            expect(lines.nth(k)).to_have_css("stroke", _progress_colour(run["progress"]))
        for k, key in ((1, None), (0, "[")):
            done = int(body.get_attribute("data-actions") or 0)
            with page.expect_response(_api("PUT", "/api/selection")) as answer:
                if key is None:
                    rows.nth(k).click()
                else:
                    page.locator("#selected-id").click()
                    page.keyboard.press(key)
            assert answer.value.ok, answer.value.text()
            expect(body).to_have_attribute("data-actions", str(done + 1), timeout=WAIT_MS)
            target = runs[k]["segment"]
            expect(page.locator("#selected-id")).to_have_text(str(target))
            assert _get(f"{server.url}/api/selection")["segments"] == [target]
            expect(rows.nth(k)).to_have_class(re.compile(r"\bcurrent\b"))
            expect(scene).to_contain_text(re.compile(rf"Segment {target}\b"), timeout=WAIT_MS)
        # Flying to a run made the queue that run's doubtful segments along the road; w goes
        # back to the whole drive's queue.
        first = runs[0]["run_id"]
        expect(page.locator("#queue-panel")).to_have_attribute("data-run", str(first))
        along = _get(f"{server.url}/api/queue?run={first}&limit=200")["items"]
        items = page.locator("#queue li")
        expect(items).to_have_count(len(along))
        for k, item in enumerate(along):
            expect(items.nth(k)).to_have_attribute("data-id", str(item["id"]))
        page.locator("#route-panel").screenshot(path=shots / "route.png")
        # The guardrail segments on no run are a queue of their own, reached from the panel.
        off = _get(f"{server.url}/api/overview")["segments_off_runs"]
        if off:
            page.locator("#off-runs").click()
            expect(page.locator("#queue-panel")).to_have_attribute("data-run", "off")
            listed = _get(f"{server.url}/api/queue/off-runs?limit=200")["items"]
            expect(items).to_have_count(len(listed))
        else:
            expect(page.locator("#off-runs")).to_be_hidden()
        # The way back to the whole drive's queue is a button its text fits in.
        whole_button = page.locator("#queue-whole")
        expect(whole_button).to_be_visible()
        assert whole_button.evaluate("b => b.scrollWidth <= b.clientWidth")
        assert whole_button.evaluate("b => b.scrollHeight <= b.clientHeight")
        page.locator("#selected-id").click()
        page.keyboard.press("w")
        expect(page.locator("#queue-panel")).to_have_attribute("data-run", "")
        whole = _get(f"{server.url}/api/queue?limit=10")["items"]
        expect(items).to_have_count(len(whole))
        expect(items.first).to_have_attribute("data-id", str(whole[0]["id"]))

        # Tune a pipe run in the scene's panel: its x histogram and threshold are drawn, and
        # when the threshold's slider moves one step the plot is redrawn with the threshold the
        # histogram route gives for the new factor.
        frame = page.frame_locator("#scene")
        frame.get_by_text("Reconstruction", exact=True).click()
        choice = frame.locator('input[aria-haspopup="listbox"][value^="run "]')
        before = choice.input_value()
        choice.click()
        option = frame.get_by_role("option", name=re.compile(r"\(pipe,")).first
        chosen = option.inner_text().strip()
        option.click()
        expect(choice).to_have_value(chosen)
        run_id = chosen.split()[1]
        # Choosing another run plots it and then re-runs its unit model, whose line ends with the
        # time it took; the slider is moved once that line is shown, so that no update of the
        # panel from the server comes while the key is pressed.
        tuned = re.compile(
            rf"run {run_id}: .* threshold ([0-9.]+) points/bin \(factor ([0-9.]+)\)"
            + (r" · \d+ ms" if chosen != before else "")
        )
        expect(scene).to_contain_text(tuned, timeout=WAIT_MS)
        threshold, factor = tuned.search(scene.inner_text()).groups()  # type: ignore[union-attr]
        histogram = _get(f"{server.url}/api/runs/{run_id}/histogram?histogram_factor={factor}")
        assert f"{histogram['threshold']:.1f}" == threshold
        # The threshold's factor (1-6, 0.1 a step): the View folder's point size slider is 1-15.
        slider = frame.locator('[role="slider"][aria-valuemax="6"]')
        expect(slider).to_have_attribute("aria-valuenow", factor)
        slider.press("ArrowRight")
        moved = f"{float(factor) + 0.1:.1f}"
        expect(slider).to_have_attribute("aria-valuenow", moved)
        histogram = _get(f"{server.url}/api/runs/{run_id}/histogram?histogram_factor={moved}")
        assert f"{histogram['threshold']:.1f}" != threshold  # the factor text changes either way
        expect(scene).to_contain_text(
            f"threshold {histogram['threshold']:.1f} points/bin (factor {moved})", timeout=WAIT_MS
        )
        page.screenshot(path=shots / "tuning.png")

        # Lasso points in the 3D view: its corners clicked on the scene, then closed; the page
        # shows the lasso, g labels the points taken (not their whole segments), z undoes it.
        frame.get_by_role("button", name="Lasso points").click()
        canvas = frame.locator("canvas[data-engine]")  # three.js's, not viser's helpers'
        box = canvas.bounding_box()
        assert box is not None
        # Corners on the 3D view (the GUI panel stands beside it, fixed).
        for fx, fy in ((0.08, 0.3), (0.55, 0.3), (0.55, 0.9), (0.3, 0.6), (0.08, 0.9)):
            canvas.click(position={"x": fx * box["width"], "y": fy * box["height"]})
        frame.get_by_role("button", name="Close the lasso").click()
        expect(page.locator("#lasso-line")).to_be_visible(timeout=WAIT_MS)
        taken = _get(f"{server.url}/api/selection")["lasso_points"]
        assert taken > 0
        # The scene's panel and the page follow the server's selection when they next hear of it.
        expect(scene).to_contain_text(f"Lasso: {taken:,} points", timeout=WAIT_MS)
        expect(page.locator("#lasso-line")).to_contain_text(f"{taken:,} points", timeout=WAIT_MS)
        before = _get(f"{server.url}/api/info")["label_counts"]
        page.locator("#selected-id").click()
        done = int(body.get_attribute("data-actions") or 0)
        with page.expect_response(_api("POST", "/api/labels/lasso")) as answer:
            page.keyboard.press("g")
        assert answer.value.ok, answer.value.text()
        changed = answer.value.json()["changed_points"]
        expect(body).to_have_attribute("data-actions", str(done + 1), timeout=WAIT_MS)
        latest = _get(f"{server.url}/api/labels/history?limit=1")["items"][0]
        assert latest["note"] == f"lasso of {taken} points" and latest["new"] == "guardrail"
        after = _get(f"{server.url}/api/info")["label_counts"]
        assert after["guardrail_points"] - before["guardrail_points"] == changed > 0
        page.screenshot(path=shots / "lasso.png")
        with page.expect_response(_api("POST", "/api/labels/undo")) as answer:
            page.keyboard.press("z")
        assert answer.value.json()["changed_points"] == changed
        expect(body).to_have_attribute("data-actions", str(done + 2), timeout=WAIT_MS)
        assert _get(f"{server.url}/api/info")["label_counts"] == {
            **before,
            "batches": before["batches"] + 2,
        }
        # A lasso being drawn does not outlive a reload of the page (the next clicks would
        # silently become its corners), and Escape on the page cancels one.
        lasso_start = frame.get_by_role("button", name="Lasso points")
        lasso_close = frame.get_by_role("button", name="Close the lasso")
        for cancel in ("reload", "Escape"):
            lasso_start.click()
            canvas.click(position={"x": 0.1 * box["width"], "y": 0.3 * box["height"]})
            expect(lasso_close).to_be_visible()
            if cancel == "reload":
                page.reload()
                expect(body).to_have_attribute("data-state", "ready", timeout=WAIT_MS)
            else:
                page.locator("#selected-id").click()
                page.keyboard.press("Escape")
            expect(lasso_close).to_be_hidden(timeout=WAIT_MS)
            expect(lasso_start).to_be_visible()

        # A crash of the server loses no label: kill it, start it again, reload.
        server.kill()
        server.start()
        page.goto(f"{server.url}/?segment={s}")
        expect(body).to_have_attribute("data-state", "ready", timeout=WAIT_MS)
        expect(page.locator("#selected-id")).to_have_text(str(s))
        expect(page.locator("#selected-label")).to_have_attribute("data-label", flipped)
        expect(page.locator("#selected-reviewed")).to_have_attribute(
            "data-reviewed", "true", timeout=WAIT_MS
        )

        # Fine-tune from the labels, see the new model beside the current one, activate it.
        before = _get(f"{server.url}/api/models")["active"]
        job, active = _fine_tune_and_activate(page, shots / "fine-tune.png")
        assert _get(f"{server.url}/api/jobs/{job}")["result"]["version"] == active
        assert active != before and _get(f"{server.url}/api/models")["active"] == active
        expect(page.locator("#header-model")).to_contain_text(active[:15], timeout=WAIT_MS)
        row = _get(f"{server.url}/api/segments/{s}")
        assert row["label"] == flipped, "an operator's label outlives a model change"

        # The gallery: crops, keyboard labelling, a link back to the 3D view.
        page.goto(f"{server.url}/gallery")
        crops = page.locator('#gallery-grid .crop[data-reviewed="false"]')
        expect(crops.first).to_be_visible(timeout=WAIT_MS)
        first_id = int(crops.first.get_attribute("data-id") or -1)
        first = page.locator(f'#gallery-grid .crop[data-id="{first_id}"]')
        first.click()
        expect(first).to_have_class(re.compile(r"\bfocused\b"))
        with page.expect_response(_api("PUT", f"/api/segments/{first_id}/label")) as answer:
            page.keyboard.press("o")
        assert answer.value.ok, answer.value.text()
        expect(first).to_have_attribute("data-reviewed", "true")
        expect(first).to_have_attribute("data-label", "other")
        row = _get(f"{server.url}/api/segments/{first_id}")
        assert row["label"] == "other" and row["reviewed"] is True
        with page.expect_response(_api("POST", "/api/labels/undo")) as answer:
            page.keyboard.press("z")
        assert answer.value.ok, answer.value.text()
        assert first_id in [x["id"] for x in answer.value.json()["segments"]]
        expect(first).to_have_attribute("data-reviewed", "false")
        assert _get(f"{server.url}/api/segments/{first_id}")["reviewed"] is False
        page.screenshot(path=shots / "gallery.png")
        browser.close()
    assert not errors, errors


#: The action bar's controls, which must stay in view and in place.
BAR_CONTROLS = (
    "#label-guardrail",
    "#label-other",
    "#label-run-guardrail",
    "#label-run-other",
    "#undo",
    "#next",
    "#auto-advance",
)
#: Its lines of text, whose width changes with what they say.
BAR_TEXTS = ("#bar-selection", "#queue-position")


def _bar_boxes(page) -> dict[str, dict]:  # type: ignore[no-untyped-def]
    """Where each action bar control is on the screen (CSS pixels), and the top and height of
    its lines of text."""
    boxes = {name: page.locator(name).bounding_box() for name in BAR_CONTROLS}
    for name in BAR_TEXTS:
        box = page.locator(name).bounding_box()
        boxes[name] = box and {k: box[k] for k in ("y", "height")}
    return boxes


@pytest.mark.parametrize("width, height", [(1280, 720), (1920, 1080)])
def test_an_operator_reviews_to_done_with_one_key_per_decision(
    server: Server, shots: Path, width: int, height: int
) -> None:
    """At 1280x720 and 1920x1080 the action bar is in view and stays in place while the
    details load; each key labels the selection and goes on to the next segment the queue
    asks about, until the page says the review is done; the route map's colours follow the
    share reviewed."""
    from playwright.sync_api import expect, sync_playwright

    assert CHROMIUM.is_file(), "browser tests need Debian's chromium (make test installs it)"
    url = server.url
    asked = _get(f"{url}/api/queue?limit=500")
    assert 0 < asked["asked"] <= 40, "the test street's queue is short enough to finish"
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": width, "height": height})
        page.set_default_timeout(WAIT_MS)
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        body = page.locator("body")
        page.goto(url)
        expect(body).to_have_attribute("data-state", "ready", timeout=WAIT_MS)
        boxes = _bar_boxes(page)
        for name, box in boxes.items():
            assert box is not None, name
            assert box["y"] >= 0 and box["y"] + box["height"] <= height, (name, box)
            if "x" in box:
                assert box["x"] >= 0 and box["x"] + box["width"] <= width, (name, box)
        position = page.locator("#queue-position")
        expect(position).to_have_text(f"{asked['asked']} asked")

        # n: the first segment asked; its crop, camera image and history load below the bar.
        page.locator("#bar-selection").click()
        done = int(body.get_attribute("data-actions") or 0)
        page.keyboard.press("n")
        expect(body).to_have_attribute("data-actions", str(done + 1), timeout=WAIT_MS)
        first = asked["items"][0]["id"]
        expect(page.locator("#selected-id")).to_have_text(str(first))
        if _get(f"{url}/api/segments/{first}")["image_id"] is not None:
            expect(page.locator("#camera-overlay")).to_have_attribute("data-loaded", "true")
        expect(position).to_have_text(f"1 of {asked['asked']} asked")
        assert _bar_boxes(page) == boxes, "the action bar moved while the details loaded"
        page.screenshot(path=shots / f"bar-{width}x{height}.png")

        # A guardrail run from the route panel to done: a click on it makes the queue that run's, along
        # the road; one key per decision, the truth's label, until it asks nothing more there.
        runs = _get(f"{url}/api/overview")["runs"]
        run = next(r for r in runs if r["asked"])
        done = int(body.get_attribute("data-actions") or 0)
        page.locator(f'#route-table tbody tr[data-run="{run["run_id"]}"]').click()
        expect(body).to_have_attribute("data-actions", str(done + 1), timeout=WAIT_MS)
        expect(page.locator("#queue-panel")).to_have_attribute("data-run", str(run["run_id"]))
        expect(page.locator("#selected-id")).to_have_text(str(run["segment"]))
        keys, labelled = _label_until_done(page, url, boxes)
        assert keys <= run["asked"] + 1  # the segment flown to, if the queue did not ask it
        expect(position).to_have_text("✓ this run is done")
        after = next(r for r in _get(f"{url}/api/overview")["runs"] if r["run_id"] == run["run_id"])
        assert after["state"] == "done" and after["progress"] == 1 and after["asked"] == 0
        line = page.locator(f'#route-map polyline.route-run[data-run="{run["run_id"]}"]')
        expect(line).to_have_attribute("data-progress", "1")  # drawn blue: the run flown to
        row = page.locator(f'#route-table tbody tr[data-run="{run["run_id"]}"]')
        expect(row).to_have_attribute("data-state", "done")
        expect(row.locator("td").last).to_have_text("done")
        # w: the whole drive's queue, to done.
        page.locator("#bar-selection").click()
        done = int(body.get_attribute("data-actions") or 0)
        page.keyboard.press("w")
        expect(body).to_have_attribute("data-actions", str(done + 1), timeout=WAIT_MS)
        expect(page.locator("#queue-panel")).to_have_attribute("data-run", "")
        if position.get_attribute("data-done") != "true":  # n: the first one it asks about
            done = int(body.get_attribute("data-actions") or 0)
            page.keyboard.press("n")
            expect(body).to_have_attribute("data-actions", str(done + 1), timeout=WAIT_MS)
        more, also = _label_until_done(page, url, boxes)
        keys, labelled = keys + more, labelled + also
        assert keys <= asked["asked"] + 1, "more keys than segments asked"
        queue = _get(f"{url}/api/queue?limit=10")
        assert queue["done"] and queue["asked"] == 0
        assert keys == len(set(labelled)) == queue["reviewed"]  # one key per decision
        expect(position).to_have_text("✓ review done")
        expect(page.locator("#queue-empty")).to_be_visible()
        # Every run is done, and the map says so in its colours.
        runs = _get(f"{url}/api/overview")["runs"]
        lines = page.locator("#route-map polyline.route-run")
        expect(lines).to_have_count(len(runs))
        for k, run in enumerate(runs):
            assert run["state"] == "done" and run["progress"] == 1
            expect(lines.nth(k)).to_have_attribute("data-progress", "1")
            if "current" not in (lines.nth(k).get_attribute("class") or ""):  # blue: flown to
                expect(lines.nth(k)).to_have_css("stroke", _progress_colour(1.0))
        page.screenshot(path=shots / f"done-{width}x{height}.png")
        browser.close()
    assert not errors, errors


@pytest.fixture()
def shipped_server(drive_path: Path, shipped_run_path: Path, tmp_path: Path) -> Iterator[Server]:
    """``guardrail serve DRIVE --run RUN`` on a run the shipped default model made."""
    yield from _serve_a_copy(drive_path, shipped_run_path, None, tmp_path)


def test_fine_tuning_the_shipped_model_from_the_page(shipped_server: Server, shots: Path) -> None:
    """The page's Fine-tune button on a run of the shipped default model (which reads the
    whole component's features): with labels of one kind only it says so and what to do; with
    labels of both, a new model comes back, and activating it re-predicts the run."""
    from playwright.sync_api import expect, sync_playwright

    assert CHROMIUM.is_file(), "browser tests need Debian's chromium (make test installs it)"
    url = shipped_server.url
    shipped = _get(f"{url}/api/models")["active"]
    every = list(range(_get(f"{url}/api/info")["n_segments"]))
    _send("POST", f"{url}/api/labels/batch", {"segments": every, "label": "other"})

    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1440, "height": 900})
        page.set_default_timeout(WAIT_MS)
        errors: list[str] = []
        page.on("pageerror", lambda exc: errors.append(str(exc)))
        body = page.locator("body")
        page.goto(url)
        expect(body).to_have_attribute("data-state", "ready", timeout=WAIT_MS)
        expect(page.locator("#header-model")).to_contain_text(shipped[:15])

        # Every segment labelled other: nothing to learn guardrails from, and the page says so.
        message = page.locator("#train-message")
        page.locator("#train").click()
        expect(message).to_contain_text("Not enough labels to learn from yet", timeout=JOB_MS)
        expect(message).to_contain_text("Label more segments (g guardrail, o other)")
        expect(message).to_have_attribute("title", re.compile(r"^TrainingDataError: "))
        expect(page.locator("#train")).to_be_enabled()
        page.screenshot(path=shots / "fine-tune-refused.png")

        # Undone, ten labels from the queue as they stand, and Fine-tune again.
        _send("POST", f"{url}/api/labels/undo", {})
        for row in _get(f"{url}/api/queue?limit=10")["items"]:
            _send("PUT", f"{url}/api/segments/{row['id']}/label", {"label": row["label"]})
        job, active = _fine_tune_and_activate(page, shots / "fine-tune-shipped.png")
        expect(message).not_to_contain_text("failed")
        assert active == _get(f"{url}/api/jobs/{job}")["result"]["version"] != shipped
        expect(page.locator("#header-model")).to_contain_text(active[:15], timeout=WAIT_MS)
        assert _get(f"{url}/api/info")["model"]["version"] == active
        browser.close()
    assert not errors, errors


def _fine_tune_and_activate(page, shot: Path) -> tuple[str, str]:  # type: ignore[no-untyped-def]
    """Press Fine-tune, wait for the new model beside the current one (``shot`` then), press
    Activate and wait until the page has shown it: the job's id and the active version."""
    from playwright.sync_api import expect

    body = page.locator("body")
    with page.expect_response(_api("POST", "/api/train")) as answer:
        page.locator("#train").click()
    assert answer.value.status == 202, answer.value.text()
    job = answer.value.json()["job"]
    expect(page.locator("#activate")).to_be_visible(timeout=JOB_MS)
    expect(page.locator("#compare-table")).to_contain_text("guardrail", timeout=WAIT_MS)
    # One measure per name: the caption says on what both were measured, and Activate is the
    # suggested button only when the new model is not worse there.
    origin = urlsplit(page.url)
    result = _get(f"{origin.scheme}://{origin.netloc}/api/jobs/{job}")["result"]
    held = result["metrics_new"]
    if held is not None:
        expect(page.locator("#compare-caption")).to_contain_text(
            f"on {held['n_held_out']:,} held-out segments of this run folder"
        )
        worse = held["guardrail"]["f1"] < result["metrics_current"]["guardrail"]["f1"] - 0.0005
        suggested, other = ("#keep", "#activate") if worse else ("#activate", "#keep")
        expect(page.locator(suggested)).to_have_class(re.compile(r"\bbtn-primary\b"))
        expect(page.locator(other)).not_to_have_class(re.compile(r"\bbtn-primary\b"))
    page.screenshot(path=shot)
    done = int(body.get_attribute("data-actions") or 0)
    with page.expect_response(_api("POST", "/api/models/*/activate"), timeout=JOB_MS) as answer:
        page.locator("#activate").click()
    assert answer.value.ok, answer.value.text()
    active = answer.value.json()["active"]
    expect(body).to_have_attribute("data-actions", str(done + 1), timeout=WAIT_MS)
    return job, active


def _label_until_done(page, url: str, boxes: dict) -> tuple[int, list[int]]:  # type: ignore[no-untyped-def]
    """Press the truth's label (else the model's) of the selected segment, one key each, until
    the queue in view asks nothing more; the action bar stays where ``boxes`` found it. The
    keys pressed and the segments labelled."""
    from playwright.sync_api import expect

    body = page.locator("body")
    position = page.locator("#queue-position")
    keys, labelled = 0, []
    while position.get_attribute("data-done") != "true":
        current = int(page.locator("#selected-id").inner_text())
        row = _get(f"{url}/api/segments/{current}")
        assert not row["reviewed"], "the page went on to a segment reviewed already"
        key = "g" if (row["truth"] or row["model_label"]) == "guardrail" else "o"
        done = int(body.get_attribute("data-actions") or 0)
        page.keyboard.press(key)
        keys += 1
        expect(body).to_have_attribute("data-actions", str(done + 1), timeout=WAIT_MS)
        labelled.append(current)
        assert _get(f"{url}/api/segments/{current}")["reviewed"] is True
        assert _bar_boxes(page) == boxes, "the action bar moved"
        assert keys <= 200, "the queue never ended"
    return keys, labelled


def _box(locator) -> dict[str, float]:  # type: ignore[no-untyped-def]
    """Where an element is drawn on the page (CSS pixels, its transform included)."""
    box = locator.bounding_box()
    assert box is not None
    return box


def _next_asked(before: list[int], after: list[int], labelled: int) -> int:
    """The segment the page goes on to after labelling ``labelled``: the first that followed
    it in the queue it had (``before``, wrapping round) and that the queue still asks about
    (``after``), else the first of ``after``."""
    at = before.index(labelled) if labelled in before else -1
    following = before[at + 1 :] + before[: max(at, 0)]
    return next((s for s in following if s in after and s != labelled), after[0])


#: The stops of the route map's progress scale (static/js/route.js): grey, amber, green.
_SCALE = ((0x9A, 0xA3, 0xAD), (0xE8, 0xA3, 0x3D), (0x1D, 0x8A, 0x45))


def _progress_colour(share: float) -> str:
    """The CSS colour the route map gives a run ``share`` reviewed."""
    t = min(1.0, max(0.0, share)) * (len(_SCALE) - 1)
    k = min(len(_SCALE) - 2, int(t))
    f = t - k
    # Math.round: halves go up.
    mix = [math.floor(a + (b - a) * f + 0.5) for a, b in zip(_SCALE[k], _SCALE[k + 1], strict=True)]
    return f"rgb({mix[0]}, {mix[1]}, {mix[2]})"


def _js_number(x: float) -> str:
    """``String(x)`` in JavaScript for a number the API sent as JSON."""
    return str(int(x)) if float(x).is_integer() else repr(float(x))


def _send(method: str, url: str, body: dict) -> dict:
    request = urllib.request.Request(
        url,
        data=json.dumps(body).encode(),
        headers={"Content-Type": "application/json"},
        method=method,
    )
    with urllib.request.urlopen(request, timeout=60) as answer:
        assert answer.status == 200, answer.status
        return json.loads(answer.read())


def _point_to_click(
    drive_path: Path, run_path: Path, image: int, not_segment: int, radius: int
) -> tuple[int, tuple[int, int]]:
    """A segment other than ``not_segment`` on camera image ``image`` and the pixel of its point
    nearest the camera, where no other segment's point nearer the camera lies within the pick
    ``radius`` (image pixels), and at
    least ``edge`` pixels inside the image: the page shows the image scaled, its bottom right
    corner under the selection panel, and a click meant for pixel (1022, 766) of a 1024 x 768
    image asked for (1024, 768)."""
    import numpy as np

    from app.image_overlay import ImageOverlay
    from app.run_tiles import RunTiles
    from guardrail_core.extract.crops import CropParams
    from guardrail_core.formats.drive import open_drive
    from guardrail_core.formats.run_folder_paths import RunFolder

    folder = RunFolder.open(run_path)
    params = CropParams.from_json(folder.info().params["crops"])
    source = open_drive(drive_path)
    tiles = RunTiles(source, folder, folder.segments()["time"])
    found = ImageOverlay(source, tiles, params).points(image)
    camera = source.cameras[source.images[image].camera]
    edge = 8
    segments, counts = np.unique(found.segment[found.segment >= 0], return_counts=True)
    for t in segments[counts >= 20]:
        if t == not_segment:
            continue
        mine = np.flatnonzero(found.segment == t)
        first = mine[np.argmin(found.depth[mine])]
        pixel = found.pixel[first]
        if not (edge <= pixel[0] < camera.width - edge and edge <= pixel[1] < camera.height - edge):
            continue
        # The pick takes the point nearest the camera within the radius: none of another
        # segment may lie there nearer the camera than this one.
        near = ((found.pixel - pixel) ** 2).sum(axis=1) <= (radius + 3) ** 2
        nearer = found.depth <= found.depth[first]
        if not (near & nearer & (found.segment != t) & (found.segment >= 0)).any():
            return int(t), (int(pixel[0]), int(pixel[1]))
    raise AssertionError(f"no segment stands clear on image {image}")


def _api(method: str, path: str):
    """A predicate for ``page.expect_response``: the answer to ``method path`` (``*`` matches
    one path part)."""
    pattern = re.compile("[^/]+".join(re.escape(part) for part in path.split("*")) + "$")

    def matches(response) -> bool:
        return response.request.method == method and bool(
            pattern.match(urlsplit(response.url).path)
        )

    return matches
