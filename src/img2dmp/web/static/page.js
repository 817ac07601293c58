// The Page view: choose or drop a photo of a page; every character's box and index over
// the photo, the predicted paths written in reading order (pen lifted between them), the
// flagged characters marked and listed, the page document to download; the arm writes it
// (page_arm.js).
import { api, el, fitCanvas, flagText, initHeader, showError, showMessage } from "./common.js";
import { armCard } from "./page_arm.js";

// Box colours of successive lines (as the page picture of img2dmp predict --page).
const LINE_COLOURS = ["#0072b2", "#009e73", "#cc79a7", "#e69f00", "#56b4e9"];
const COLOURS = { path: "rgba(224, 0, 122, 0.85)", travel: "rgba(29,35,48,0.55)", pen: "#1c9a5a" };
// Seconds (at 1x) the lifted pen takes from one character to the next.
const TRAVEL_S = 0.25;

// A stroke model's page lists every stroke as an entry (docs/PAGE.md): its character's
// box, index and flags are shown once, on the character's first stroke.
const isStrokes = (page) => page.entries === "strokes";
/** The box an entry belongs to: its own, or on a stroke model's page its character's. */
const boxKey = (c) => (c.character === undefined ? c.index : c.character);
/** One entry per box: every entry, or each character's first stroke. */
const owners = (page) => (isStrokes(page) ? page.characters.filter((c) => c.stroke === 1)
  : page.characters);
const unit = (page) => (isStrokes(page) ? "stroke" : "character");
/** The kind of the model that read `page` (for the flags' words). */
const modelKind = (page) => (isStrokes(page) ? "strokes" : "dmp");

const $ = (id) => document.getElementById(id);
const ui = {
  card: $("page-card"), choose: $("choose-photo"), file: $("photo-file"), replay: $("replay"),
  showAll: $("show-all"), speed: $("speed"), numbers: $("show-numbers"),
  download: $("download-page"), summary: $("page-summary"), playLine: $("play-line"),
  progress: $("play-progress"), status: $("play-status"), message: $("page-message"),
  drop: $("page-drop"), stage: $("page-stage"), photo: $("photo"), paths: $("paths"),
  live: $("live"), boxes: $("boxes"), placeholder: $("page-placeholder"),
  dropLabel: $("page-drop-label"), legend: $("legend"), flaggedCard: $("flagged-card"),
  flagged: $("flagged"),
};

const state = {
  file: null, // the photo chosen
  photoUrl: null, // its object URL, shown by the <img>
  answer: null, // the last /api/predict_page answer
  seq: 0,
  abort: null,
  play: null, // {timeline, elapsed, prev, drawn}
  raf: null,
};

const models = initHeader("page", ui.message);
const arm = armCard(markArm);

// ---------------------------------------------------------------- the photo ------

function choosePhoto(file) {
  if (!file) return;
  state.file = file;
  if (state.photoUrl) URL.revokeObjectURL(state.photoUrl);
  state.photoUrl = URL.createObjectURL(file);
  ui.photo.src = state.photoUrl;
  clearResult();
  ui.stage.hidden = false;
  ui.placeholder.hidden = true;
  readPage();
}

function setupDrop() {
  const on = (flag) => {
    ui.drop.classList.toggle("drop-target", flag);
    ui.dropLabel.hidden = !flag;
  };
  ui.card.addEventListener("dragover", (e) => {
    e.preventDefault();
    on(true);
  });
  ui.card.addEventListener("dragleave", (e) => {
    if (!ui.card.contains(e.relatedTarget)) on(false);
  });
  ui.card.addEventListener("drop", (e) => {
    e.preventDefault();
    on(false);
    choosePhoto(e.dataTransfer.files[0]);
  });
  ui.choose.addEventListener("click", () => ui.file.click());
  ui.file.addEventListener("change", () => {
    choosePhoto(ui.file.files[0]);
    ui.file.value = "";
  });
}

// ---------------------------------------------------------------- reading --------

function pageUrl() {
  const q = new URLSearchParams({ name: state.file.name || "photo" });
  if (models.current()) q.set("model", models.current());
  return `/api/predict_page?${q}`;
}

