// The review page: a 3D scene (viser, in an iframe) on the left, the selected
// segment, the label buttons, the review queue and the model box on the right.
//
// The selection lives on the server: a click in the 3D scene changes it there,
// and a long poll of GET /api/selection?after=VERSION answers the moment it does;
// when this page selects something (queue, `n`, ?segment=ID) it PUTs
// /api/selection, which also moves the 3D camera.

import * as api from "./api.js";
import { int, pct, plural, toast } from "./api.js";
import { closeZoom, initCamera, renderCamera, toggleCamera, toggleZoom, zoomOpen } from "./camera.js";
import { initRoute, loadRoute, stepRun } from "./route.js";

// How long one long poll of the selection waits before it is asked again (seconds),
// and how long after a failed one (ms).
const SELECTION_WAIT_S = 20;
const SELECTION_RETRY_MS = 1000;
const JOB_POLL_MS = 500;
const QUEUE_LIMIT = 10;
const RUN_QUEUE_LIMIT = 200; // a run's doubtful segments, all of them in practice
const HISTORY_SHOWN = 5;

const $ = (id) => document.getElementById(id);

const state = {
  info: null,
  selection: [], // segment ids, as the server has them
  lassoPoints: 0, // points a lasso in the 3D view took (g and o then label those points)
  detail: null, // GET /api/segments/{selection[0]}
  queue: [],
  queueTotals: null, // {asked, reviewed, done} of the queue's scope
  // A run_id: the queue reviews that run along the road ("review this run"); "off": the
  // guardrail segments on no run, along the road; null: the whole drive's queue.
  queueRun: null,
  // Bumped on every selection change made by this page: a poll that started
  // before it may carry the old selection and must be dropped.
  selectionSeq: 0,
  selectionVersion: null, // the server's version of the selection this page has shown
  detailSeq: 0,
  job: null, // {id, result} of the last fine-tuning job
  lastRefresh: 0,
  labelsVersion: 0, // bumped after every change: the camera image's colours follow the labels
  autoAdvance: localStorage.getItem("guardrail.autoAdvance") !== "false", // g/o then go on
};

// Actions (label, undo, next, train, activate) run one after the other.
const serialize = api.serializer((err) => {
  console.error(err);
  toast(err.message || String(err), "error");
});

// What the page is doing, for tests and tools to wait on (never on time):
// <body data-state> is "ready" once the first loads (info, selection, detail,
// queue) settled; <body data-actions> counts the actions finished, each with
// the refresh it does (afterChange), whether it succeeded or not.
let actionsDone = 0;

function run(fn) {
  return serialize(async () => {
    try {
      await fn();
    } finally {
      actionsDone += 1;
      document.body.dataset.actions = String(actionsDone);
    }
  });
}

// ---- banner (connection / auth problems) -------------------------------

function setBanner(message) {
  const el = $("banner");
  el.textContent = message || "";
  el.hidden = !message;
}

function explain(err) {
  if (err.status === 401 || err.status === 403) {
    return api.token
      ? `The server refused the token: ${err.message}`
      : `This server needs a token: open the page as index.html?token=… (${err.message})`;
  }
  return err.message;
}

// ---- info, header, model box --------------------------------------------

async function loadInfo() {
  const info = await api.get("/api/info");
  state.info = info;
  renderInfo();
  return info;
}

// The server may hand out a scene URL on localhost; an operator on another
// machine needs the host they reached this page by, on the scene's port.
function sceneSrc(url) {
  if (!url) return "about:blank";
  try {
    const u = new URL(url, window.location.href);
    const local = ["localhost", "127.0.0.1", "0.0.0.0", "[::1]"];
    if (local.includes(u.hostname) && !local.includes(window.location.hostname)) {
      u.hostname = window.location.hostname;
    }
    if (api.token) {
      // The scene's websocket needs the token too: viser connects to ?websocket= when given.
      const ws = new URL(u.href);
      ws.protocol = u.protocol === "https:" ? "wss:" : "ws:";
      ws.search = `?token=${encodeURIComponent(api.token)}`;
      u.searchParams.set("websocket", ws.href);
    }
    return u.href;
  } catch {
    return url;
  }
}

