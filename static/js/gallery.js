// The gallery: every segment's crop in a grid, filtered, sorted and paged by
// the server (GET /api/segments). Arrow keys move a focus ring, g/o label the
// focused crop (or the shift+clicked ones, in one batch), z undoes, enter or a
// click on the id opens the segment in the 3D review page.
//
// The filters live in the page URL too, so reload and Back keep them.

import * as api from "./api.js";
import { int, pct, plural, toast } from "./api.js";

const PAGE_SIZE = 200;
const FILTER_KEYS = ["label", "reviewed", "min_probability", "max_probability", "crop", "sort"];

const $ = (id) => document.getElementById(id);
const grid = $("gallery-grid");

const state = {
  items: [], // Segment objects in display order
  elements: new Map(), // id -> .crop element
  total: 0,
  focus: -1, // index into items, -1 when none
  multi: new Set(), // shift+clicked ids
  generation: 0, // bumped on every filter change; older page loads are dropped
  lastQuery: null, // the filters of the grid shown, to skip needless reloads
  loading: false,
};

const run = api.serializer((err) => {
  console.error(err);
  toast(err.message || String(err), "error");
});

// ---- filters <-> controls <-> URL --------------------------------------

function readProbability(input, fallback) {
  const v = Number.parseFloat(input.value);
  return Number.isFinite(v) ? Math.min(1, Math.max(0, v)) : fallback;
}

/** The query for GET /api/segments, without offset/limit. */
function currentFilters() {
  let lo = readProbability($("filter-min"), 0);
  let hi = readProbability($("filter-max"), 1);
  if (lo > hi) [lo, hi] = [hi, lo];
  return {
    label: $("filter-label").value || null,
    reviewed: $("filter-reviewed").value || null,
    // The full range is left out, so that segments without a probability
    // (no crop and no segment head) are not filtered away.
    min_probability: lo > 0 ? lo : null,
    max_probability: hi < 1 ? hi : null,
    crop: $("filter-crop").checked ? "true" : null,
    sort: $("sort").value || "uncertainty",
  };
}

function filtersFromUrl() {
  const p = new URLSearchParams(window.location.search);
  const setSelect = (el, v) => {
    if (v !== null && [...el.options].some((o) => o.value === v)) el.value = v;
  };
  setSelect($("filter-label"), p.get("label"));
  setSelect($("filter-reviewed"), p.get("reviewed"));
  setSelect($("sort"), p.get("sort"));
  if (p.has("min_probability")) $("filter-min").value = p.get("min_probability");
  if (p.has("max_probability")) $("filter-max").value = p.get("max_probability");
  if (p.has("crop")) $("filter-crop").checked = p.get("crop") !== "false";
}

function filtersToUrl(filters) {
  const u = new URL(window.location.href);
  for (const k of FILTER_KEYS) u.searchParams.delete(k);
  for (const [k, v] of Object.entries(filters)) {
    if (v !== null && v !== undefined && v !== "") u.searchParams.set(k, String(v));
  }
  // The crop box is on by default: say so when it is off.
  if (!filters.crop) u.searchParams.set("crop", "false");
  history.replaceState(null, "", u.pathname + u.search);
}

// ---- loading --------------------------------------------------------------

async function reload() {
  const filters = currentFilters();
  const key = api.query(filters);
  if (key === state.lastQuery) return; // e.g. typing then blurring a number field
  state.lastQuery = key;
  filtersToUrl(filters);
  state.generation += 1;
  state.items = [];
  state.elements.clear();
  state.multi.clear();
  state.focus = -1;
  state.total = 0;
  state.loading = false;
  grid.replaceChildren();
  renderStatus();
  await loadPage();
}

async function loadPage() {
  if (state.loading) return;
  const generation = state.generation;
  state.loading = true;
  $("load-more").disabled = true;
  try {
    const q = { ...currentFilters(), offset: state.items.length, limit: PAGE_SIZE };
    const page = await api.get(`/api/segments${api.query(q)}`);
    if (generation !== state.generation) return; // filters changed meanwhile
    state.total = page.total ?? 0;
    const fragment = document.createDocumentFragment();
    for (const seg of page.items || []) {
      if (state.elements.has(seg.id)) continue; // shifted by a label change between pages
      state.items.push(seg);
      const el = renderCrop(seg);
      state.elements.set(seg.id, el);
      fragment.append(el);
    }
    grid.append(fragment);
  } catch (err) {
    if (generation === state.generation) showLoadError(err);
  } finally {
    if (generation === state.generation) {
      state.loading = false;
      $("load-more").disabled = false;
      renderStatus();
    }
  }
}

