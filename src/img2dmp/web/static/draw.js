// The Draw page: draw (or drop) a digit, predict its DMP, watch it written, download it,
// have the simulated robot write it. A stroke model's character is played stroke by
// stroke (the pen-up travel between them dashed and faint); it cannot be bent.
import {
  api, ApiError, capture, downloadText, el, fitCanvas, flagText, initHeader, showError,
  showJobState, showMessage,
} from "./common.js";

// Strokes are kept in a fixed logical frame (LOGICAL x LOGICAL), whatever the CSS size.
const LOGICAL = 320;
const INK_WIDTH = LOGICAL / 14; // as the server renders the strokes
const AUTO_PREDICT_MS = 400;
const POLL_MS = 500;
const COLORS = {
  ink: "#1d2330", traj: "#e4572e", start: "#1c9a5a", other: "rgba(47,91,211,0.5)",
  unbent: "rgba(93,102,119,0.55)",
};
// Dragging the goal starts within this many CSS pixels of its marker.
const GOAL_GRAB_PX = 22;
// The pen-up travel (between a stroke model's strokes): dashed, thin and this faint.
const PEN_UP_ALPHA = 0.5;

const $ = (id) => document.getElementById(id);
const ui = {
  drawing: $("drawing"), drawOverlay: $("drawing-overlay"), stage: $("drop-zone"),
  placeholder: $("draw-placeholder"), dropLabel: $("drop-label"), file: $("file"),
  drawError: $("draw-error"), result: $("result"), inputImage: $("input-image"),
  seenOverlay: $("seen-overlay"), seenEmpty: $("seen-empty"), meta: $("result-meta"),
  fitNote: $("fit-note"), confNote: $("confidence-note"), bend: $("bend"), speed: $("speed"),
  speedValue: $("speed-value"), bendReset: $("bend-reset"), bendMeta: $("bend-meta"),
  bendError: $("bend-error"), bendOff: $("bend-off"), strokeNote: $("stroke-note"),
  robotHint: $("robot-hint"), drawTitle: $("draw-title"),
  hyps: $("hypotheses"), replay: $("replay"), dlDmp: $("download-dmp"),
  dlCsv: $("download-csv"), write: $("write"), job: $("job"), jobProgress: $("job-progress"),
  jobStatus: $("job-status"), robotError: $("robot-error"), jobResult: $("job-result"),
  paperFigure: $("paper-figure"), paper: $("paper"), animFigure: $("animation-figure"),
  animSlot: $("animation-slot"), summary: $("summary"),
};

const state = {
  strokes: [], // [[[x, y, t_ms], ...], ...] in the logical frame
  current: null, // the stroke being drawn
  t0: null, // performance.now() of the first point
  upload: null, // {name, dataUrl, img} when an image file is the input
  answer: null, // the last /api/predict answer
  selected: 0, // index of the hypothesis shown
  name: "drawing",
  timer: null,
  seq: 0,
  abort: null,
  raf: null,
  job: null,
  goal: null, // [x, y] the goal dragged to (model frame), or null: the hypothesis' own
  bent: null, // the last /api/bend answer for the shown hypothesis, or null: not bent
  bendBusy: false, // a /api/bend request is on its way
  bendPending: null, // what to do once it is back: "draw" (again), "play" or null
  drag: null, // the pointer dragging the goal
};

const models = initHeader("draw", ui.drawError);

// ---------------------------------------------------------------- drawing --------

function logicalPoint(e) {
  const r = ui.drawing.getBoundingClientRect();
  const s = LOGICAL / r.width;
  const t = e.timeStamp > 0 ? e.timeStamp : performance.now();
  if (state.t0 === null) state.t0 = t;
  const round = (v) => Math.round(v * 100) / 100;
  return [round((e.clientX - r.left) * s), round((e.clientY - r.top) * s), round(t - state.t0)];
}

function redrawDrawing() {
  const { ctx, width, height } = fitCanvas(ui.drawing);
  ctx.fillStyle = "#fff";
  ctx.fillRect(0, 0, width, height);
  if (state.upload && state.upload.img) {
    const img = state.upload.img;
    const m = fitFrame(width, height, img.naturalHeight, img.naturalWidth);
    ctx.imageSmoothingEnabled = m.s < 1; // pixelated when enlarged, smooth when shrunk
    ctx.drawImage(img, m.ox, m.oy, img.naturalWidth * m.s, img.naturalHeight * m.s);
  }
  const s = width / LOGICAL;
  ctx.strokeStyle = COLORS.ink;
  ctx.fillStyle = COLORS.ink;
  ctx.lineCap = "round";
  ctx.lineJoin = "round";
  ctx.lineWidth = INK_WIDTH * s;
  for (const stroke of state.strokes) drawStroke(ctx, stroke, s);
  ui.drawing.dataset.strokes = String(state.strokes.length);
  ui.placeholder.hidden = state.strokes.length > 0 || state.upload !== null;
}