function renderInfo() {
  const info = state.info;
  if (!info) return;
  $("drive-name").textContent = info.drive ?? "—";
  $("run-name").textContent = info.run ?? "—";
  const model = info.model || {};
  $("header-model").textContent = model.version ?? "—";
  if (info.operator) {
    $("operator").textContent = info.operator;
    $("operator-wrap").hidden = false;
  }
  document.title = `Guardrail review — ${info.run ?? ""}`;

  // Set the iframe once: reloading it would reset the 3D view.
  const scene = $("scene");
  const src = sceneSrc(info.scene_url);
  if (!info.scene_url && !scene.srcdoc) {
    scene.srcdoc = '<p style="color:#aaa;font:14px system-ui,sans-serif;padding:16px">'
      + "This server has no 3D scene: the panel on the right still works.</p>";
  } else if (info.scene_url && scene.dataset.src !== src) {
    scene.removeAttribute("srcdoc");
    scene.dataset.src = src;
    scene.src = src;
  }

  $("model-version").textContent = model.version ?? "—";
  $("model-mode").textContent = model.mode ?? "—";
  const heldOut = (model.metrics && model.metrics.held_out) || {};
  $("model-f1-guardrail").textContent = pct(heldOut.guardrail?.f1);
  $("model-f1-other").textContent = pct(heldOut.other?.f1);
  $("model-measured-on").textContent = heldOut.n_held_out
    ? `Measured when it was trained, ${measuredOn(heldOut, "its training drives")}.`
    : "";

  $("label-counts").textContent = labelCountsText(info);
}

/** The operators' labels in words: "888 points labelled (621 guardrail) in 15 actions". */
function labelCountsText(info) {
  const c = info.label_counts || {};
  const of = `of ${int(info.n_segments)} segments, ${int(info.n_points)} points`;
  if (!c.labelled_points) return `no labels yet, ${of}`;
  return `${int(c.labelled_points)} points labelled (${int(c.guardrail_points)} guardrail)`
    + (c.batches !== undefined ? ` in ${plural(c.batches, "action")}` : "") + `, ${of}`;
}

// ---- selection ----------------------------------------------------------

const sameIds = (a, b) => a.length === b.length && a.every((x, i) => x === b[i]);

/** Read the selection (with `wait`, a long poll that answers when it changes) and show it. */
async function readSelection(wait) {
  const seq = state.selectionSeq;
  const query =
    wait && state.selectionVersion !== null
      ? `?after=${state.selectionVersion}&wait_s=${SELECTION_WAIT_S}`
      : "";
  const sel = await api.get(`/api/selection${query}`);
  if (!$("banner").dataset.sticky) setBanner(null);
  if (!state.info) loadInfo().catch(() => {});
  // This page changed the selection meanwhile: the answer may be older than that change.
  // The version is not taken either, so the next poll answers at once with the current one.
  if (seq !== state.selectionSeq) return;
  state.selectionVersion = sel.version;
  const ids = sel.segments || [];
  const lasso = sel.lasso_points || 0;
  if (!sameIds(ids, state.selection) || lasso !== state.lassoPoints) {
    state.selection = ids;
    state.lassoPoints = lasso;
    renderQueue(); // highlight
    await loadDetail();
  }
}

/** Follow the selection the 3D view makes, for as long as the page is open. */
async function followSelection() {
  for (;;) {
    try {
      await readSelection(true);
    } catch (err) {
      setBanner(`Lost contact with the server: ${explain(err)}`);
      await new Promise((resolve) => setTimeout(resolve, SELECTION_RETRY_MS));
    }
  }
}

/** Select `ids` from this page: the server moves the 3D camera to them. */
async function selectSegments(ids) {
  state.selectionSeq += 1;
  state.selection = ids;
  renderQueue();
  const detailPromise = loadDetail();
  const sel = await api.put("/api/selection", { segments: ids });
  state.selectionSeq += 1; // polls started during the PUT are stale too
  state.lassoPoints = (sel && sel.lasso_points) || 0; // a page selection lets a lasso go
  const serverIds = (sel && sel.segments) || ids;
  if (!sameIds(serverIds, state.selection)) {
    state.selection = serverIds;
    renderQueue();
    await loadDetail();
  } else {
    await detailPromise;
  }
}

