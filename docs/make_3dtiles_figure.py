"""A picture of a run's 3D Tiles export in CesiumJS, for docs/export.md.

Exports the run (``guardrail export RUN --3dtiles``) into a temporary folder, installs CesiumJS
from the npm registry into ``--cesium-dir`` once (``npm install cesium``; nothing is fetched at
view time: no imagery, no terrain, no Cesium ion), serves both over HTTP on a free local port,
opens them in Debian's Chromium with Playwright, waits until every tile is loaded, and writes
``docs/images/export_3dtiles_cesium.png``.

    .venv/bin/python docs/make_3dtiles_figure.py RUN_DIR [--cesium-dir /tmp/cesium]
"""

from __future__ import annotations

import argparse
import functools
import http.server
import shutil
import subprocess
import sys
import tempfile
import threading
from pathlib import Path

from playwright.sync_api import sync_playwright

ROOT = Path(__file__).resolve().parent.parent
OUT = ROOT / "docs" / "images" / "export_3dtiles_cesium.png"
CHROMIUM_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]

PAGE = """<!doctype html><html><head><meta charset="utf-8">
<script src="node_modules/cesium/Build/Cesium/Cesium.js"></script>
<link href="node_modules/cesium/Build/Cesium/Widgets/widgets.css" rel="stylesheet">
<style>html,body,#c{width:100%;height:100%;margin:0}</style></head>
<body><div id="c"></div><script>
window.report = {errors: [], done: false};
(async () => {
  try {
    const viewer = new Cesium.Viewer("c", {baseLayer: false, baseLayerPicker: false,
      geocoder: false, timeline: false, animation: false, homeButton: false,
      sceneModePicker: false, navigationHelpButton: false, fullscreenButton: false,
      infoBox: false, selectionIndicator: false});
    const tileset = await Cesium.Cesium3DTileset.fromUrl("tiles/tileset.json");
    tileset.tileFailed.addEventListener((e) => window.report.errors.push(String(e.message)));
    viewer.scene.primitives.add(tileset);
    await viewer.zoomTo(tileset, new Cesium.HeadingPitchRange(
      Cesium.Math.toRadians(200), Cesium.Math.toRadians(-20), 45));
    tileset.allTilesLoaded.addEventListener(() => { window.report.done = true; });
  } catch (e) { window.report.errors.push(String(e && e.stack || e)); window.report.done = true; }
})();
</script></body></html>
"""


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--cesium-dir", type=Path, default=Path(tempfile.gettempdir()) / "cesium")
    args = parser.parse_args()
    if not (args.cesium_dir / "node_modules" / "cesium").is_dir():
        args.cesium_dir.mkdir(parents=True, exist_ok=True)
        subprocess.run(["npm", "install", "--prefix", str(args.cesium_dir), "cesium"], check=True)
    site = Path(tempfile.mkdtemp(prefix="cesium-site-"))
    try:
        guardrail = Path(sys.executable).with_name("guardrail")
        tiles = site / "tiles"
        subprocess.run(
            [str(guardrail), "export", str(args.run_dir), "--3dtiles", str(tiles)], check=True
        )
        (site / "node_modules").symlink_to(args.cesium_dir / "node_modules")
        (site / "index.html").write_text(PAGE)
        handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(site))
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
        threading.Thread(target=server.serve_forever, daemon=True).start()
        with sync_playwright() as playwright:
            browser = playwright.chromium.launch(
                executable_path="/usr/bin/chromium", args=CHROMIUM_ARGS
            )
            page = browser.new_page(viewport={"width": 1000, "height": 700})
            page.goto(f"http://127.0.0.1:{server.server_port}/index.html")
            page.wait_for_function("window.report.done", timeout=120_000)
            errors = page.evaluate("window.report.errors")
            if errors:
                raise SystemExit(f"CesiumJS could not show the tileset: {errors}")
            page.screenshot(path=str(OUT))
            browser.close()
        server.shutdown()
    finally:
        shutil.rmtree(site, ignore_errors=True)
    print(f"wrote {OUT}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
