// Shared by the pages: the header (tabs + model switcher), fetch helpers, messages,
// what a prediction's flags mean, high-DPI canvases. Plain ES module, no dependencies.

const PAGES = [
  { id: "draw", label: "Draw", href: "/" },
  { id: "page", label: "Page", href: "/page" },
  { id: "record", label: "Record", href: "/record" },
];
const MODEL_KEY = "img2dmp.model";

/** An HTTP error of the API, carrying its status and the `detail` line. */
export class ApiError extends Error {
  constructor(status, detail) {
    super(detail);
    this.status = status;
    this.detail = detail;
  }
}

/** The `detail` of an error answer, or a readable fallback. */
async function errorDetail(res) {
  const text = await res.text().catch(() => "");
  try {
    const body = JSON.parse(text);
    if (typeof body.detail === "string") return body.detail;
    if (Array.isArray(body.detail)) {
      // FastAPI's validation errors: [{loc, msg}, ...]
      return body.detail
        .map((d) => `${(d.loc || []).filter((x) => x !== "body").join(".")}: ${d.msg}`)
        .join("; ");
    }
    if (body.detail !== undefined) return JSON.stringify(body.detail);
  } catch (_) {
    /* not JSON */
  }
  const short = text.trim().slice(0, 200);
  return short ? `${res.status} ${res.statusText}: ${short}` : `${res.status} ${res.statusText}`;
}

/**
 * fetch + JSON; throws ApiError (with the API's detail) on a non-2xx answer. A Blob or
 * File `body` is sent as its own bytes (with its type), anything else as JSON.
 */
export async function api(path, { method = "GET", body, signal } = {}) {
  const opts = { method, signal, headers: { Accept: "application/json" } };
  if (body instanceof Blob) {
    opts.headers["Content-Type"] = body.type || "application/octet-stream";
    opts.body = body;
  } else if (body !== undefined) {
    opts.headers["Content-Type"] = "application/json";
    opts.body = JSON.stringify(body);
  }
  let res;
  try {
    res = await fetch(path, opts);
  } catch (e) {
    if (e.name === "AbortError") throw e;
    throw new ApiError(0, "The server does not answer. Is `img2dmp serve` still running?");
  }
  if (!res.ok) throw new ApiError(res.status, await errorDetail(res));
  if (res.status === 204) return null;
  return res.json();
}

/**
 * Show a message in `box` (kind "error" or "notice"); `actions` are [label, onClick]
 * buttons added after the text. An empty text hides the box.
 */
export function showMessage(box, kind, text, actions = []) {
  box.replaceChildren();
  if (!text) {
    box.hidden = true;
    return;
  }
  box.className = kind;
  box.setAttribute("role", kind === "error" ? "alert" : "status");
  if (kind === "error") {
    const title = document.createElement("span");
    title.className = "error-title";
    title.textContent = "Error:";
    box.append(title);
  }
  const span = document.createElement("span");
  span.className = "message-text";
  span.textContent = text;
  box.append(span);
  for (const [label, onClick] of actions) {
    const b = document.createElement("button");
    b.type = "button";
    b.textContent = label;
    b.addEventListener("click", onClick);
    box.append(b);
  }
  box.hidden = false;
}

/** Show an exception (ApiError or anything else) as an error message. */
export function showError(box, err, prefix = "") {
  if (err && err.name === "AbortError") return;
  const text = err instanceof ApiError ? err.detail : String((err && err.message) || err);
  showMessage(box, "error", prefix ? `${prefix}: ${text}` : text);
  console.error(err);
}

const pct = (share) => `${Math.round(100 * share)}\u00a0%`;

/**
 * What each flag of a prediction means (`fit`: its path_on_ink and ink_written; `kind`:
 * the model's, "dmp" or "strokes").
 */
const FLAG_TEXT = {
  off_ink: (fit) => `the path leaves the ink (on ink ${pct(fit.path_on_ink)})`,
  unexplained_ink: (fit) => `part of the ink is not written (written ${pct(fit.ink_written)})`,
  several_characters: () => "the image holds several characters",
  cut_by_border: () => "it touches the photo's border, so part of it may be cut off",
  unfamiliar: (fit, kind) => "it looks unlike the characters the model learnt, so " +
    (kind === "strokes" ? "its strokes and their count are a guess" : "its path is a guess"),
};

/**
 * The flags as one clause ("the path leaves the ink (on ink 62 %); ..."), "" for none;
 * `kind`: the model's ("dmp", one path, or "strokes").
 */
export function flagText(flags, fit, kind = "dmp") {
  return (flags || []).map((f) => (FLAG_TEXT[f] ? FLAG_TEXT[f](fit || {}, kind) : f)).join("; ");
}

/**
 * Size a canvas's backing store to its CSS size times devicePixelRatio and return a 2-D
 * context drawing in CSS pixels.
 */