async function loadDetail() {
  const seq = ++state.detailSeq;
  const id = state.selection[0];
  if (id === undefined) {
    state.detail = null;
    renderDetail();
    return;
  }
  try {
    const detail = await api.get(`/api/segments/${id}`);
    if (seq !== state.detailSeq) return; // a newer selection won
    state.detail = detail;
  } catch (err) {
    if (seq !== state.detailSeq) return;
    state.detail = null;
    toast(`segment ${id}: ${err.message}`, "error");
  }
  renderDetail();
}

function setLabelChip(el, label) {
  el.textContent = label ?? "—";
  el.dataset.label = label ?? "";
  el.className = `label-chip${label ? ` label-${label}` : ""}`;
}

const CROP_STATUS_TEXT = {
  ok: "ok",
  no_image: "no camera image holds all its points",
  too_small: "too few points for a crop",
};

function renderDetail() {
  const d = state.detail;
  const n = state.selection.length;
  $("selection-count").textContent = n > 1 ? `(${n} selected, showing the first)` : "";
  const lasso = $("lasso-line");
  lasso.hidden = !state.lassoPoints;
  lasso.textContent = state.lassoPoints
    ? `Lasso: ${plural(state.lassoPoints, "point")} in ${plural(n, "segment")}; g and o label these points`
    : "";
  $("selection-empty").hidden = n > 0;
  $("selection-detail").hidden = n === 0;
  renderBar();
  if (n === 0) return;

  $("selected-id").textContent = d ? String(d.id) : String(state.selection[0]);
  if (!d) return;

  const img = $("selected-crop");
  const missing = $("selected-crop-missing");
  if (d.crop_url) {
    const src = api.imageUrl(d.crop_url);
    if (img.getAttribute("src") !== src) img.src = src;
    img.hidden = false;
    missing.hidden = true;
  } else {
    img.hidden = true;
    img.removeAttribute("src");
    missing.textContent = d.crop_status === "too_small" ? "too small" : "no crop";
    missing.hidden = false;
  }

  renderCamera(d, state.labelsVersion);

  setLabelChip($("selected-label"), d.label);
  $("selected-reviewed").textContent = d.reviewed ? "✓ reviewed" : "not yet";
  $("selected-reviewed").dataset.reviewed = String(Boolean(d.reviewed));
  $("selected-points").textContent = int(d.n_points);

  const p = typeof d.probability === "number" ? d.probability : null;
  $("selected-probability").textContent = pct(p);
  const bar = $("selected-probability-bar");
  bar.style.width = p === null ? "0" : `${Math.max(0, Math.min(1, p)) * 100}%`;
  bar.className = p !== null && p >= 0.5 ? "fill-guardrail" : "fill-other";

  $("selected-raw").textContent = d.raw_label ?? "—";
  $("selected-model-label").textContent = d.model_label ?? "—";
  const hasTruth = d.truth !== null && d.truth !== undefined;
  $("selected-truth-term").hidden = !hasTruth;
  $("selected-truth").hidden = !hasTruth;
  if (hasTruth) {
    $("selected-truth").textContent = d.truth === d.label ? `${d.truth} ✓` : `${d.truth} ✗ (label differs)`;
  }
  $("selected-place").textContent = `${d.slice_index ?? "—"} / ${d.component ?? "—"}`;
  $("selected-crop-status").textContent = CROP_STATUS_TEXT[d.crop_status] ?? d.crop_status ?? "—";

  renderHistory(d.history || []);
}

