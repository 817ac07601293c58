// The Record page: trace images (MNIST or a folder) to record pen paths, saved by the
// server as image_<n>.json in the shared recordings' format.
import { api, ApiError, fitCanvas, capture, initHeader, showError, showMessage } from "./common.js";

const $ = (id) => document.getElementById(id);
const ui = {
  noSource: $("no-source"), recorder: $("recorder"), index: $("index"), ofCount: $("of-count"),
  name: $("image-name"), badge: $("recorded-badge"), count: $("recorded-count"),
  image: $("trace-image"), canvas: $("trace"), label: $("label"), labelHint: $("label-hint"),
  undo: $("undo"), clear: $("clear"), skip: $("skip"), save: $("save"),
  message: $("record-message"), pageError: $("page-error"),
};

const state = {
  info: null, // /api/images
  n: null, // the image shown
  meta: null, // /api/images/{n}/meta
  strokes: [], // [[[x, y, t_ms], ...], ...] in the image's pixels (corner convention)
  current: null,
  t0: null,
  saving: false,
  seq: 0,
};

// the model plays no part in recording: no switcher here
initHeader("record", ui.pageError, { switcher: false });

// ---------------------------------------------------------------- images ---------

async function load() {
  try {
    state.info = await api("/api/images");
  } catch (e) {
    showError(ui.pageError, e, "Could not list the images");
    return;
  }
  if (!state.info.source) {
    ui.noSource.hidden = false;
    return;
  }
  const { count, next } = state.info;
  ui.index.max = String(Math.max(0, count - 1));
  updateCount();
  if (count === 0) {
    ui.recorder.hidden = false;
    showMessage(ui.message, "error", "The image source holds no images.");
    return;
  }
  const start = Number.isInteger(next) && next < count ? next : 0;
  if (!(Number.isInteger(next) && next < count)) {
    showMessage(ui.message, "notice", "Every image is recorded; saving again needs Replace.");
  }
  await showImage(start, false);
  ui.recorder.hidden = false; // shown once its first image is known
}

function updateCount() {
  const { count, recorded } = state.info;
  ui.ofCount.textContent = count > 0 ? `(0\u2013${count - 1})` : "";
  ui.count.textContent = `${recorded} recorded`;
}

async function showImage(n, clearMessage = true) {
  const seq = ++state.seq;
  if (clearMessage) showMessage(ui.message, "", "");
  let meta;
  try {
    meta = await api(`/api/images/${n}/meta`);
  } catch (e) {
    if (seq === state.seq) showError(ui.message, e, `Image ${n}`);
    return;
  }
  if (seq !== state.seq) return;
  state.n = n;
  state.meta = meta;
  ui.recorder.dataset.index = String(n);
  ui.index.value = String(n);
  ui.name.textContent = meta.name || "";
  ui.badge.hidden = !meta.recorded;
  ui.image.style.aspectRatio = `${meta.width} / ${meta.height}`;
  ui.image.src = `/api/images/${n}`;
  const mnist = state.info.source === "mnist";
  ui.label.value = meta.label === null || meta.label === undefined ? "" : String(meta.label);
  ui.label.required = meta.label === null || meta.label === undefined;
  ui.labelHint.textContent = ui.label.required
    ? "required: which digit is it?"
    : mnist ? "MNIST's label" : "";
  resetStrokes();
}

// ---------------------------------------------------------------- tracing --------

function imagePoint(e) {
  const r = ui.canvas.getBoundingClientRect();
  const sx = r.width / state.meta.width;
  const sy = r.height / state.meta.height;
  const t = e.timeStamp > 0 ? e.timeStamp : performance.now();
  if (state.t0 === null) state.t0 = t;
  const round = (v, d) => Math.round(v * d) / d;
  return [
    round((e.clientX - r.left) / sx, 1000),
    round((e.clientY - r.top) / sy, 1000),
    round(t - state.t0, 100),
  ];
}

function addPoint(p) {
  const pts = state.current.points;
  const last = pts[pts.length - 1];
  if (p[0] === last[0] && p[1] === last[1]) return;
  if (p[2] <= last[2]) p[2] = Math.round((last[2] + 0.01) * 100) / 100;
  pts.push(p);
}

function onPointerDown(e) {
  if (!state.meta || (e.pointerType === "mouse" && e.button !== 0)) return;
  e.preventDefault(); // no text selection, no scrolling; so focus moves by hand:
  if (document.activeElement instanceof HTMLElement) document.activeElement.blur();
  capture(ui.canvas, e);
  state.current = { id: e.pointerId, points: [imagePoint(e)] };
  state.strokes.push(state.current.points);
  if (!ui.message.hidden && ui.message.className === "notice") showMessage(ui.message, "", "");
  redraw();
}

function onPointerMove(e) {
  if (!state.current || e.pointerId !== state.current.id) return;
  const events = e.getCoalescedEvents ? e.getCoalescedEvents() : [];
  for (const ev of events.length ? events : [e]) addPoint(imagePoint(ev));
  redraw();
}

function onPointerUp(e) {
  if (!state.current || e.pointerId !== state.current.id) return;
  addPoint(imagePoint(e));
  state.current = null;
  redraw();
}

