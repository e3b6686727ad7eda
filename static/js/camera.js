// The selected segment's camera image with the points on it coloured by label:
// small under the segment's facts, and enlarged (v, or its button) with wheel
// zoom and drag. A click on a point of either selects that point's segment; a
// click counts within PICK_SCREEN_PX of a point on the screen, however far the
// image is zoomed.

import * as api from "./api.js";

const $ = (id) => document.getElementById(id);

// How near a click must land to a point, in screen pixels.
const PICK_SCREEN_PX = 8;
// The enlarged image's zoom range (1: the whole image fits).
const MAX_ZOOM = 10;
// A press that moves less than this many screen pixels is a click, not a drag.
const DRAG_PX = 4;

const camera = {
  show: true, // key i hides the small image
  select: async () => {}, // selects segment ids on the page and the server
  run: (fn) => fn(), // runs a page action after the ones before it
  zoom: { base: 1, scale: 1, x: 0, y: 0, drag: null },
};

/** Wire the image: `select(ids)` selects on the page, `run(fn)` queues an action. */
export function initCamera(select, run) {
  camera.select = select;
  camera.run = run;
  const img = $("camera-overlay");
  img.addEventListener("click", (e) => run(() => pickAt(img, e.clientX, e.clientY)));
  img.addEventListener("load", () => {
    img.dataset.loaded = "true";
  });
  $("camera-enlarge").addEventListener("click", openZoom);
  $("zoom-close").addEventListener("click", closeZoom);
  const view = $("zoom-view");
  view.addEventListener("wheel", onWheel, { passive: false });
  view.addEventListener("pointerdown", onPointerDown);
  view.addEventListener("pointermove", onPointerMove);
  view.addEventListener("pointerup", onPointerUp);
  $("zoom-image").addEventListener("load", fitZoom);
  window.addEventListener("resize", () => {
    if (!$("camera-zoom").hidden) fitZoom();
  });
}

/** Show segment `d`'s camera image (or hide the figure when it has none, or i hid it). */
export function renderCamera(d, labelsVersion) {
  const figure = $("camera-figure");
  const img = $("camera-overlay");
  const show = camera.show && d.image_id !== null && d.image_id !== undefined;
  figure.hidden = !show;
  if (!show) return;
  const url = `/api/images/${d.image_id}/overlay${api.query({ segment: d.id, v: labelsVersion })}`;
  const src = api.imageUrl(url);
  if (img.getAttribute("src") !== src) {
    img.dataset.loaded = "false";
    img.src = src;
    if (!$("camera-zoom").hidden) $("zoom-image").src = src;
  }
  img.dataset.image = String(d.image_id);
}

/** Key i: hide or show the small image. */
export function toggleCamera(d, labelsVersion) {
  camera.show = !camera.show;
  if (d) renderCamera(d, labelsVersion); // without a selection there is no image
}

/** Key v: enlarge the image, or close the enlarged one. */
export function toggleZoom() {
  if ($("camera-zoom").hidden) openZoom();
  else closeZoom();
}

/** Whether the enlarged image is open (Escape closes it first). */
export const zoomOpen = () => !$("camera-zoom").hidden;

function openZoom() {
  const small = $("camera-overlay");
  if ($("camera-figure").hidden || !small.getAttribute("src")) return;
  const img = $("zoom-image");
  img.dataset.image = small.dataset.image;
  if (img.getAttribute("src") !== small.getAttribute("src")) img.src = small.src;
  $("camera-zoom").hidden = false;
  fitZoom();
}

export function closeZoom() {
  $("camera-zoom").hidden = true;
}

/** The whole image fits the view, centred, unzoomed. */
function fitZoom() {
  const img = $("zoom-image");
  const view = $("zoom-view");
  if (!img.naturalWidth || !view.clientWidth) return;
  const z = camera.zoom;
  z.base = Math.min(view.clientWidth / img.naturalWidth, view.clientHeight / img.naturalHeight);
  z.scale = 1;
  z.x = (view.clientWidth - img.naturalWidth * z.base) / 2;
  z.y = (view.clientHeight - img.naturalHeight * z.base) / 2;
  img.style.width = `${img.naturalWidth * z.base}px`;
  img.style.height = `${img.naturalHeight * z.base}px`;
  applyZoom();
}

function applyZoom() {
  const z = camera.zoom;
  $("zoom-image").style.transform = `translate(${z.x}px, ${z.y}px) scale(${z.scale})`;
  $("zoom-view").dataset.scale = z.scale.toFixed(3);
}

function onWheel(event) {
  event.preventDefault();
  const z = camera.zoom;
  const box = $("zoom-view").getBoundingClientRect();
  const px = event.clientX - box.left;
  const py = event.clientY - box.top;
  const scale = Math.min(MAX_ZOOM, Math.max(1, z.scale * (event.deltaY < 0 ? 1.25 : 0.8)));
  // The image point under the pointer stays under it.
  z.x = px - ((px - z.x) * scale) / z.scale;
  z.y = py - ((py - z.y) * scale) / z.scale;
  z.scale = scale;
  applyZoom();
}

function onPointerDown(event) {
  const z = camera.zoom;
  z.drag = { x0: event.clientX, y0: event.clientY, x: z.x, y: z.y, moved: false };
  $("zoom-view").setPointerCapture(event.pointerId);
}

function onPointerMove(event) {
  const z = camera.zoom;
  if (!z.drag) return;
  const dx = event.clientX - z.drag.x0;
  const dy = event.clientY - z.drag.y0;
  if (Math.hypot(dx, dy) >= DRAG_PX) z.drag.moved = true;
  if (!z.drag.moved) return;
  z.x = z.drag.x + dx;
  z.y = z.drag.y + dy;
  applyZoom();
}

function onPointerUp(event) {
  const z = camera.zoom;
  const drag = z.drag;
  z.drag = null;
  if (drag && !drag.moved) {
    camera.run(() => pickAt($("zoom-image"), event.clientX, event.clientY));
  }
}

/**
 * Select the segment of the point nearest the camera within PICK_SCREEN_PX of a
 * click at (clientX, clientY) on `img`, however it is scaled on the screen.
 */
async function pickAt(img, clientX, clientY) {
  if (!img.naturalWidth || !img.clientWidth) return;
  const box = img.getBoundingClientRect(); // the transformed box: scale included
  const perScreenPx = img.naturalWidth / box.width;
  const x = (clientX - box.left) * perScreenPx;
  const y = (clientY - box.top) * (img.naturalHeight / box.height);
  if (x < 0 || y < 0 || x >= img.naturalWidth || y >= img.naturalHeight) return;
  const radius = Math.max(1, Math.ceil(PICK_SCREEN_PX * perScreenPx));
  const res = await api.get(`/api/images/${img.dataset.image}/pick${api.query({ x, y, radius })}`);
  if (res.segment === null) {
    api.toast("no segment there: click on a point");
    return;
  }
  await camera.select([res.segment]);
}