function renderHistory(history) {
  const list = $("history");
  list.replaceChildren();
  if (!history.length) {
    const li = document.createElement("li");
    li.className = "muted";
    li.textContent = "no changes yet";
    list.append(li);
    return;
  }
  // The server sends the history newest first.
  for (const h of history.slice(0, HISTORY_SHOWN)) {
    const li = document.createElement("li");
    li.classList.toggle("undone", Boolean(h.undone));
    const who = h.who ? ` ${h.who}` : "";
    const what = h.old === h.new ? `${h.new}` : `${h.old ?? "—"} → ${h.new ?? "—"}`;
    const extra = [h.kind, h.n_points !== undefined && h.n_points !== null ? `${int(h.n_points)} pts` : null,
      h.model_version ? `model ${h.model_version}` : null, h.batch !== undefined ? `action ${h.batch}` : null]
      .filter(Boolean).join(", ");
    li.textContent = `${api.formatTime(h.at)}${who}: ${what}${extra ? ` (${extra})` : ""}${h.undone ? " — undone" : ""}`;
    list.append(li);
  }
}

// ---- queue --------------------------------------------------------------

async function loadQueue() {
  const run = state.queueRun;
  const path = run === "off" ? "/api/queue/off-runs" : "/api/queue";
  const params = run === null
    ? { limit: QUEUE_LIMIT }
    : run === "off" ? { limit: RUN_QUEUE_LIMIT } : { limit: RUN_QUEUE_LIMIT, run };
  const res = await api.get(`${path}${api.query(params)}`);
  if (run !== state.queueRun) return; // the scope changed meanwhile
  state.queue = (res && res.items) || [];
  state.queueTotals = res ? { asked: res.asked, reviewed: res.reviewed, done: res.done } : null;
  renderQueue();
}

/** Review run `runId` along the road (null: the whole drive's queue). */
async function setQueueRun(runId) {
  state.queueRun = runId;
  $("queue-panel").dataset.run = runId === null ? "" : String(runId);
  await loadQueue();
}

function renderQueue() {
  const list = $("queue");
  list.replaceChildren();
  const run = state.queueRun;
  $("queue-scope").textContent = run === null
    ? ""
    : run === "off" ? "· guardrail segments on no run, along the road" : `· guardrail run ${run}, along the road`;
  $("queue-whole").hidden = run === null;
  $("queue-empty").textContent = run === null
    ? "Review done: nothing left to ask."
    : run === "off" ? "No unreviewed guardrail segment lies off the runs."
      : `Guardrail run ${run} is done: nothing left to ask there.`;
  $("queue-empty").hidden = state.queue.length > 0;
  const totals = state.queueTotals;
  $("queue-summary").textContent = totals
    ? `${int(totals.asked)} asked · ${int(totals.reviewed)} reviewed`
      + (state.queue.length < totals.asked ? ` · the first ${state.queue.length} shown` : "")
    : "";
  renderBar();
  for (const item of state.queue) {
    const li = document.createElement("li");
    li.dataset.id = String(item.id);
    li.tabIndex = 0;
    li.title = `select segment ${item.id}`;
    li.classList.toggle("current", state.selection.includes(item.id));

    if (item.crop_url) {
      const img = document.createElement("img");
      img.src = api.imageUrl(item.crop_url);
      img.width = 28;
      img.height = 28;
      img.loading = "lazy";
      img.alt = "";
      li.append(img);
    } else {
      const ph = document.createElement("span");
      ph.className = "thumb-missing";
      li.append(ph);
    }
    const id = document.createElement("span");
    id.className = "q-id";
    id.textContent = `#${item.id}`;
    const label = document.createElement("span");
    setLabelChip(label, item.label);
    const prob = document.createElement("span");
    prob.className = "q-prob";
    prob.textContent = pct(item.probability, 0);
    const reason = document.createElement("span");
    reason.className = `reason reason-${item.reason}`;
    reason.dataset.reason = item.reason ?? "";
    reason.textContent = item.reason ?? "";
    li.append(id, label, prob, reason);
    list.append(li);
  }
}

function onQueueClick(event) {
  const li = event.target.closest("#queue li[data-id]");
  if (!li) return;
  const id = Number(li.dataset.id);
  run(() => selectSegments([id]));
}