function drawStroke(ctx, stroke, s) {
  if (stroke.length === 1) {
    ctx.beginPath();
    ctx.arc(stroke[0][0] * s, stroke[0][1] * s, ctx.lineWidth / 2, 0, 2 * Math.PI);
    ctx.fill();
    return;
  }
  ctx.beginPath();
  ctx.moveTo(stroke[0][0] * s, stroke[0][1] * s);
  for (const p of stroke.slice(1)) ctx.lineTo(p[0] * s, p[1] * s);
  ctx.stroke();
}

function onPointerDown(e) {
  if (e.pointerType === "mouse" && e.button !== 0) return;
  e.preventDefault();
  clearTimeout(state.timer);
  if (state.upload) clearAll(); // drawing starts a new input
  capture(ui.drawing, e);
  state.current = { id: e.pointerId, points: [logicalPoint(e)] };
  state.strokes.push(state.current.points);
  clearOverlay(ui.drawOverlay);
  redrawDrawing();
}

function onPointerMove(e) {
  if (!state.current || e.pointerId !== state.current.id) return;
  const events = e.getCoalescedEvents ? e.getCoalescedEvents() : [];
  for (const ev of events.length ? events : [e]) addPoint(logicalPoint(ev));
  redrawDrawing();
}

function addPoint(p) {
  const pts = state.current.points;
  const last = pts[pts.length - 1];
  if (p[0] === last[0] && p[1] === last[1]) return; // the pen did not move
  if (p[2] <= last[2]) p[2] = last[2] + 0.01; // keep time strictly increasing
  pts.push(p);
}

function onPointerUp(e) {
  if (!state.current || e.pointerId !== state.current.id) return;
  addPoint(logicalPoint(e));
  state.current = null;
  redrawDrawing();
  clearTimeout(state.timer);
  state.timer = setTimeout(predict, AUTO_PREDICT_MS);
}

function clearAll() {
  clearTimeout(state.timer);
  state.strokes = [];
  state.current = null;
  state.t0 = null;
  state.upload = null;
  state.name = "drawing";
  showMessage(ui.drawError, "", "");
  clearOverlay(ui.drawOverlay);
  redrawDrawing();
}

// ---------------------------------------------------------------- image files ----

function readFile(file) {
  if (!file) return;
  const reader = new FileReader();
  reader.onerror = () => showMessage(ui.drawError, "error", `Could not read ${file.name}.`);
  reader.onload = () => {
    clearAll();
    const dataUrl = String(reader.result);
    state.upload = { name: file.name, dataUrl, img: null };
    state.name = file.name.replace(/\.[^.]*$/, "") || "image";
    const img = new Image();
    img.onload = () => {
      if (state.upload && state.upload.dataUrl === dataUrl) {
        state.upload.img = img;
        redrawDrawing();
      }
    };
    img.src = dataUrl;
    redrawDrawing();
    predict();
  };
  reader.readAsDataURL(file);
}

function setupDrop() {
  const zone = ui.stage;
  const on = (flag) => {
    zone.classList.toggle("drop-target", flag);
    ui.dropLabel.hidden = !flag;
  };
  zone.addEventListener("dragover", (e) => {
    e.preventDefault();
    on(true);
  });
  zone.addEventListener("dragleave", () => on(false));
  zone.addEventListener("drop", (e) => {
    e.preventDefault();
    on(false);
    readFile(e.dataTransfer.files[0]);
  });
  $("choose-file").addEventListener("click", () => ui.file.click());
  ui.file.addEventListener("change", () => {
    readFile(ui.file.files[0]);
    ui.file.value = "";
  });
}

// ---------------------------------------------------------------- predicting -----

function requestBody() {
  const body = {};
  if (state.upload) body.image = state.upload.dataUrl;
  else {
    body.strokes = state.strokes;
    body.canvas = [LOGICAL, LOGICAL];
  }
  if (models.current()) body.model = models.current();
  return body;
}