function showLoadError(err) {
  const auth = err.status === 401 || err.status === 403;
  const banner = $("banner");
  banner.textContent = auth && !api.token
    ? `This server needs a token: open the page as gallery.html?token=… (${err.message})`
    : `Could not load segments: ${err.message}`;
  banner.hidden = false;
}

function renderStatus() {
  const shown = state.items.length;
  $("gallery-count").textContent = state.loading && !shown
    ? "loading…"
    : `showing ${int(shown)} of ${int(state.total)}`;
  $("gallery-empty").hidden = state.loading || shown > 0;
  $("load-more").hidden = shown >= state.total;
  $("multi-status").textContent = state.multi.size
    ? `${plural(state.multi.size, "crop")} selected (g/o labels them, esc clears)`
    : "";
}

// ---- one crop -------------------------------------------------------------

function renderCrop(seg) {
  const el = document.createElement("div");
  el.className = "crop";
  el.setAttribute("role", "gridcell");
  el.dataset.id = String(seg.id);

  if (seg.crop_url) {
    const img = document.createElement("img");
    img.loading = "lazy";
    img.decoding = "async";
    img.width = 128;
    img.height = 128;
    img.alt = `crop of segment ${seg.id}`;
    img.src = api.imageUrl(seg.crop_url);
    el.append(img);
  } else {
    const ph = document.createElement("div");
    ph.className = "crop-missing";
    ph.textContent = seg.crop_status === "too_small" ? "too small" : "no crop";
    el.append(ph);
  }

  const check = document.createElement("span");
  check.className = "check";
  check.textContent = "✓";
  check.title = "reviewed";

  const meta = document.createElement("div");
  meta.className = "crop-meta";
  const link = document.createElement("a");
  link.className = "crop-id";
  link.href = api.withToken("index.html", { segment: seg.id });
  link.textContent = `#${seg.id}`;
  link.title = "open in the 3D view";
  const prob = document.createElement("span");
  prob.className = "crop-prob";
  meta.append(link, prob);

  el.append(check, meta);
  updateCrop(el, seg);
  return el;
}

/** Refresh the parts of a crop element that a label change can alter. */
function updateCrop(el, seg) {
  el.dataset.label = seg.label;
  el.dataset.reviewed = String(Boolean(seg.reviewed));
  el.classList.toggle("label-guardrail", seg.label === "guardrail");
  el.classList.toggle("label-other", seg.label === "other");
  el.classList.toggle("reviewed", Boolean(seg.reviewed));
  el.querySelector(".crop-prob").textContent = pct(seg.probability);
  el.title = `segment ${seg.id}: ${seg.label}${seg.reviewed ? " (reviewed)" : ""}, `
    + `model ${seg.model_label ?? "—"}, ${int(seg.n_points)} points`;
}

/** Apply the Segment objects of a label/undo response to the grid. */
function applySegments(segments) {
  for (const seg of segments || []) {
    const at = state.items.findIndex((s) => s.id === seg.id);
    if (at < 0) continue;
    state.items[at] = { ...state.items[at], ...seg };
    updateCrop(state.elements.get(seg.id), state.items[at]);
  }
}

// ---- focus ring and multi-selection ------------------------------------

function setFocus(index) {
  if (!state.items.length) return;
  const i = Math.max(0, Math.min(state.items.length - 1, index));
  const old = state.items[state.focus];
  if (old) state.elements.get(old.id)?.classList.remove("focused");
  state.focus = i;
  const el = state.elements.get(state.items[i].id);
  el.classList.add("focused");
  el.scrollIntoView({ block: "nearest" });
  // Near the end of what is loaded: fetch the next page ahead of the cursor.
  if (state.items.length - i <= columns() && state.items.length < state.total) loadPage();
}

function columns() {
  // Count the crops on the first row; the grid's layout decides.
  const first = grid.firstElementChild;
  if (!first) return 1;
  let n = 0;
  for (const el of grid.children) {
    if (el.offsetTop !== first.offsetTop) break;
    n += 1;
  }
  return Math.max(1, n);
}

function toggleMulti(id, on) {
  const want = on ?? !state.multi.has(id);
  if (want) state.multi.add(id);
  else state.multi.delete(id);
  state.elements.get(id)?.classList.toggle("selected", want);
  renderStatus();
}

function clearMulti() {
  for (const id of state.multi) state.elements.get(id)?.classList.remove("selected");
  state.multi.clear();
  renderStatus();
}