/** The action bar's line: what is selected, and where it stands in the queue. */
function renderBar() {
  const n = state.selection.length;
  const d = state.detail;
  let text = "nothing selected";
  if (state.lassoPoints) text = `lasso: ${plural(state.lassoPoints, "point")}`;
  else if (n > 1) text = `${n} segments selected`;
  else if (n === 1) {
    text = `#${state.selection[0]}`;
    if (d && d.id === state.selection[0]) {
      text += ` · ${d.label}${d.reviewed ? " ✓" : ""} · ${pct(d.probability, 0)}`;
    }
  }
  $("bar-selection").textContent = text;
  const position = $("queue-position");
  const totals = state.queueTotals;
  const done = Boolean(totals && totals.done);
  position.dataset.done = String(done);
  if (!totals) {
    position.textContent = "";
  } else if (done) {
    position.textContent = state.queueRun === null
      ? "✓ review done"
      : state.queueRun === "off" ? "✓ none left off the runs" : "✓ this run is done";
  } else {
    const at = state.queue.findIndex((q) => state.selection.includes(q.id));
    position.textContent = at < 0
      ? `${int(totals.asked)} asked`
      : `${at + 1} of ${int(totals.asked)} asked`;
  }
}

async function nextInQueue() {
  if (!state.queue.length) await loadQueue();
  if (!state.queue.length) {
    toast("Review done: nothing left to ask");
    return;
  }
  const current = state.selection[0];
  const at = state.queue.findIndex((q) => q.id === current);
  const item = at < 0 ? state.queue[0] : state.queue[at + 1];
  if (!item) {
    toast("the last one the queue asks about: label it");
    return;
  }
  await selectSegments([item.id]);
  toast(`segment ${item.id}: ${item.reason ?? "queued"}, ${pct(item.probability, 0)}`);
}

// ---- labelling ------------------------------------------------------------

async function labelSelection(label, expand) {
  const ids = [...state.selection];
  if (!ids.length) {
    toast("nothing selected: click a segment in the 3D view or press n", "error");
    return;
  }
  if (state.lassoPoints && expand === "none") {
    const res = await api.post("/api/labels/lasso", { label });
    toast(`${plural(state.lassoPoints, "lasso point")} -> ${label} (${int(res.changed_points)} changed)`);
    await afterChange();
    return;
  }
  const before = state.queue.map((q) => q.id);
  const res = await api.post("/api/labels/batch", { segments: ids, label, expand });
  const labelled = (res.segments || []).map((x) => x.id);
  const scope = expand === "component" ? " (whole piece)" : "";
  toast(`${plural(labelled.length, "segment")} → ${label}${scope} (${int(res.changed_points)} points)`);
  if (!state.autoAdvance) {
    await afterChange();
    return;
  }
  // One key per decision: on to the one that followed in the queue, selected before the queue
  // reloads (a round trip saved); should the queue no longer ask about it (a run just
  // checked), the first it asks about is selected instead.
  state.labelsVersion += 1;
  const at = before.indexOf(ids[0]);
  const following = before.slice(at + 1).concat(before.slice(0, Math.max(at, 0)));
  const guess = following.find((id) => !labelled.includes(id));
  // The next one's facts first: the server answers one request at a time in effect.
  if (guess !== undefined) await selectSegments([guess]);
  const refreshed = Promise.all([loadInfo(), loadRoute()]);
  await loadQueue();
  const asked = new Set(state.queue.map((q) => q.id));
  const next = guess !== undefined && asked.has(guess)
    ? guess
    : following.find((id) => asked.has(id) && !labelled.includes(id))
      ?? state.queue.find((q) => !labelled.includes(q.id))?.id;
  if (next === undefined) {
    if (guess !== undefined) await selectSegments([...ids]); // nothing left: back to it
    else await loadDetail();
    toast($("queue-empty").textContent);
  } else if (next !== guess) {
    await selectSegments([next]);
  } else {
    renderBar(); // its place in the reloaded queue
  }
  await refreshed;
}

async function undo() {
  const res = await api.post("/api/labels/undo");
  if (res.undone_batch === null || res.undone_batch === undefined) {
    toast("nothing to undo");
    return;
  }
  toast(`undone: the labels of ${plural((res.segments || []).length, "segment")} (${int(res.changed_points)} points) are back`);
  await afterChange();
}