async function readPage() {
  if (!state.file) return;
  await models.ready;
  const seq = ++state.seq;
  if (state.abort) state.abort.abort();
  state.abort = new AbortController();
  arm.reset(); // a new reading: the arm's run of the previous one goes
  setState("loading");
  showMessage(ui.message, "", "");
  ui.summary.textContent = `Reading ${state.file.name || "the photo"}\u2026`;
  try {
    const answer = await api(pageUrl(), {
      method: "POST", body: state.file, signal: state.abort.signal,
    });
    if (seq !== state.seq) return;
    await ui.photo.decode().catch(() => {}); // its size places the paths
    if (seq === state.seq) showPage(answer);
  } catch (e) {
    if (seq !== state.seq || e.name === "AbortError") return;
    setState("error");
    ui.summary.textContent = "";
    showError(ui.message, e, "Could not read the page");
  }
}

function setState(name) {
  ui.card.dataset.state = name;
  if (name === "loading") ui.card.setAttribute("aria-busy", "true");
  else ui.card.removeAttribute("aria-busy");
}

function clearResult() {
  stopPlaying();
  state.answer = null;
  state.play = null;
  ui.boxes.replaceChildren();
  ui.flagged.replaceChildren();
  ui.flaggedCard.hidden = true;
  ui.download.hidden = true;
  ui.legend.hidden = true;
  ui.playLine.hidden = true;
  for (const b of [ui.replay, ui.showAll]) b.disabled = true;
  Object.assign(ui.card.dataset, {
    characters: "0", strokes: "", lines: "0", flagged: "0", drawn: "0",
  });
  for (const c of [ui.paths, ui.live]) clearCanvas(c);
}

function showPage(answer) {
  state.answer = answer;
  const page = answer.page;
  const chars = page.characters;
  const flagged = owners(page).filter((c) => c.flags.length > 0);
  const [w, h] = page.image_size_px;
  ui.stage.style.setProperty("--aspect", String(w / h));
  Object.assign(ui.card.dataset, {
    characters: String(owners(page).length), lines: String(page.lines.length),
    strokes: isStrokes(page) ? String(chars.length) : "", flagged: String(flagged.length),
  });
  showSummary(answer, flagged.length);
  ui.download.href = answer.document;
  ui.download.download = answer.filename;
  ui.download.hidden = false;
  drawBoxes(page);
  listFlagged(flagged, modelKind(page));
  arm.show(answer);
  ui.legend.hidden = chars.length === 0;
  if (chars.length === 0) {
    setState("done");
    showMessage(ui.message, "notice", noCharactersText(page));
    return;
  }
  for (const b of [ui.replay, ui.showAll]) b.disabled = false;
  play();
}

/** "65 characters in 3 lines · 45 flagged" (a stroke model's page: "8 characters (16
 * strokes) in 2 lines"), then the photo, the model and the time. */
function showSummary(answer, nFlagged) {
  const page = answer.page;
  const n = owners(page).length;
  const lines = page.lines.length;
  const [w, h] = page.image_size_px;
  const plural = (k, word) => `${k}\u00a0${word}${k === 1 ? "" : "s"}`;
  const strokes = isStrokes(page) ? ` (${plural(page.characters.length, "stroke")})` : "";
  const counts = el("strong", { id: "page-count" },
    `${plural(n, "character")}${strokes} in ${plural(lines, "line")}`);
  const flags = n ? el("strong", { class: nFlagged ? "flag-count" : "" }, `${nFlagged} flagged`) : "";
  const r = page.refinement;
  const unfamiliar = r.unfamiliar_steps !== undefined ? `, ${r.unfamiliar_steps} if unfamiliar` : "";
  const refined = r.steps || r.unfamiliar_steps ? ` \u00b7 refined ${r.steps} steps${unfamiliar}` : "";
  const rest = ` \u00b7 photo ${w}\u00d7${h}\u00a0px \u00b7 model ${answer.model}${refined}` +
    ` \u00b7 read in ${(answer.elapsed_ms / 1000).toFixed(2)}\u00a0s`;
  ui.summary.replaceChildren(counts, n ? " \u00b7 " : "", flags, ...turnedText(page),
    ...restoredText(page), rest);
}