export function fitCanvas(canvas) {
  const rect = canvas.getBoundingClientRect();
  const dpr = window.devicePixelRatio || 1;
  const w = Math.max(1, Math.round(rect.width * dpr));
  const h = Math.max(1, Math.round(rect.height * dpr));
  if (canvas.width !== w || canvas.height !== h) {
    canvas.width = w;
    canvas.height = h;
  }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(w / Math.max(rect.width, 1), 0, 0, h / Math.max(rect.height, 1), 0, 0);
  return { ctx, width: rect.width, height: rect.height };
}

/** Keep the pointer's events while it is down, even outside the canvas. */
export function capture(canvas, e) {
  canvas.dataset.pointerType = e.pointerType || "";
  try {
    canvas.setPointerCapture(e.pointerId);
  } catch (_) {
    /* a synthetic event's pointer cannot be captured; drawing works without */
  }
}

function el(tag, attrs = {}, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "class") e.className = v;
    else e.setAttribute(k, v);
  }
  e.append(...children);
  return e;
}
export { el };

/** The header: project name, the pages as tabs, the model switcher slot. */
function buildHeader(page) {
  const header = document.getElementById("site-header");
  header.className = "site-header";
  const tabs = el("nav", { class: "tabs", "aria-label": "Pages" });
  for (const p of PAGES) {
    const a = el("a", { href: p.href }, p.label);
    if (p.id === page) a.setAttribute("aria-current", "page");
    tabs.append(a);
  }
  const select = el("select", { id: "model-select" });
  const label = el("label", { class: "model-switch", id: "model-switch" }, "Model", select);
  label.hidden = true;
  const brand = el(
    "div",
    { class: "brand" },
    el("span", { class: "name" }, "img2dmp"),
    el("span", { class: "tagline" }, "handwritten digit \u2192 movement primitive \u2192 robot"),
  );
  header.replaceChildren(el("div", { class: "bar" }, brand, tabs, label));
  return { select, label };
}

/**
 * Build the header and load `/api/models`. Returns {ready: Promise, current(), info(),
 * onChange(cb)}. The switcher is shown only when several models are served (and
 * `switcher` is true); the choice is remembered in localStorage. `errorBox` receives a failure to list the models.
 */
export function initHeader(page, errorBox, { switcher = true } = {}) {
  const { select, label } = buildHeader(page);
  const listeners = [];
  const state = { models: [], current: null };
  const ready = api("/api/models")
    .then((answer) => {
      state.models = answer.models || [];
      const saved = localStorage.getItem(MODEL_KEY);
      const ids = state.models.map((m) => m.id);
      state.current = ids.includes(saved) ? saved : answer.default || ids[0] || null;
      select.replaceChildren(
        ...state.models.map((m) => {
          const hyp = m.n_hypotheses > 1 ? `, ${m.n_hypotheses} hypotheses` : "";
          const kind = m.kind === "strokes" ? `, strokes (up to ${m.stroke_slots})` : "";
          return el("option", { value: m.id }, `${m.id}${hyp}${kind}`);
        }),
      );
      select.value = state.current || "";
      label.hidden = !switcher || state.models.length < 2;
      document.body.dataset.model = state.current || "";
      return state;
    })
    .catch((e) => {
      if (errorBox) showError(errorBox, e, "Could not list the models");
      return state;
    });
  select.addEventListener("change", () => {
    state.current = select.value;
    localStorage.setItem(MODEL_KEY, state.current);
    document.body.dataset.model = state.current;
    for (const cb of listeners) cb(state.current);
  });
  return {
    ready,
    current: () => state.current,
    info: () => state.models.find((m) => m.id === state.current) || null,
    onChange: (cb) => listeners.push(cb),
  };
}

/** Save a text as a file download. */
/* A robot job's state on its card: the progress bar and the status line for "queued",
   "running" (`runningText(job, share)` says what runs), "done" and "failed" (its reason in
   `errorBox`); the caller shows what a finished job made. */
export function showJobState(job, { card, progress, status, errorBox, runningText }) {
  card.hidden = false;
  card.dataset.status = job.status;
  const p = Number(job.progress) || 0;
  if (job.status === "queued") {
    progress.removeAttribute("value");
    const pos = job.position ? ` (position ${job.position})` : "";
    status.textContent = `Waiting for the robot${pos}\u2026`;
  } else if (job.status === "running") {
    if (p > 0) progress.value = p;
    else progress.removeAttribute("value");
    status.textContent = runningText(job, p);
  } else if (job.status === "done") {
    progress.value = 1;
    status.textContent = "Done.";
  } else {
    progress.value = 0;
    status.textContent = "Failed.";
    showMessage(errorBox, "error", job.error || "The robot run failed (no reason given).");
  }
}

export function downloadText(text, filename, type = "application/json") {
  const url = URL.createObjectURL(new Blob([text], { type }));
  const a = el("a", { href: url, download: filename });
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 1000);
}