function resetStrokes() {
  state.strokes = [];
  state.current = null;
  state.t0 = null;
  redraw();
}

function redraw() {
  const { ctx, width, height } = fitCanvas(ui.canvas);
  ctx.clearRect(0, 0, width, height);
  const points = state.strokes.reduce((a, s) => a + s.length, 0);
  ui.recorder.dataset.points = String(points);
  ui.recorder.dataset.strokes = String(state.strokes.length);
  ui.undo.disabled = ui.clear.disabled = state.strokes.length === 0;
  ui.save.disabled = points < 2 || state.saving;
  if (!state.meta) return;
  const sx = width / state.meta.width;
  const sy = height / state.meta.height;
  ctx.lineCap = "round";
  ctx.lineJoin = "round";
  ctx.lineWidth = Math.max(3, 0.3 * sx);
  state.strokes.forEach((stroke, i) => {
    const last = i === state.strokes.length - 1;
    ctx.strokeStyle = last ? "rgba(228,87,46,0.9)" : "rgba(47,91,211,0.85)";
    ctx.beginPath();
    stroke.forEach(([x, y], k) => (k ? ctx.lineTo(x * sx, y * sy) : ctx.moveTo(x * sx, y * sy)));
    ctx.stroke();
    ctx.fillStyle = "#1c9a5a";
    ctx.beginPath();
    ctx.arc(stroke[0][0] * sx, stroke[0][1] * sy, ctx.lineWidth, 0, 2 * Math.PI);
    ctx.fill();
  });
}

function undo() {
  if (state.current) return;
  state.strokes.pop();
  if (state.strokes.length === 0) state.t0 = null;
  redraw();
}

// ---------------------------------------------------------------- saving ---------

function labelValue() {
  const text = ui.label.value.trim();
  if (text === "") return null;
  const v = Number(text);
  return Number.isInteger(v) && v >= 0 && v <= 9 ? v : NaN;
}

async function save(replace = false) {
  if (state.saving || state.current || !state.meta) return;
  const label = labelValue();
  if (Number.isNaN(label) || (label === null && ui.label.required)) {
    showMessage(ui.message, "error", "Enter the digit shown (0-9) in the Digit field first.");
    ui.label.focus();
    return;
  }
  const body = { image: state.n, strokes: state.strokes, replace };
  if (label !== null) body.label = label;
  state.saving = true;
  redraw();
  try {
    const answer = await api("/api/recordings", { method: "POST", body });
    state.info.recorded = answer.recorded;
    updateCount();
    const plural = (k, word) => `${k} ${word}${k === 1 ? "" : "s"}`;
    const text =
      `Saved ${answer.file} (${plural(answer.points, "point")}, ` +
      `${plural(answer.strokes, "stroke")}).`;
    const last = state.n + 1 >= state.info.count;
    showMessage(ui.message, "notice", last ? `${text} That was the last image.` : text);
    showImage(last ? state.n : state.n + 1, false);
  } catch (e) {
    if (e instanceof ApiError && e.status === 409) {
      showMessage(ui.message, "error", e.detail, [["Replace", () => save(true)]]);
    } else {
      showError(ui.message, e, "Not saved");
    }
  } finally {
    state.saving = false;
    redraw();
  }
}

function nextImage() {
  if (state.n === null) return;
  if (state.n + 1 >= state.info.count) {
    showMessage(ui.message, "notice", "That was the last image.");
    return;
  }
  showImage(state.n + 1);
}

// ---------------------------------------------------------------- wiring ---------

function onKey(e) {
  if (ui.recorder.hidden) return;
  const inField = e.target instanceof HTMLInputElement;
  if ((e.ctrlKey || e.metaKey) && e.key.toLowerCase() === "z" && !inField) {
    e.preventDefault();
    undo();
  } else if (e.key === "Enter" && (!inField || e.target === ui.label)) {
    if (e.target instanceof HTMLButtonElement) return; // the button's own click
    e.preventDefault();
    save();
  } else if (e.key === "ArrowRight" && !inField) {
    nextImage();
  }
}

function init() {
  ui.canvas.addEventListener("pointerdown", onPointerDown);
  ui.canvas.addEventListener("pointermove", onPointerMove);
  ui.canvas.addEventListener("pointerup", onPointerUp);
  ui.canvas.addEventListener("pointercancel", onPointerUp);
  ui.image.addEventListener("load", redraw);
  ui.image.addEventListener("error", () => {
    if (state.n !== null) showMessage(ui.message, "error", `Image ${state.n} did not load.`);
  });
  ui.undo.addEventListener("click", undo);
  ui.clear.addEventListener("click", resetStrokes);
  ui.skip.addEventListener("click", () => nextImage());
  ui.save.addEventListener("click", () => save());
  ui.index.addEventListener("change", () => {
    const n = Number(ui.index.value);
    if (Number.isInteger(n) && n >= 0 && n < state.info.count) showImage(n);
    else showMessage(ui.message, "error", `Choose an image from 0 to ${state.info.count - 1}.`);
  });
  document.addEventListener("keydown", onKey);
  window.addEventListener("resize", redraw);
  load();
}

init();