async function predict() {
  clearTimeout(state.timer);
  if (!state.upload && state.strokes.length === 0) {
    showMessage(ui.drawError, "notice", `Draw ${whatToDraw()} first (or choose an image file).`);
    return;
  }
  await models.ready;
  const seq = ++state.seq;
  if (state.abort) state.abort.abort();
  state.abort = new AbortController();
  ui.result.dataset.state = "loading";
  ui.result.setAttribute("aria-busy", "true");
  try {
    const answer = await api("/api/predict", {
      method: "POST", body: requestBody(), signal: state.abort.signal,
    });
    if (seq !== state.seq) return;
    showMessage(ui.drawError, "", "");
    showAnswer(answer);
  } catch (e) {
    if (seq !== state.seq || e.name === "AbortError") return;
    ui.result.dataset.state = "error";
    showError(ui.drawError, e, "Prediction failed");
  } finally {
    if (seq === state.seq) ui.result.removeAttribute("aria-busy");
  }
}

function showAnswer(answer) {
  state.answer = answer;
  state.selected = 0;
  resetBend();
  const n = answer.hypotheses.length;
  ui.result.dataset.hypotheses = String(n);
  ui.result.dataset.answers = String(Number(ui.result.dataset.answers || 0) + 1);
  ui.inputImage.src = answer.input_image;
  ui.inputImage.hidden = false;
  ui.seenEmpty.hidden = true;
  const [h, w] = answer.model_size;
  const top = answer.hypotheses[0];
  ui.meta.textContent =
    `Model ${answer.model} \u00b7 input ${w}\u00d7${h}\u00a0px \u00b7 ` +
    `movement ${top.tau_s.toFixed(2)}\u00a0s \u00b7 ` +
    `answered in ${Math.round(answer.elapsed_ms)}\u00a0ms`;
  showFlags(answer);
  showConfidence(answer);
  showStrokes(answer);
  if (state.job === null) {  // the last run wrote the previous drawing: not this one
    resetJobView();
    ui.job.hidden = true;
  }
  renderHypotheses();
  for (const b of [ui.replay, ui.dlDmp, ui.dlCsv, ui.write]) b.disabled = false;
  ui.write.disabled = state.job !== null;
  ui.bend.hidden = isStrokes();
  ui.seenOverlay.classList.toggle("bendable", !isStrokes());
  animate();
}

/** Whether the answer shown is a stroke model's: a character as several DMPs. */
function isStrokes() {
  return Boolean(state.answer && state.answer.kind === "strokes");
}

/**
 * A stroke model's answer: how many strokes it read and how sure it is of each; why
 * bending is off; what the robot and the download do with it. A one-DMP model's: none.
 */
function showStrokes(answer) {
  const strokes = answer.kind === "strokes" ? answer.hypotheses[0].strokes : null;
  ui.result.dataset.strokes = strokes ? String(strokes.length) : "";
  ui.strokeNote.hidden = !strokes;
  ui.bendOff.hidden = !strokes;
  ui.dlDmp.textContent = strokes ? "Download strokes" : "Download DMP";
  ui.robotHint.textContent = strokes
    ? "A simulated KUKA iiwa arm writes the character stroke by stroke on paper, lifting " +
      "the pen between strokes; this takes a few seconds."
    : "A simulated KUKA iiwa arm writes the movement shown (the selected hypothesis, bent " +
      "if you bent it) on paper; this takes a few seconds.";
  if (!strokes) return;
  const n = strokes.length;
  const sure = strokes.map((s) => `${Math.round(100 * s.presence)}\u00a0%`).join(", ");
  const order = n > 1
    ? ", written in the order numbered, the pen lifted between them (dashed)" : "";
  const count = answer.dmp.count || {};
  const ofCount = count.probability === undefined ? ""
    : `; of the count: ${Math.round(100 * count.probability)}\u00a0%`;
  ui.strokeNote.textContent =
    `${n} stroke${n === 1 ? "" : "s"} read (this model reads up to ` +
    `${modelSlots(answer.model)})${order}; how sure it is of each: ${sure}${ofCount}.`;
  ui.bendOff.textContent =
    `Bending is for one-DMP models: ${answer.model} is a stroke model, whose character is ` +
    `${n} DMP${n === 1 ? "" : "s"}, one per stroke.`;
}

/** What the chosen model reads: a character of several strokes, or a digit. */
function whatToDraw() {
  const m = models.info();
  return m && m.kind === "strokes" ? "a character" : "a digit";
}

/** The Draw card asks for what the chosen model reads. */
function nameWhatToDraw() {
  const what = whatToDraw();
  ui.drawTitle.lastChild.textContent = `Draw ${what}`;
  ui.placeholder.firstChild.textContent = `Draw ${what} here`;
}