/** " · a glare's contrast given back, up to 2.4×" and " · a shake of 9.3 px at 31° undone"
 * for a page whose photo was mended before its ink was read (the document's glare_gain
 * and shake); nothing for one read as it was. */
function restoredText(page) {
  const out = [];
  if ((page.glare_gain || 1) > 1) {
    out.push(" \u00b7 ", el("span", { id: "page-glare" },
      `a glare's contrast given back, up to ${page.glare_gain.toFixed(1)}\u00d7`));
  }
  if (page.shake) {
    const { length_px: length, direction_deg: direction } = page.shake;
    out.push(" \u00b7 ", el("span", { id: "page-shake" },
      `a shake of ${length.toFixed(1)}\u00a0px at ${Math.round(direction)}\u00b0 undone`));
  }
  return out;
}

/** " · turned 14.4° clockwise to level its lines" for a page read turned (a photo taken
 * askew, sideways or upside down: the document's turned_deg); nothing for one read as it
 * stands. */
function turnedText(page) {
  const d = page.turned_deg || 0;
  if (!d) return [];
  const way = d < 0 ? "clockwise" : "counter-clockwise";
  const why = Math.abs(d) < 45 ? "to level its lines" : "to read it upright";
  return [" \u00b7 ", el("span", { id: "page-turned" },
    `turned ${Math.abs(d).toFixed(1)}\u00b0 ${way} ${why}`)];
}

function noCharactersText(page) {
  if (page.flags.includes("no_ink")) {
    return "Nothing on this photo stands out from the paper: no characters found.";
  }
  if (page.flags.includes("too_small")) {
    return "The characters on this photo are under 4 pixels tall, too small to read: " +
      "photograph the page closer or at a higher resolution.";
  }
  return "No characters found on this photo.";
}

// ---------------------------------------------------------------- boxes ----------

/** Position `node` over the photo's pixel box [x0, y0, x1, y1] (shares of its size). */
function placeBox(node, box, w, h) {
  const [x0, y0, x1, y1] = box;
  Object.assign(node.style, {
    left: `${(100 * x0) / w}%`, top: `${(100 * y0) / h}%`,
    width: `${(100 * (x1 - x0)) / w}%`, height: `${(100 * (y1 - y0)) / h}%`,
  });
}

function boxTitle(c, kind) {
  const pct = (v) => `${Math.round(100 * v)}\u00a0%`;
  const sure = c.count_probability == null ? "" : ` (${pct(c.count_probability)} sure)`;
  const read = c.stroke === undefined ? `probability ${pct(c.probability)}`
    : `${c.n_strokes}\u00a0stroke${c.n_strokes === 1 ? "" : "s"}${sure}`;
  const head = `#${boxKey(c)}: ${read}, path on ink ` +
    `${pct(c.fit.path_on_ink)}, ink written ${pct(c.fit.ink_written)}`;
  return c.flags.length ? `${head}\nFlagged: ${flagText(c.flags, c.fit, kind)}` : head;
}

function drawBoxes(page) {
  const [w, h] = page.image_size_px;
  const kind = modelKind(page);
  ui.boxes.replaceChildren(
    ...owners(page).map((c) => {
      const flagged = c.flags.length > 0;
      const box = el(
        "div",
        { class: flagged ? "box flagged" : "box", title: boxTitle(c, kind), "data-index": boxKey(c),
          "data-flags": c.flags.join(" ") },
        el("span", { class: "index" }, String(boxKey(c))),
      );
      if (!flagged) box.style.setProperty("--line-colour", lineColour(c.line));
      placeBox(box, isStrokes(page) ? c.character_box_image_px : c.box_image_px, w, h);
      return box;
    }),
  );
}

function lineColour(line) {
  return LINE_COLOURS[line % LINE_COLOURS.length];
}

function boxOf(index) {
  return ui.boxes.querySelector(`.box[data-index="${index}"]`);
}

