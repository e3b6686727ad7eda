// Tiny shared client for the review app's REST API.
//
// The server may require a bearer token. Operators get a link like
// `index.html?token=...`; we read the token from the page URL once and then
//  - send it as `Authorization: Bearer <token>` on every fetch,
//  - append `token=` to image URLs (an <img> cannot send headers),
//  - keep it in links between the pages (withToken / keepTokenInLinks).

const pageParams = new URLSearchParams(window.location.search);

/** The operator's token from `?token=`, or null. */
export const token = pageParams.get("token") || null;

/** An Error carrying the HTTP status and the server's `detail`. */
export class ApiError extends Error {
  constructor(status, detail) {
    super(detail);
    this.name = "ApiError";
    this.status = status;
  }
}

// FastAPI's own validation errors have `detail` as a list of {loc, msg}.
function detailText(body, fallback) {
  const detail = body && body.detail;
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail)) {
    return detail
      .map((d) => (d && d.msg ? `${(d.loc || []).join(".")}: ${d.msg}` : String(d)))
      .join("; ");
  }
  if (detail != null) return JSON.stringify(detail);
  return fallback;
}

/**
 * Fetch `path` (e.g. "/api/info") and return its parsed JSON.
 * `body`, when given, is sent as JSON. Throws ApiError on non-2xx.
 */
export async function request(method, path, body) {
  const headers = { Accept: "application/json" };
  if (token) headers.Authorization = `Bearer ${token}`;
  const init = { method, headers };
  if (body !== undefined) {
    headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  let response;
  try {
    response = await fetch(path, init);
  } catch (err) {
    throw new ApiError(0, `server unreachable (${err.message})`);
  }
  let data = null;
  const text = await response.text();
  if (text) {
    try {
      data = JSON.parse(text);
    } catch {
      data = null;
    }
  }
  if (!response.ok) {
    throw new ApiError(response.status, detailText(data, `${response.status} ${response.statusText}`));
  }
  return data;
}

export const get = (path) => request("GET", path);
export const put = (path, body) => request("PUT", path, body);
export const post = (path, body) => request("POST", path, body ?? {});

/** Build a query string from an object, skipping null/undefined/"" values. */
export function query(params) {
  const q = new URLSearchParams();
  for (const [k, v] of Object.entries(params)) {
    if (v !== null && v !== undefined && v !== "") q.set(k, String(v));
  }
  const s = q.toString();
  return s ? `?${s}` : "";
}

/** `url` with `token=` appended when we have one (for <img src>). */
export function imageUrl(url) {
  if (!url) return url;
  if (!token) return url;
  const u = new URL(url, window.location.href);
  u.searchParams.set("token", token);
  return u.origin === window.location.origin ? u.pathname + u.search + u.hash : u.href;
}

/** A link to one of our pages (relative `href`) that keeps the token. */
export function withToken(href, params = {}) {
  const u = new URL(href, window.location.href);
  for (const [k, v] of Object.entries(params)) {
    if (v !== null && v !== undefined && v !== "") u.searchParams.set(k, String(v));
  }
  if (token) u.searchParams.set("token", token);
  return u.origin === window.location.origin ? u.pathname + u.search + u.hash : u.href;
}

/** Rewrite every `a[data-keep-token]` under `root` to carry the token. */
export function keepTokenInLinks(root = document) {
  if (!token) return;
  for (const a of root.querySelectorAll("a[data-keep-token]")) {
    a.href = withToken(a.getAttribute("href"));
  }
}

// ---- small helpers shared by both pages -------------------------------

/** "—" for missing numbers, else a percentage with `digits` decimals. */
export function pct(x, digits = 1) {
  return typeof x === "number" && Number.isFinite(x) ? `${(x * 100).toFixed(digits)}%` : "—";
}

/** "—" for missing numbers, else a grouped integer. */
export function int(x) {
  return typeof x === "number" && Number.isFinite(x) ? Math.round(x).toLocaleString("en-US") : "—";
}

/** Plural helper: plural(3, "segment") -> "3 segments". */
export function plural(n, word) {
  return `${int(n)} ${word}${n === 1 ? "" : "s"}`;
}

/** True when a key event should be left to a text field. */
export function isTyping(event) {
  const el = event.target;
  if (!(el instanceof HTMLElement)) return false;
  if (el.isContentEditable) return true;
  const tag = el.tagName;
  if (tag === "TEXTAREA" || tag === "SELECT") return true;
  if (tag === "INPUT") {
    const type = (el.getAttribute("type") || "text").toLowerCase();
    // Buttons and boxes do not take text; everything else does.
    return !["button", "submit", "reset", "checkbox", "radio", "range"].includes(type);
  }
  return false;
}

/**
 * Run async actions one after the other, so that e.g. `g` then `z` pressed
 * quickly reach the server in that order. Errors go to `onError`.
 */
export function serializer(onError) {
  let chain = Promise.resolve();
  return (fn) => {
    chain = chain.then(fn).catch(onError);
    return chain;
  };
}

let toastTimer = null;

/** Show a short message in #toast; `kind` "error" colours it. */
export function toast(message, kind = "info") {
  const el = document.getElementById("toast");
  if (!el) return;
  el.textContent = message;
  el.dataset.kind = kind;
  el.hidden = false;
  el.classList.add("show");
  clearTimeout(toastTimer);
  toastTimer = setTimeout(() => {
    el.classList.remove("show");
    el.hidden = true;
  }, kind === "error" ? 6000 : 2500);
}

/** Format a history/model timestamp (ISO string or epoch seconds). */
export function formatTime(at) {
  if (at === null || at === undefined || at === "") return "—";
  let d;
  if (typeof at === "number") d = new Date(at < 1e12 ? at * 1000 : at);
  else d = new Date(at);
  if (Number.isNaN(d.getTime())) return String(at);
  const now = new Date();
  const time = d.toLocaleTimeString("en-GB", { hour12: false });
  return d.toDateString() === now.toDateString()
    ? time
    : `${d.toISOString().slice(0, 10)} ${time}`;
}