/** The stroke slots of a served model ("?" if the list does not say). */
function modelSlots(id) {
  const m = models.info();
  return m && m.id === id && m.stroke_slots ? String(m.stroke_slots) : "?";
}

/** One line when the model has one hypothesis: its probability (always 1) means nothing. */
function showConfidence(answer) {
  const one = answer.hypotheses.length === 1;
  ui.confNote.hidden = !one;
  if (!one) return;
  const fit = answer.fit || {};
  const pct = (v) => `${Math.round(100 * v)} %`;
  const how = Number.isFinite(fit.path_on_ink) && Number.isFinite(fit.ink_written)
    ? `: on ink ${pct(fit.path_on_ink)}, ink written ${pct(fit.ink_written)}` : "";
  const what = answer.kind === "strokes" ? "one reading of the character" : "one movement";
  ui.confNote.textContent =
    `This model proposes ${what} per image, so its probability is always 100 % ` +
    `and says nothing about how sure it is; how well the path covers the ink does${how}.`;
}

/** One line under the result when the prediction is flagged; nothing when it is not. */
function showFlags(answer) {
  const text = flagText(answer.flags, answer.fit, answer.kind);
  ui.result.dataset.flags = (answer.flags || []).join(" ");
  ui.fitNote.replaceChildren();
  ui.fitNote.hidden = !text;
  if (!text) return;
  const onlyNew = answer.flags.every((f) => f === "unfamiliar");
  ui.fitNote.append(onlyNew ? `This character is new to the model: ${text}.`
    : `This does not look like one character: ${text}.`);
  if (answer.flags.includes("several_characters")) {
    ui.fitNote.append(" ", el("a", { href: "/page" }, "Read it on the Page view"), ".");
  }
}

function renderHypotheses() {
  const hyps = state.answer.hypotheses;
  ui.hyps.replaceChildren();
  ui.hyps.hidden = hyps.length < 2;
  if (hyps.length < 2) return;
  hyps.forEach((h, i) => {
    const pct = `${(100 * h.probability).toFixed(1)}\u00a0%`;
    const bar = el("span", { class: "bar" }, el("span", {}));
    bar.firstChild.style.width = `${Math.max(0, Math.min(1, h.probability)) * 100}%`;
    const button = el(
      "button",
      { type: "button", "aria-pressed": String(i === state.selected),
        "aria-label": `Hypothesis ${h.rank}, probability ${pct}; play it` },
      el("span", { class: "rank" }, `#${h.rank}`), bar, el("span", { class: "pct" }, pct),
    );
    button.addEventListener("click", () => {
      state.selected = i;
      for (const b of ui.hyps.querySelectorAll("button")) {
        b.setAttribute("aria-pressed", String(b === button));
      }
      state.goal = null; // a goal belongs to the hypothesis it was dragged from
      state.bent = null;
      bend({ play: true });
    });
    ui.hyps.append(el("li", { class: i === 0 ? "top" : "" }, button));
  });
}

// ---------------------------------------------------------------- trajectories ----

/** Map of a frame of H x W pixels (centre convention) into a box, aspect kept. */
function fitFrame(boxW, boxH, h, w) {
  const s = Math.min(boxW / w, boxH / h);
  return { s, ox: (boxW - w * s) / 2, oy: (boxH - h * s) / 2 };
}

function mapPoints(points, m) {
  return points.map(([x, y]) => [m.ox + (x + 0.5) * m.s, m.oy + (y + 0.5) * m.s]);
}

function clearOverlay(canvas) {
  const { ctx, width, height } = fitCanvas(canvas);
  ctx.clearRect(0, 0, width, height);
}

/** Draw points[0..k] (pen-up travel dashed), the start marker and a direction arrow. */
function drawPath(ctx, pts, pen, k, style) {
  ctx.lineCap = "round";
  ctx.lineJoin = "round";
  ctx.strokeStyle = style.color;
  const last = Math.min(k, pts.length - 1);
  const isDown = (i) => !pen || (pen[i - 1] >= 0.5 && pen[i] >= 0.5);
  // one path per run of pen-down (solid) or pen-up (dashed, thin) segments, so that
  // translucent lines do not darken where the segments meet
  for (let i = 1; i <= last; ) {
    const down = isDown(i);
    ctx.lineWidth = down ? style.width : Math.max(1, style.width / 2);
    ctx.setLineDash(down ? [] : [4, 4]);
    ctx.globalAlpha = down ? 1 : PEN_UP_ALPHA;
    ctx.beginPath();
    ctx.moveTo(pts[i - 1][0], pts[i - 1][1]);
    for (; i <= last && isDown(i) === down; i++) ctx.lineTo(pts[i][0], pts[i][1]);
    ctx.stroke();
  }
  ctx.setLineDash([]);
  ctx.globalAlpha = 1;
  if (!style.markers || pts.length === 0) return;
  drawArrow(ctx, pts, style);
  ctx.fillStyle = COLORS.start;
  ctx.strokeStyle = "#fff";
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.arc(pts[0][0], pts[0][1], style.width + 3, 0, 2 * Math.PI);
  ctx.fill();
  ctx.stroke();
  if (k < pts.length - 1) {
    const p = pts[Math.max(0, k)];
    ctx.fillStyle = style.color;
    ctx.beginPath();
    ctx.arc(p[0], p[1], style.width + 2, 0, 2 * Math.PI);
    ctx.fill();
    ctx.stroke();
  }
}