function focusedItem() {
  return state.focus >= 0 ? state.items[state.focus] : null;
}

// ---- actions --------------------------------------------------------------

async function label(labelName) {
  if (state.multi.size) {
    const ids = [...state.multi];
    const res = await api.post("/api/labels/batch", { segments: ids, label: labelName, expand: "none" });
    applySegments(res.segments);
    clearMulti();
    toast(`${plural((res.segments || []).length, "segment")} -> ${labelName} (${int(res.changed_points)} points)`);
    return;
  }
  const item = focusedItem();
  if (!item) {
    toast("click a crop or use the arrow keys first", "error");
    return;
  }
  const res = await api.put(`/api/segments/${item.id}/label`, { label: labelName });
  applySegments(res.segments);
  toast(`${plural((res.segments || []).length, "segment")} -> ${labelName} (${int(res.changed_points)} points)`);
}

async function undo() {
  const res = await api.post("/api/labels/undo");
  if (res.undone_batch === null || res.undone_batch === undefined) {
    toast("nothing to undo");
    return;
  }
  applySegments(res.segments);
  toast(`undid batch ${res.undone_batch}: ${plural((res.segments || []).length, "segment")} (${int(res.changed_points)} points)`);
}

function openInReview(id) {
  window.location.href = api.withToken("index.html", { segment: id });
}

// ---- events -------------------------------------------------------------

function onGridClick(event) {
  const el = event.target.closest(".crop[data-id]");
  if (!el) return;
  const id = Number(el.dataset.id);
  const index = state.items.findIndex((s) => s.id === id);
  if (event.shiftKey) {
    // Shift+click toggles a crop in the multi-selection (and never follows
    // the id link, which would open a new window).
    event.preventDefault();
    toggleMulti(id);
    setFocus(index);
    return;
  }
  if (event.target.closest("a.crop-id")) return; // the link opens the review page
  clearMulti();
  setFocus(index);
}

function onKeyDown(event) {
  if (event.ctrlKey || event.metaKey || event.altKey || api.isTyping(event)) return;
  // Space/enter on a focused button or link does its own thing.
  const onControl = event.target instanceof HTMLElement && event.target.closest("button, a, select");
  const step = { ArrowLeft: -1, ArrowRight: 1, ArrowUp: -columns(), ArrowDown: columns() }[event.key];
  if (step !== undefined) {
    event.preventDefault();
    const from = state.focus;
    const to = from < 0 ? 0 : from + step;
    setFocus(to);
    if (event.shiftKey) {
      // shift+arrow grows the multi-selection, like shift+click.
      if (from >= 0) toggleMulti(state.items[from].id, true);
      if (focusedItem()) toggleMulti(focusedItem().id, true);
    }
    return;
  }
  if (event.key === "Escape") {
    clearMulti();
    return;
  }
  if (event.key === "Enter") {
    if (onControl) return;
    const item = focusedItem();
    if (item) {
      event.preventDefault();
      openInReview(item.id);
    }
    return;
  }
  if (event.repeat) return;
  switch (event.key.toLowerCase()) {
    case "g":
      run(() => label("guardrail"));
      break;
    case "o":
      run(() => label("other"));
      break;
    case "z":
    case "u":
      run(undo);
      break;
    default:
      return;
  }
  event.preventDefault();
}

async function loadHeader() {
  try {
    const info = await api.get("/api/info");
    $("drive-name").textContent = info.drive ?? "—";
    $("run-name").textContent = info.run ?? "—";
    $("header-model").textContent = info.model?.version ?? "—";
    document.title = `Guardrail gallery — ${info.run ?? ""}`;
  } catch (err) {
    showLoadError(err);
  }
}

function init() {
  api.keepTokenInLinks();
  filtersFromUrl();

  const form = $("filters");
  form.addEventListener("submit", (e) => e.preventDefault());
  form.addEventListener("change", () => reload());
  // Number fields: follow typing too, a moment after it stops.
  let typingTimer = null;
  for (const id of ["filter-min", "filter-max"]) {
    $(id).addEventListener("input", () => {
      clearTimeout(typingTimer);
      typingTimer = setTimeout(() => reload(), 500);
    });
  }
  // After choosing a filter, hand the keys back to the grid.
  for (const el of form.querySelectorAll("select, input[type=checkbox]")) {
    el.addEventListener("change", () => el.blur());
  }

  grid.addEventListener("click", onGridClick);
  document.addEventListener("keydown", onKeyDown);
  $("load-more").addEventListener("click", () => loadPage());

  loadHeader();
  reload();
}

init();