// After anything that changes labels: refresh what shows them.
async function afterChange() {
  state.labelsVersion += 1;
  await Promise.all([loadDetail(), loadQueue(), loadInfo(), loadRoute()]);
}

// ---- fine-tuning ---------------------------------------------------------

async function startTraining() {
  $("train").disabled = true;
  $("compare").hidden = true;
  $("train-status").hidden = false;
  $("train-progress").value = 0;
  $("train-message").textContent = "starting…";
  try {
    const res = await api.post("/api/train", { mode: "fast" });
    state.job = { id: res.job, result: null };
    pollJob(res.job, 0);
  } catch (err) {
    $("train").disabled = false;
    $("train-message").textContent = `could not start: ${err.message}`;
    throw err;
  }
}

async function resumeTraining() {
  const { items } = await api.get("/api/jobs?kind=train");
  const running = items.find((job) => job.status === "queued" || job.status === "running");
  if (!running) return;
  $("train").disabled = true;
  $("train-status").hidden = false;
  state.job = { id: running.id, result: null };
  pollJob(running.id, 0);
}

function pollJob(jobId, failures) {
  setTimeout(async () => {
    let job;
    try {
      job = await api.get(`/api/jobs/${encodeURIComponent(jobId)}`);
    } catch (err) {
      // A few hiccups are fine; a job that vanished is not.
      if (failures >= 5 || err.status === 404) {
        $("train").disabled = false;
        $("train-message").textContent = `lost the job: ${err.message}`;
        return;
      }
      pollJob(jobId, failures + 1);
      return;
    }
    renderJob(job);
    if (job.status === "done" || job.status === "failed" || job.status === "cancelled") {
      $("train").disabled = false;
      if (job.status === "done") showComparison(job.result);
      else if (job.status === "cancelled") toast("fine-tuning cancelled", "info");
      else toast(`fine-tuning failed: ${job.advice ?? job.error ?? "unknown error"}`, "error");
      return;
    }
    pollJob(jobId, 0);
  }, JOB_POLL_MS);
}

function renderJob(job) {
  const progress = $("train-progress");
  progress.value = typeof job.progress === "number" ? job.progress : 0;
  progress.dataset.status = job.status;
  let text = `${job.status}${typeof job.progress === "number" ? ` ${pct(job.progress, 0)}` : ""}`;
  if (job.message) text += ` — ${job.message}`;
  if (job.status === "failed") text = `failed: ${job.advice ?? job.error ?? job.message ?? "unknown error"}`;
  // The program's own words stay a hover away, for whoever looks into it.
  $("train-message").title = job.status === "failed" && job.advice ? job.error ?? "" : "";
  $("train-message").textContent = text;
}

const COMPARE_ROWS = [
  ["guardrail F1", (m) => m?.guardrail?.f1, "pct"],
  ["other F1", (m) => m?.other?.f1, "pct"],
  ["accuracy", (m) => m?.accuracy, "pct"],
  ["n held out", (m) => m?.n_held_out, "int"],
];

const isNum = (x) => typeof x === "number" && Number.isFinite(x);

/** On which held-out segments, and against which labels, figures `m` were measured. */
function measuredOn(m, where) {
  const against = m.against === "operator labels"
    ? "against the operators' labels"
    : m.against
      ? `against the operators' labels where reviewed (${int(m.n_reviewed_held_out)}), else the current model's corrected labels, which favours the current model`
      : "against their labels";
  return `on ${int(m.n_held_out)} held-out segments of ${where}, ${against}`;
}