/** An arrow head pointing along the path where it has left the start point. */
function drawArrow(ctx, pts, style) {
  const [x0, y0] = pts[0];
  const reach = Math.max(14, 6 * style.width);
  let j = 1;
  while (j < pts.length - 1 && Math.hypot(pts[j][0] - x0, pts[j][1] - y0) < reach) j++;
  if (j >= pts.length) return;
  const [x1, y1] = pts[j];
  const [xa, ya] = pts[Math.max(0, j - 1)];
  const a = Math.atan2(y1 - ya, x1 - xa);
  if (!Number.isFinite(a) || (x1 === x0 && y1 === y0)) return;
  const size = 4 + 1.6 * style.width;
  ctx.fillStyle = COLORS.start;
  ctx.beginPath();
  ctx.moveTo(x1 + Math.cos(a) * size, y1 + Math.sin(a) * size);
  ctx.lineTo(x1 + Math.cos(a + 2.5) * size, y1 + Math.sin(a + 2.5) * size);
  ctx.lineTo(x1 + Math.cos(a - 2.5) * size, y1 + Math.sin(a - 2.5) * size);
  ctx.closePath();
  ctx.fill();
}

/** One frame: the shown hypothesis up to sample k on both overlays. */
function drawFrame(k) {
  const answer = state.answer;
  const hyps = answer.hypotheses;
  const sel = shown();
  const seen = fitCanvas(ui.seenOverlay);
  seen.ctx.clearRect(0, 0, seen.width, seen.height);
  const mm = modelMap(seen);
  hyps.forEach((h, i) => {
    if (i === state.selected) return;
    const style = { color: COLORS.other, width: i === 0 ? 3.5 : 2, markers: false };
    drawPath(seen.ctx, mapPoints(h.model, mm), h.pen, h.model.length, style);
  });
  if (state.bent) { // the hypothesis as the model wrote it, thin, under the bent one
    const h = hyps[state.selected];
    drawPath(seen.ctx, mapPoints(h.model, mm), h.pen, h.model.length,
      { color: COLORS.unbent, width: 1.5, markers: false });
  }
  const bold = state.selected === 0 ? 4 : 2.5;
  drawPath(seen.ctx, mapPoints(sel.model, mm), sel.pen, k,
    { color: COLORS.traj, width: bold, markers: true });
  if (sel.strokes) drawStrokeNumbers(seen.ctx, mapPoints(sel.model, mm), sel.strokes, k);
  else drawGoal(seen.ctx, mapPoints([goal()], mm)[0]);
  const end = sel.model[sel.model.length - 1];
  ui.result.dataset.end = `${end[0].toFixed(3)},${end[1].toFixed(3)}`;
  ui.result.dataset.tau = String(sel.tau_s);
  const drawn = fitCanvas(ui.drawOverlay);
  drawn.ctx.clearRect(0, 0, drawn.width, drawn.height);
  const [ih, iw] = answer.image_size;
  const im = fitFrame(drawn.width, drawn.height, ih, iw);
  drawPath(drawn.ctx, mapPoints(sel.image, im), sel.pen, k,
    { color: COLORS.traj, width: bold - 1, markers: true });
  if (sel.strokes) drawStrokeNumbers(drawn.ctx, mapPoints(sel.image, im), sel.strokes, k);
}