function listFlagged(flagged, kind) {
  ui.flaggedCard.hidden = flagged.length === 0;
  ui.flagged.replaceChildren(
    ...flagged.map((c) => {
      const item = el(
        "button",
        { type: "button", class: "flag-item", "data-index": boxKey(c) },
        el("span", { class: "index" }, `#${boxKey(c)}`),
        el("span", {}, flagText(c.flags, c.fit, kind)),
      );
      const mark = (on) => boxOf(boxKey(c))?.classList.toggle("focus", on);
      item.addEventListener("mouseenter", () => mark(true));
      item.addEventListener("mouseleave", () => mark(false));
      item.addEventListener("focus", () => mark(true));
      item.addEventListener("blur", () => mark(false));
      item.addEventListener("click", () => boxOf(boxKey(c))?.scrollIntoView({ block: "center" }));
      return el("li", {}, item);
    }),
  );
}

// ---------------------------------------------------------------- paths ----------

function clearCanvas(canvas) {
  const { ctx, width, height } = fitCanvas(canvas);
  ctx.clearRect(0, 0, width, height);
  return ctx;
}

/** Photo pixels (centre convention) to the canvas's CSS pixels. */
function photoMap(canvas) {
  const [w] = state.answer.page.image_size_px;
  const s = canvas.getBoundingClientRect().width / w;
  return (p) => [(p[0] + 0.5) * s, (p[1] + 0.5) * s];
}

function lineWidth(canvas) {
  const page = state.answer.page;
  const s = canvas.getBoundingClientRect().width / page.image_size_px[0];
  return Math.max(1.5, Math.min(4, (page.character_height_px * s) / 15));
}

/** Character `c`'s path up to sample k: pen-down runs solid, pen-up travel dashed
 * (`withTravel`), on a context already styled. */
function drawCharacter(ctx, c, k, map, withTravel) {
  const pts = c.path_image_px.map(map);
  const last = Math.min(k, pts.length - 1);
  const isDown = (i) => c.pen[i - 1] >= 0.5 && c.pen[i] >= 0.5; // the segment to point i
  for (let i = 1; i <= last; ) {
    const down = isDown(i);
    const start = i - 1;
    while (i <= last && isDown(i) === down) i++;
    if (!down && !withTravel) continue;
    ctx.setLineDash(down ? [] : [3, 4]);
    ctx.beginPath();
    ctx.moveTo(...pts[start]);
    for (let j = start + 1; j < i; j++) ctx.lineTo(...pts[j]);
    ctx.stroke();
  }
  ctx.setLineDash([]);
  return pts[Math.max(0, last)];
}

function pathStyle(ctx, width) {
  ctx.lineCap = "round";
  ctx.lineJoin = "round";
  ctx.strokeStyle = COLOURS.path;
  ctx.lineWidth = width;
}

/** The written characters (the first `n`) on the paths layer, drawn afresh. */
function drawWritten(n) {
  const ctx = clearCanvas(ui.paths);
  const map = photoMap(ui.paths);
  pathStyle(ctx, lineWidth(ui.paths));
  for (const c of state.answer.page.characters.slice(0, n)) drawCharacter(ctx, c, Infinity, map);
}

function drawPen(ctx, p, down, width) {
  ctx.beginPath();
  ctx.arc(p[0], p[1], width + 2.5, 0, 2 * Math.PI);
  ctx.fillStyle = down ? COLOURS.pen : "#fff";
  ctx.strokeStyle = COLOURS.pen;
  ctx.lineWidth = 1.5;
  ctx.fill();
  if (!down) ctx.stroke();
}

// ---------------------------------------------------------------- playing --------

/** When each character starts (seconds at 1x): its own duration, a lift before it. */
function timeline(chars) {
  let t = 0;
  return chars.map((c, i) => {
    if (i > 0) t += TRAVEL_S;
    const times = c.times_s;
    const entry = { start: t, duration: times[times.length - 1] - times[0] };
    t += entry.duration;
    return entry;
  });
}

function play() {
  stopPlaying();
  const chars = state.answer.page.characters;
  state.play = { timeline: timeline(chars), elapsed: 0, prev: null, drawn: 0 };
  drawWritten(0);
  ui.playLine.hidden = false;
  ui.progress.max = chars.length;
  setState("playing");
  showProgress(0);
  state.raf = requestAnimationFrame(step);
}