function showComparison(result) {
  state.job.result = result;
  const box = $("compare");
  if (!result || !result.version) {
    $("train-message").textContent = "done, but no new model came back";
    return;
  }
  $("compare-caption").textContent = result.metrics_new
    ? `Both models ${measuredOn(result.metrics_new, "this run folder")} (not used to train).`
    : "Nothing could be held out to compare the models on.";
  $("compare-new-version").textContent = result.version;
  $("compare-current-version").textContent = state.info?.model?.version ?? "";
  const body = box.querySelector("tbody");
  body.replaceChildren();
  for (const [name, pick, kind] of COMPARE_ROWS) {
    const a = pick(result.metrics_new);
    const b = pick(result.metrics_current);
    const tr = document.createElement("tr");
    const fmt = kind === "pct" ? (x) => pct(x) : int;
    let change = "";
    let cls = "";
    if (isNum(a) && isNum(b)) {
      const diff = kind === "pct" ? (a - b) * 100 : a - b;
      change = kind === "pct" ? `${diff >= 0 ? "+" : ""}${diff.toFixed(1)} pt` : (diff ? `${diff > 0 ? "+" : ""}${diff}` : "");
      if (kind === "pct" && Math.abs(diff) >= 0.05) cls = diff > 0 ? "better" : "worse";
    }
    for (const [text, c] of [[name, ""], [fmt(a), ""], [fmt(b), ""], [change, cls]]) {
      const td = document.createElement(text === name ? "th" : "td");
      td.textContent = text;
      if (c) td.className = c;
      tr.append(td);
    }
    body.append(tr);
  }
  // Activation is the suggested action only when the new model is not worse on these segments.
  const fNew = result.metrics_new?.guardrail?.f1;
  const fNow = result.metrics_current?.guardrail?.f1;
  const worse = isNum(fNew) && isNum(fNow) && fNew < fNow - 0.0005;
  $("activate").classList.toggle("btn-primary", !worse);
  $("keep").classList.toggle("btn-primary", worse);
  $("compare-advice").dataset.worse = String(worse);
  $("compare-advice").textContent = worse
    ? `The new model finds guardrails worse here (${((fNew - fNow) * 100).toFixed(1)} pt guardrail F1): keep the current one, or label more and fine-tune again.`
    : isNum(fNew) && isNum(fNow)
      ? "The new model is not worse here: activate it to re-predict the run folder."
      : "No held-out figures to compare: activate it only if you trust the labels it learnt from.";
  $("activate").disabled = false;
  box.hidden = false;
  box.scrollIntoView({ block: "nearest" });
}

async function activateNew() {
  const version = state.job?.result?.version;
  if (!version) return;
  $("activate").disabled = true;
  try {
    const res = await api.post(`/api/models/${encodeURIComponent(version)}/activate`);
    toast(`model ${res.active} active: ${plural(res.changed_segments, "segment")} changed label`);
    $("compare").hidden = true;
    $("train-status").hidden = true;
    await afterChange();
  } finally {
    $("activate").disabled = false;
  }
}

function keepCurrent() {
  $("compare").hidden = true;
  $("train-status").hidden = true;
  toast(`kept model ${state.info?.model?.version ?? ""}`);
}

/** Cancel a lasso: one being drawn in the 3D view, and the points one took. */
async function cancelLasso() {
  const sel = await api.post("/api/lasso/cancel");
  const had = state.lassoPoints;
  state.lassoPoints = (sel && sel.lasso_points) || 0;
  if (had) {
    toast("lasso cancelled");
    renderDetail();
  }
}

// ---- help overlay, focus hint, keyboard ---------------------------------

function setHelp(open) {
  $("help").hidden = !open;
  if (open) $("help-close").focus();
}

function onKeyDown(event) {
  if (event.ctrlKey || event.metaKey || event.altKey || api.isTyping(event)) return;
  if (event.key === "Escape") {
    if (zoomOpen()) {
      closeZoom();
      return;
    }
    setHelp(false);
    run(cancelLasso);
    return;
  }
  if (event.key === "?") {
    event.preventDefault();
    setHelp($("help").hidden);
    return;
  }
  if (event.repeat) return; // a held key must not fire a burst of requests
  switch (event.key.toLowerCase()) {
    case "g":
      run(() => labelSelection("guardrail", event.shiftKey ? "component" : "none"));
      break;
    case "o":
      run(() => labelSelection("other", event.shiftKey ? "component" : "none"));
      break;
    case "z":
    case "u":
      run(undo);
      break;
    case "n":
      run(nextInQueue);
      break;
    case "i":
      toggleCamera(state.detail, state.labelsVersion);
      break;
    case "v":
      toggleZoom();
      break;
    case "[":
      run(() => stepRun(-1));
      break;
    case "w":
      run(() => setQueueRun(null));
      break;
    case "]":
      run(() => stepRun(+1));
      break;
    default:
      return;
  }
  event.preventDefault();
}