/** Each stroke begun by sample k: a dot where it starts (after the first) and its number. */
function drawStrokeNumbers(ctx, pts, strokes, k) {
  ctx.font = "bold 13px system-ui, sans-serif";
  ctx.textBaseline = "bottom";
  strokes.forEach((s, j) => {
    const first = s.rows[0];
    if (first > k || first >= pts.length) return;
    const [x, y] = pts[first];
    if (j > 0) {
      ctx.fillStyle = COLORS.start;
      ctx.beginPath();
      ctx.arc(x, y, 4, 0, 2 * Math.PI);
      ctx.fill();
    }
    ctx.lineWidth = 3;
    ctx.strokeStyle = "#fff";
    ctx.strokeText(String(j + 1), x + 7, y - 4);
    ctx.fillStyle = COLORS.start;
    ctx.fillText(String(j + 1), x + 7, y - 4);
  });
}

/** The goal's marker: a ring where the movement is drawn to (the DMP's g). */
function drawGoal(ctx, [x, y]) {
  ctx.setLineDash([]);
  ctx.lineWidth = 2.5;
  ctx.strokeStyle = "#fff";
  ctx.beginPath();
  ctx.arc(x, y, 9, 0, 2 * Math.PI);
  ctx.stroke();
  ctx.strokeStyle = COLORS.traj;
  ctx.lineWidth = 2;
  for (const r of [8, 3]) {
    ctx.beginPath();
    ctx.arc(x, y, r, 0, 2 * Math.PI);
    ctx.stroke();
  }
  const rect = ui.seenOverlay.getBoundingClientRect();
  ui.seenOverlay.dataset.goal = `${x.toFixed(1)},${y.toFixed(1)}`; // CSS px in the overlay
  ui.seenOverlay.dataset.goalPage = `${(rect.left + x).toFixed(1)},${(rect.top + y).toFixed(1)}`;
}

/** The map of the model frame into the seen overlay ({ctx, width, height} of fitCanvas). */
function modelMap(seen) {
  const [mh, mw] = state.answer.model_size;
  return fitFrame(seen.width, seen.height, mh, mw);
}

/** Play the shown hypothesis (bent, if it is) in real time (its `t`, seconds). */
function animate() {
  if (!state.answer) return;
  cancelAnimationFrame(state.raf);
  const h = shown();
  const t = h.t;
  const start = performance.now();
  ui.result.dataset.state = "animating";
  ui.result.dataset.selected = String(state.answer.hypotheses[state.selected].rank);
  const step = (now) => {
    const elapsed = (now - start) / 1000 + (t[0] || 0);
    let k = 0;
    while (k < t.length - 1 && t[k + 1] <= elapsed) k++;
    drawFrame(k);
    if (k < t.length - 1) state.raf = requestAnimationFrame(step);
    else ui.result.dataset.state = "done";
  };
  state.raf = requestAnimationFrame(step);
}

// ---------------------------------------------------------------- bending --------

/** The hypothesis shown: the bent one (POST /api/bend's) or the selected prediction. */
function shown() {
  return state.bent ? state.bent.hypothesis : state.answer.hypotheses[state.selected];
}

/** The DMP document the robot writes and the buttons download, and its rank in it. */
function shownDocument() {
  if (state.bent) return { dmp: state.bent.dmp, rank: 1 };
  return { dmp: state.answer.dmp, rank: state.answer.hypotheses[state.selected].rank };
}

/** The goal (model frame): where it was dragged, else the selected hypothesis' own g. */
function goal() {
  if (state.goal) return state.goal;
  const doc = state.answer.dmp;
  const params = doc.hypotheses ? doc.hypotheses[state.selected].params : doc.params;
  return params.g.slice(0, 2);
}

/** The tempo the speed slider asks for: 2^v times as fast. */
function tempo() {
  return 2 ** Number(ui.speed.value);
}

function speedText() {
  return `${Number((2 ** Number(ui.speed.value)).toPrecision(2))}×`;
}

function resetBend() {
  state.goal = null;
  state.bent = null;
  state.bendPending = null;
  ui.speed.value = "0";
  ui.speedValue.textContent = speedText();
  showMessage(ui.bendError, "", "");
  showBent();
}

/**
 * Bend the selected hypothesis as the goal and the speed say (POST /api/bend, the
 * library's bend_dmp); then draw it whole (`play: false`, while dragging) or play it.
 * One request at a time: what is asked meanwhile is sent when it is back.
 */