function stopPlaying() {
  cancelAnimationFrame(state.raf);
  state.raf = null;
  for (const b of ui.boxes.querySelectorAll(".box.current")) b.classList.remove("current");
}

function step(now) {
  const p = state.play;
  if (p.prev !== null) p.elapsed += ((now - p.prev) / 1000) * Number(ui.speed.value);
  p.prev = now;
  const chars = state.answer.page.characters;
  const done = p.timeline.filter((e) => e.start + e.duration <= p.elapsed).length;
  if (done !== p.drawn) {
    p.drawn = done;
    drawWritten(done);
    showProgress(done);
  }
  if (done >= chars.length) {
    finish();
    return;
  }
  drawLive(done, p.elapsed - p.timeline[done].start);
  state.raf = requestAnimationFrame(step);
}

/** The live layer: character i written up to `t` seconds, or the pen on its way to it. */
function drawLive(i, t) {
  const ctx = clearCanvas(ui.live);
  const map = photoMap(ui.live);
  const width = lineWidth(ui.live);
  const c = state.answer.page.characters[i];
  markCurrent(boxKey(c));
  if (t < 0) {
    drawTravel(ctx, i, 1 + t / TRAVEL_S, map, width);
    return;
  }
  const times = c.times_s;
  let k = 0;
  while (k < times.length - 1 && times[k + 1] - times[0] <= t) k++;
  pathStyle(ctx, width);
  const at = drawCharacter(ctx, c, k, map, true);
  drawPen(ctx, at, c.pen[k] >= 0.5, width);
}

/** The lifted pen a share `u` of the way from character i-1's end to character i's start. */
function drawTravel(ctx, i, u, map, width) {
  const chars = state.answer.page.characters;
  const prev = chars[i - 1].path_image_px;
  const a = map(prev[prev.length - 1]);
  const b = map(chars[i].path_image_px[0]);
  const at = [a[0] + (b[0] - a[0]) * u, a[1] + (b[1] - a[1]) * u];
  ctx.strokeStyle = COLOURS.travel;
  ctx.lineWidth = 1;
  ctx.setLineDash([3, 4]);
  ctx.beginPath();
  ctx.moveTo(...a);
  ctx.lineTo(...at);
  ctx.stroke();
  ctx.setLineDash([]);
  drawPen(ctx, at, false, width);
}

/** Mark the box of the character the arm is writing, entry `index` of the page
 * document (null: none). */
function markArm(index) {
  for (const b of ui.boxes.querySelectorAll(".box.arm")) b.classList.remove("arm");
  const c = index === null ? undefined : state.answer?.page.characters[index];
  if (c) boxOf(boxKey(c))?.classList.add("arm");
}

function markCurrent(index) {
  const box = boxOf(index);
  if (!box || box.classList.contains("current")) return;
  for (const b of ui.boxes.querySelectorAll(".box.current")) b.classList.remove("current");
  box.classList.add("current");
}

function showProgress(done) {
  const n = state.answer.page.characters.length;
  ui.card.dataset.drawn = String(done);
  ui.progress.value = done;
  ui.status.textContent = `${done} of ${n} ${unit(state.answer.page)}s written`;
}

function finish() {
  const n = state.answer.page.characters.length;
  stopPlaying();
  state.play.drawn = n;
  clearCanvas(ui.live);
  drawWritten(n);
  showProgress(n);
  setState("done");
}

// ---------------------------------------------------------------- wiring ---------

function init() {
  setupDrop();
  ui.replay.addEventListener("click", () => state.answer && play());
  ui.showAll.addEventListener("click", () => state.answer && finish());
  ui.numbers.addEventListener("change", () => {
    ui.boxes.classList.toggle("no-numbers", !ui.numbers.checked);
  });
  models.onChange(() => readPage());
  new ResizeObserver(() => {
    if (state.answer && state.play) drawWritten(state.play.drawn);
  }).observe(ui.stage);
}

init();