// Keys typed while the 3D iframe has focus never reach this document, so say
// so whenever our window loses focus.
function setFocusHint(show) {
  $("focus-hint").hidden = !show;
}

// Refresh what another tab (the gallery) may have changed, at most every 2 s.
function refreshOnReturn() {
  const now = Date.now();
  if (now - state.lastRefresh < 2000) return;
  state.lastRefresh = now;
  state.labelsVersion += 1; // the gallery may have relabelled points on the camera image
  Promise.all([loadDetail(), loadQueue(), loadInfo(), loadRoute()]).catch(() => {});
}

// ---- start --------------------------------------------------------------

async function init() {
  document.body.dataset.state = "loading";
  document.body.dataset.actions = "0";
  api.keepTokenInLinks();
  document.addEventListener("keydown", onKeyDown);
  window.addEventListener("blur", () => setFocusHint(true));
  window.addEventListener("focus", () => {
    setFocusHint(false);
    refreshOnReturn();
  });
  $("focus-hint").addEventListener("click", () => {
    window.focus();
    setFocusHint(false);
  });
  setFocusHint(!document.hasFocus());

  initCamera(selectSegments, run);
  $("help-button").addEventListener("click", () => setHelp(true));
  $("help-close").addEventListener("click", () => setHelp(false));
  $("help").addEventListener("click", (e) => {
    if (e.target === $("help")) setHelp(false);
  });

  for (const button of document.querySelectorAll("#actions-panel button[data-label]")) {
    button.addEventListener("click", () =>
      run(() => labelSelection(button.dataset.label, button.dataset.expand)));
  }
  $("undo").addEventListener("click", () => run(undo));
  const advance = $("auto-advance");
  advance.checked = state.autoAdvance;
  advance.addEventListener("change", () => {
    state.autoAdvance = advance.checked;
    localStorage.setItem("guardrail.autoAdvance", String(advance.checked));
  });
  $("next").addEventListener("click", () => run(nextInQueue));
  $("queue").addEventListener("click", onQueueClick);
  $("queue").addEventListener("keydown", (e) => {
    if (e.key === "Enter") onQueueClick(e);
  });
  $("train").addEventListener("click", () => run(startTraining));
  $("activate").addEventListener("click", () => run(activateNew));
  $("keep").addEventListener("click", keepCurrent);
  initRoute(selectSegments, run, setQueueRun);
  $("queue-whole").addEventListener("click", () => run(() => setQueueRun(null)));

  try {
    await loadInfo();
  } catch (err) {
    setBanner(explain(err));
    $("banner").dataset.sticky = err.status === 401 || err.status === 403 ? "1" : "";
    if ($("banner").dataset.sticky) {
      document.body.dataset.state = "failed";
      return; // nothing else will work either
    }
  }
  // A lasso left open by the page before a reload would take the next clicks as corners.
  await api.post("/api/lasso/cancel").catch((err) => toast(`lasso: ${err.message}`, "error"));
  const queueLoaded = loadQueue().catch((err) => toast(`queue: ${err.message}`, "error"));
  const routeLoaded = loadRoute().catch((err) => toast(`route: ${err.message}`, "error"));
  resumeTraining().catch(() => {}); // a training started before a reload goes on showing

  const wanted = new URLSearchParams(window.location.search).get("segment");
  if (wanted !== null && /^\d+$/.test(wanted)) {
    await run(() => selectSegments([Number(wanted)]));
  } else {
    await readSelection(false).catch((err) =>
      setBanner(`Lost contact with the server: ${explain(err)}`),
    );
  }
  renderDetail();
  followSelection();
  await Promise.all([queueLoaded, routeLoaded]);
  document.body.dataset.state = "ready";
}

init();