async function bend({ play }) {
  if (!state.answer || isStrokes()) return;
  if (state.goal === null && ui.speed.value === "0") {
    state.bent = null;
    showBent();
    if (play) animate();
    else drawFrame(Infinity);
    return;
  }
  if (state.bendBusy) {
    state.bendPending = play ? "play" : state.bendPending || "draw";
    return;
  }
  state.bendBusy = true;
  // "bending" until the last asked-for bend is drawn: "done" before it would show a
  // movement bent to a goal the pointer has already left
  ui.result.dataset.state = "bending";
  const key = `${state.seq}:${state.selected}`; // what it bends: this prediction, this rank
  const h = state.answer.hypotheses[state.selected];
  const body = { dmp: state.answer.dmp, hypothesis: h.rank, n_points: h.t.length };
  if (state.goal) body.goal = state.goal;
  if (ui.speed.value !== "0") body.tempo = tempo();
  let ok = false;
  try {
    const answer = await api("/api/bend", { method: "POST", body });
    if (key === `${state.seq}:${state.selected}`) {
      state.bent = answer;
      ok = true;
      showMessage(ui.bendError, "", "");
    }
  } catch (e) {
    showError(ui.bendError, e, "Could not bend the movement");
  } finally {
    state.bendBusy = false;
  }
  const pending = state.bendPending;
  state.bendPending = null;
  if (pending) {
    bend({ play: play || pending === "play" });
    return;
  }
  if (!ok) {
    if (key === `${state.seq}:${state.selected}`) ui.result.dataset.state = "done";
    return;
  }
  showBent();
  if (play) animate();
  else {
    drawFrame(Infinity);
    ui.result.dataset.state = "done";
  }
}

/** The line saying how the shown movement is bent; the Undo button. */
function showBent() {
  ui.result.dataset.bent = state.bent ? "1" : "0";
  ui.bendReset.disabled = state.goal === null && ui.speed.value === "0";
  if (!state.bent) {
    ui.bendMeta.textContent = "";
    return;
  }
  const was = state.answer.hypotheses[state.selected].tau_s;
  const parts = [];
  if (state.goal) {
    parts.push(`goal (${state.goal[0].toFixed(1)}, ${state.goal[1].toFixed(1)}) px`);
  }
  if (ui.speed.value !== "0") parts.push(`speed ${speedText()}`);
  ui.bendMeta.textContent = `Bent: ${parts.join(", ")} · movement ` +
    `${state.bent.hypothesis.tau_s.toFixed(2)} s (the model's: ${was.toFixed(2)} s)`;
}

/** Pointer position in the model frame, kept inside it. */
function modelPoint(e) {
  const r = ui.seenOverlay.getBoundingClientRect();
  const m = modelMap({ width: r.width, height: r.height });
  const [mh, mw] = state.answer.model_size;
  const clamp = (v, hi) => Math.min(hi - 0.5, Math.max(-0.5, v));
  const x = (e.clientX - r.left - m.ox) / m.s - 0.5;
  const y = (e.clientY - r.top - m.oy) / m.s - 0.5;
  return [Math.round(clamp(x, mw) * 100) / 100, Math.round(clamp(y, mh) * 100) / 100];
}

function nearGoal(e) {
  const r = ui.seenOverlay.getBoundingClientRect();
  const [gx, gy] = mapPoints([goal()], modelMap({ width: r.width, height: r.height }))[0];
  return Math.hypot(e.clientX - r.left - gx, e.clientY - r.top - gy) <= GOAL_GRAB_PX;
}

function onGoalDown(e) {
  if (!state.answer || isStrokes()) return;
  if ((e.pointerType === "mouse" && e.button !== 0) || !nearGoal(e)) return;
  e.preventDefault();
  capture(ui.seenOverlay, e);
  cancelAnimationFrame(state.raf);
  state.drag = e.pointerId;
  ui.seenOverlay.style.cursor = "grabbing";
}

function onGoalMove(e) {
  if (!state.answer || isStrokes()) return;
  if (state.drag !== e.pointerId) {
    ui.seenOverlay.style.cursor = nearGoal(e) ? "grab" : "";
    return;
  }
  state.goal = modelPoint(e);
  drawFrame(Infinity);
  bend({ play: false });
}

function onGoalUp(e) {
  if (state.drag !== e.pointerId) return;
  state.drag = null;
  state.goal = modelPoint(e);
  ui.seenOverlay.style.cursor = "grab";
  bend({ play: true });
}

// ---------------------------------------------------------------- the robot ------

function resetJobView() {
  showMessage(ui.robotError, "", "");
  ui.jobResult.hidden = true;
  ui.paperFigure.hidden = true;
  ui.animFigure.hidden = true;
  ui.summary.hidden = true;
  $("log-line").hidden = true;
  ui.animSlot.replaceChildren();
}

