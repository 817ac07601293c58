// The Page view's robot card: the simulated arm writes the page being shown (a robot job
// of the server, POST /api/pages/{id}/write), its progress by character, then the
// page's figure, its totals, the video, the table of the characters and the downloads.
import { ApiError, api, el, showError, showJobState, showMessage } from "./common.js";

const POLL_MS = 500;
const WIDTH_MM = { min: 10, max: 1000 };

const $ = (id) => document.getElementById(id);

/**
 * The card. `markArm(index)` marks the box of the character the arm is writing on the
 * photo (null: none). Returns {show(answer), reset()}: `show` offers the page of a
 * /api/predict_page answer to the arm, `reset` forgets the page and any run of it.
 */
export function armCard(markArm) {
  const ui = {
    card: $("arm-card"), width: $("arm-width"), skip: $("arm-skip"), video: $("arm-video"),
    write: $("arm-write"), job: $("arm-job"), progress: $("arm-progress"),
    status: $("arm-status"), error: $("arm-error"), result: $("arm-result"),
    totals: $("arm-totals"), paper: $("arm-paper"), paperLink: $("arm-paper-link"),
    paperOpen: $("arm-paper-open"), animFigure: $("arm-animation-figure"),
    animSlot: $("arm-animation-slot"), animCaption: $("arm-animation-caption"),
    table: $("arm-table"), csv: $("arm-csv"), log: $("arm-log"), summary: $("arm-summary"),
  };
  // The page offered (its answer) and the job of it being followed: a new page read
  // forgets both, so a run of the previous page never shows under this one.
  const state = { answer: null, job: null };

  function reset() {
    state.answer = null;
    state.job = null;
    markArm(null);
    ui.card.hidden = true;
    ui.write.disabled = true;
    ui.job.hidden = true;
    ui.job.dataset.status = "";
    showMessage(ui.error, "", "");
    clearResult();
  }

  function clearResult() {
    ui.result.hidden = true;
    ui.paper.removeAttribute("src");
    ui.animFigure.hidden = true;
    ui.animSlot.replaceChildren();
    ui.table.tBodies[0].replaceChildren();
    ui.totals.replaceChildren();
    ui.summary.textContent = "";
  }

  function show(answer) {
    reset();
    state.answer = answer;
    const n = answer.page.characters.length;
    ui.card.hidden = n === 0;
    ui.write.disabled = n === 0;
  }

  /** The width field as a number within its bounds (written back, so the user sees it). */
  function widthMm() {
    const v = Number(ui.width.value);
    const mm = Number.isFinite(v) && ui.width.value !== "" ? v : Number(ui.width.defaultValue);
    const clamped = Math.min(WIDTH_MM.max, Math.max(WIDTH_MM.min, mm));
    ui.width.value = String(clamped);
    return clamped;
  }

  async function write() {
    const answer = state.answer;
    if (!answer || state.job) return;
    ui.write.disabled = true;
    showMessage(ui.error, "", "");
    clearResult();
    const body = { width_mm: widthMm(), skip_flagged: ui.skip.checked, video: ui.video.checked };
    try {
      const job = await api(`/api/pages/${encodeURIComponent(answer.id)}/write`, {
        method: "POST", body,
      });
      if (state.answer !== answer) return; // another page was read meanwhile
      state.job = job.id;
      showJob(job);
      poll(job.id);
    } catch (e) {
      if (state.answer !== answer) return;
      ui.write.disabled = false;
      ui.job.hidden = true;
      const prefix = e instanceof ApiError && e.status === 503 ? "The robot is not available"
        : "The arm cannot write this page";
      showError(ui.error, e, prefix);
    }
  }

  async function poll(id) {
    let job;
    try {
      job = await api(`/api/jobs/${encodeURIComponent(id)}`);
    } catch (e) {
      if (state.job !== id) return;
      endJob();
      showError(ui.error, e, "Lost the robot job");
      return;
    }
    if (state.job !== id) return; // forgotten: a new page was read
    showJob(job);
    if (job.status === "done" || job.status === "failed") endJob();
    else setTimeout(() => poll(id), POLL_MS);
  }

  function endJob() {
    state.job = null;
    markArm(null);
    ui.write.disabled = !state.answer;
  }

  function showJob(job) {
    showJobState(job, {
      card: ui.job, progress: ui.progress, status: ui.status, errorBox: ui.error,
      runningText: (j, p) => runningText(j.character, p),
    });
    if (job.status === "running") markArm(job.character ? job.character.index : null);
    if (job.status === "done") showResult(job);
  }

  function runningText(character, p) {
    if (!character) return "Checking that the arm reaches the page, starting the simulation\u2026";
    const { number, of, index } = character;
    return `The arm is writing character ${number} of ${of} (#${index})\u2026 ` +
      `${Math.round(100 * p)}\u00a0%`;
  }

  function showResult(job) {
    const files = job.files || {};
    ui.result.hidden = false;
    if (files.paper) {
      ui.paper.src = files.paper;
      ui.paperLink.href = files.paper;
      ui.paperOpen.href = files.paper;
    }
    showVideo(files.animation, job.page.video_speed);
    const strokes = state.answer?.page.entries === "strokes"; // a stroke model's page
    showTotals(job.page.totals, strokes ? "stroke" : "character");
    showTable(job.page.characters);
    // Saved under the names img2dmp write --page gives them (<stem>_characters.csv).
    const stem = (state.answer?.filename || "page.json").replace(/\.json$/, "");
    offer(ui.csv, files.characters, `${stem}_characters.csv`);
    offer(ui.log, files.log, `${stem}_log.csv`);
    ui.summary.textContent = (job.summary || []).join("\n");
  }

  function offer(link, url, filename) {
    link.hidden = !url;
    if (url) Object.assign(link, { href: url, download: filename });
  }

  function showVideo(url, speed) {
    ui.animFigure.hidden = !url;
    if (!url) return;
    ui.animSlot.replaceChildren(el("img", { src: url, alt: "The arm writing the page" }));
    ui.animCaption.textContent = speed > 1.001
      ? `The arm writing the page (a time lapse, ${speed.toFixed(1)}\u00d7 the simulated time)`
      : "The arm writing the page";
  }

  /** "5 of 5 characters written · inked 99.9 % · force 5.00 ± 0.02 N" and the rest
   * (`unit`: what the page's entries are, a stroke model's page's "stroke"). */
  function showTotals(t, unit) {
    const pct = (v) => (v === null ? "\u2013" : `${(100 * v).toFixed(1)}\u00a0%`);
    const num = (v, digits) => (v === null ? "\u2013" : v.toFixed(digits));
    const strong = (text) => el("strong", {}, text);
    ui.totals.replaceChildren(
      strong(`${t.characters_written} of ${t.characters} ${unit}s written`),
      ` on ${num(t.width_mm, 1)}\u00a0\u00d7\u00a0${num(t.height_mm, 1)}\u00a0mm \u00b7 `,
      "commanded paths inked ", strong(pct(t.ink_share)),
      `, ink on the paths ${pct(t.ink_on_path_share)} \u00b7 force `,
      strong(`${num(t.force_mean_n, 2)}\u00a0\u00b1\u00a0${num(t.force_std_n, 2)}\u00a0N`),
      ` (set ${t.force_set_n}\u00a0N) \u00b7 tracking ${num(t.tracking_error_mean_mm, 3)}` +
        `\u00a0mm mean \u00b7 ${num(t.simulated_s, 1)}\u00a0s simulated`,
      t.travel_contact_s > 0
        ? ` \u00b7 the pen touched the paper between ${unit}s for ` +
          `${num(t.travel_contact_s, 3)}\u00a0s`
        : "",
    );
  }

  function showTable(characters) {
    const pct = (v) => (v === null || v === undefined ? "\u2013" : (100 * v).toFixed(1));
    const num = (v, digits) => (v === null || v === undefined ? "\u2013" : v.toFixed(digits));
    ui.table.tBodies[0].replaceChildren(
      ...characters.map((c) => {
        const cells = c.written
          ? [pct(c.ink_share), pct(c.ink_on_path_share), num(c.placement_error_mm, 2),
            `${num(c.force_mean_n, 2)} \u00b1 ${num(c.force_std_n, 2)}`,
            num(c.tracking_error_mean_mm, 3), String(c.strokes)]
          : ["skipped", "", "", "", "", ""];
        const row = el("tr", { "data-index": c.index, class: c.written ? "" : "skipped" },
          el("td", {}, String(c.index)), el("td", {}, String(c.line)),
          ...cells.map((text) => el("td", {}, text)), el("td", {}, c.flags.join(" ")));
        return row;
      }),
    );
  }

  ui.write.addEventListener("click", write);
  ui.width.addEventListener("change", widthMm);
  reset();
  return { show, reset };
}
