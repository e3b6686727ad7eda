// The route panel of the review page: a map of the drive (the trajectory and
// every reconstructed guardrail run, coloured by the operators' progress on it)
// and the inventory table beside it. A click on a run, on the map or in the
// table, selects the run's most doubtful unreviewed segment: the 3D scene flies
// there, and the review queue becomes that run's doubtful segments along the road.
// `[` and `]` go to the previous and the next run along the drive.

import * as api from "./api.js";
import { int, plural, toast } from "./api.js";

const SVG = "http://www.w3.org/2000/svg";
const $ = (id) => document.getElementById(id);

const route = {
  overview: null, // GET /api/overview
  current: null, // the run_id last flown to
  select: async () => {}, // selects segments on the page and the server
  run: (fn) => fn(), // runs a page action after the ones before it
  review: async () => {}, // makes the review queue that of one run
};

/**
 * Wire the panel: `select(ids)` is the page's own selection (it moves the 3D
 * camera), `run(fn)` its queue of actions (a click is one), `review(runId)`
 * makes the review queue that run's, along the road.
 */
export function initRoute(select, run, review) {
  route.select = select;
  route.run = run;
  route.review = review;
  $("route-map").addEventListener("click", onClick);
  // What the table cannot reach: guardrail segments on no reconstructed run.
  $("off-runs").addEventListener("click", () => route.run(() => route.review("off")));
  $("route-table").addEventListener("click", onClick);
  $("route-table").addEventListener("keydown", (event) => {
    if (event.key === "Enter") onClick(event);
  });
}

/** Fetch the overview again (after labels changed) and redraw. */
export async function loadRoute() {
  route.overview = await api.get("/api/overview");
  renderRoute();
}

function onClick(event) {
  const target = event.target.closest("[data-run]");
  if (!target) return;
  route.run(() => flyTo(Number(target.dataset.run)));
}

/** Select run `runId`'s segment to look at, so the 3D scene flies to it. */
export async function flyTo(runId) {
  const run = route.overview?.runs.find((r) => r.run_id === runId);
  if (!run) return;
  route.current = runId;
  renderRoute();
  await route.review(runId);
  if (run.segment === null) {
    toast(`run ${runId} has no segment to look at`, "error");
    return;
  }
  await route.select([run.segment]);
  toast(`guardrail run ${runId}: ${reviewText(run)}`);
}

/** Fly to the run before (-1) or after (+1) the current one along the drive. */
export async function stepRun(direction) {
  const runs = route.overview?.runs || [];
  if (!runs.length) {
    toast("this run has no reconstructed guardrail runs");
    return;
  }
  const at = runs.findIndex((r) => r.run_id === route.current);
  const next = at < 0 ? (direction > 0 ? 0 : runs.length - 1) : at + direction;
  if (next < 0 || next >= runs.length) {
    toast(direction > 0 ? "the last run of the drive" : "the first run of the drive");
    return;
  }
  await flyTo(runs[next].run_id);
}

// The progress scale (style.css's .progress-scale draws the same stops): grey, amber, green.
const SCALE = [[0x9a, 0xa3, 0xad], [0xe8, 0xa3, 0x3d], [0x1d, 0x8a, 0x45]];

/** The colour of a run `share` (0..1) reviewed, as `rgb(r, g, b)`. */
export function progressColour(share) {
  const t = Math.max(0, Math.min(1, share)) * (SCALE.length - 1);
  const k = Math.min(SCALE.length - 2, Math.floor(t));
  const f = t - k;
  const mix = SCALE[k].map((a, i) => Math.round(a + (SCALE[k + 1][i] - a) * f));
  return `rgb(${mix.join(", ")})`;
}

function reviewText(run) {
  const asked = run.reviewed + run.asked;
  if (!run.asked) return `done, ${plural(run.reviewed, "segment")} reviewed`;
  return `${run.reviewed} of ${plural(asked, "segment")} asked reviewed`
    + (run.changed ? `, ${run.changed} changed` : "");
}

function renderRoute() {
  const overview = route.overview;
  if (!overview) return;
  renderMap(overview);
  renderTable(overview);
  const runs = overview.runs;
  const done = runs.filter((r) => r.state === "done").length;
  $("route-summary").textContent = `${(overview.length_m / 1000).toFixed(2)} km · `
    + `${plural(runs.length, "guardrail run")}, ${done} done`;
  const off = $("off-runs");
  off.hidden = !overview.segments_off_runs;
  off.textContent = `${plural(overview.segments_off_runs, "guardrail segment")} on no run ▸`;
}

function renderMap(overview) {
  const svg = $("route-map");
  svg.replaceChildren();
  const points = overview.trajectory.concat(...overview.runs.map((r) => r.path));
  if (!points.length) return;
  const xs = points.map((p) => p[0]);
  const ys = points.map((p) => p[1]);
  const [x0, x1, y0, y1] = [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)];
  const margin = 0.04 * Math.max(x1 - x0, y1 - y0, 1);
  // North up: the map's y grows downwards, so y is negated.
  svg.setAttribute("viewBox", [x0 - margin, -y1 - margin, x1 - x0 + 2 * margin, y1 - y0 + 2 * margin].join(" "));
  const line = (path, cls) => {
    const el = document.createElementNS(SVG, "polyline");
    el.setAttribute("points", path.map((p) => `${p[0]},${-p[1]}`).join(" "));
    el.setAttribute("class", cls);
    el.setAttribute("vector-effect", "non-scaling-stroke");
    return el;
  };
  svg.append(line(overview.trajectory, "route-trajectory"));
  for (const run of overview.runs) {
    const path = run.path.length > 1 ? run.path : [run.path[0], run.path[0]];
    const el = line(path, `route-run${run.run_id === route.current ? " current" : ""}`);
    el.dataset.run = String(run.run_id);
    el.dataset.progress = String(run.progress);
    el.style.stroke = progressColour(run.progress);
    const title = document.createElementNS(SVG, "title");
    title.textContent = `guardrail run ${run.run_id}: ${run.type}, ${reviewText(run)}`;
    el.append(title);
    svg.append(el);
  }
}

function renderTable(overview) {
  const body = $("route-table").querySelector("tbody");
  body.replaceChildren();
  for (const run of overview.runs) {
    const tr = document.createElement("tr");
    tr.dataset.run = String(run.run_id);
    tr.dataset.state = run.state;
    tr.tabIndex = 0;
    tr.title = run.signature ? `${run.signature}; fly to it` : "fly to it";
    tr.classList.toggle("current", run.run_id === route.current);
    const cells = [
      String(run.run_id),
      run.type,
      run.signature ? run.signature.split(":")[0] : "—",
      run.length_m === null ? "—" : `${run.length_m.toFixed(0)} m`,
      String(run.poles),
    ];
    for (const text of cells) {
      const td = document.createElement("td");
      td.textContent = text;
      tr.append(td);
    }
    const status = document.createElement("td");
    const bar = document.createElement("span");
    bar.className = "route-progress";
    bar.style.setProperty("--share", String(run.progress));
    bar.style.setProperty("--colour", progressColour(run.progress));
    status.title = reviewText(run);
    status.append(bar, document.createTextNode(
      run.asked ? ` ${run.reviewed}/${run.reviewed + run.asked}` : " done"));
    tr.append(status);
    body.append(tr);
  }
}