async function writeWithRobot() {
  if (!state.answer || state.job) return;
  resetJobView();
  ui.write.disabled = true;
  const { dmp, rank } = shownDocument();
  const body = isStrokes()
    ? { strokes_page: state.answer.strokes_page, video: true }
    : { dmp, hypothesis: rank, video: true, image: state.answer.input_image };
  try {
    const job = await api("/api/write", { method: "POST", body });
    state.job = job.id;
    showJob(job);
    pollJob(job.id);
  } catch (e) {
    ui.write.disabled = false;
    ui.job.hidden = true;
    const prefix = e instanceof ApiError && e.status === 503 ? "The robot is not available" : "";
    showError(ui.robotError, e, prefix || "Could not start the robot");
  }
}

async function pollJob(id) {
  let job;
  try {
    job = await api(`/api/jobs/${encodeURIComponent(id)}`);
  } catch (e) {
    endJob();
    showError(ui.robotError, e, "Lost the robot job");
    return;
  }
  showJob(job);
  if (job.status === "done" || job.status === "failed") endJob();
  else setTimeout(() => pollJob(id), POLL_MS);
}

function endJob() {
  state.job = null;
  ui.write.disabled = !state.answer;
}

function showJob(job) {
  showJobState(job, {
    card: ui.job, progress: ui.jobProgress, status: ui.jobStatus, errorBox: ui.robotError,
    runningText: (_, p) => (p > 0
      ? `The arm is writing\u2026 ${Math.round(100 * p)}\u00a0%`
      : "Starting the simulation\u2026"),
  });
  if (job.status === "done" || job.status === "failed") showJobFiles(job);
}

function showJobFiles(job) {
  const files = job.files || {};
  ui.jobResult.hidden = false;
  if (files.paper) {
    ui.paper.src = files.paper;
    $("paper-link").href = files.paper;
    ui.paperFigure.hidden = false;
  }
  if (files.animation) {
    const video = /\.(mp4|webm|mov|m4v)(\?|$)/i.test(files.animation);
    const media = video
      ? el("video", { src: files.animation, controls: "", autoplay: "", loop: "", muted: "",
        playsinline: "" })
      : el("img", { src: files.animation, alt: "The arm writing the digit" });
    if (video) media.muted = true;
    ui.animSlot.replaceChildren(media);
    ui.animFigure.hidden = false;
  }
  const lines = job.summary || [];
  ui.summary.textContent = lines.join("\n");
  ui.summary.hidden = lines.length === 0;
  $("log-line").hidden = !files.log;
  if (files.log) $("log-link").href = files.log;
}

// ---------------------------------------------------------------- wiring ---------

function download(kind) {
  if (!state.answer) return;
  const name = state.bent ? `${state.name}-bent` : state.name;
  if (kind === "dmp") {
    const suffix = isStrokes() ? "strokes" : "dmp";
    downloadText(`${JSON.stringify(shownDocument().dmp, null, 1)}\n`, `${name}.${suffix}.json`);
  } else {
    downloadText((state.bent || state.answer).csv, `${name}.csv`, "text/csv");
  }
}

function init() {
  ui.drawing.addEventListener("pointerdown", onPointerDown);
  ui.drawing.addEventListener("pointermove", onPointerMove);
  ui.drawing.addEventListener("pointerup", onPointerUp);
  ui.drawing.addEventListener("pointercancel", onPointerUp);
  $("clear").addEventListener("click", clearAll);
  $("predict").addEventListener("click", predict);
  ui.replay.addEventListener("click", animate);
  ui.dlDmp.addEventListener("click", () => download("dmp"));
  ui.dlCsv.addEventListener("click", () => download("csv"));
  ui.write.addEventListener("click", writeWithRobot);
  ui.seenOverlay.addEventListener("pointerdown", onGoalDown);
  ui.seenOverlay.addEventListener("pointermove", onGoalMove);
  ui.seenOverlay.addEventListener("pointerup", onGoalUp);
  ui.seenOverlay.addEventListener("pointercancel", onGoalUp);
  ui.speed.addEventListener("input", () => {
    ui.speedValue.textContent = speedText();
  });
  ui.speed.addEventListener("change", () => bend({ play: true }));
  ui.bendReset.addEventListener("click", () => {
    resetBend();
    animate();
  });
  setupDrop();
  models.ready.then(nameWhatToDraw);
  models.onChange(() => {
    nameWhatToDraw();
    if (state.upload || state.strokes.length) predict();
  });
  window.addEventListener("resize", () => {
    redrawDrawing();
    if (state.answer && ui.result.dataset.state === "done") drawFrame(Infinity);
  });
  redrawDrawing();
  clearOverlay(ui.seenOverlay);
}

init();
