"""The browser pages of ``img2dmp serve`` in a real browser (Playwright + Debian's Chromium).

- Draw: a digit drawn with the mouse is predicted, its trajectory played over the model's
  input, the ranked hypotheses listed, the DMP downloaded and read back; a pen draws too;
  an API error (a text file as the image) shows its detail in the page; the model
  switcher switches; the simulated robot writes the prediction and shows the paper; a
  flagged prediction gets its one-line note, an unflagged one none; the goal dragged
  moves the path's end, the speed slider halves its duration (the same path), and the
  robot writes the bent DMP and shows its figure near its own size; a model of one
  hypothesis says in one line that its probability means nothing; a stroke model's
  two-stroke character is drawn stroke by stroke, its count said, the pen-up travel
  between the strokes faint and dashed, bending off;
- Page: a photo of a page chosen on the Page view shows every character's box over its
  ink, the count of characters and lines, writes them one after the other, marks and
  lists the flagged one, and downloads the page document; the arm writes a page of three
  characters, naming the character it writes, and shows the page's figure (full size in
  a new tab), its totals and its table; a width at which it does not fit shows the
  server's line; reading a photo again clears the arm's result;
- Record: two strokes traced over an MNIST image are saved as ``image_<n>.json`` in the
  shared recordings' format, with the two strokes;
- the server's names and origins with real requests: a page whose name was made to
  resolve to 127.0.0.1 (DNS rebinding) gets 400 for itself and for its own requests, a
  page of another origin cannot write, a name given with --allowed-host works.

Everything runs against a server started here on two tiny networks (one epoch each),
conftest's tiny stroke model and a tiny MNIST folder. Without ``/usr/bin/chromium`` or
the ``playwright`` package the tests skip, unless ``IMG2DMP_REQUIRE_BROWSER=1`` (CI),
where they fail.
"""

from __future__ import annotations

import base64
import importlib.util
import json
import os
import re
import shutil
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from img2dmp.data.dmpfile import read_dmp_file
from img2dmp.data.mnist import MNIST_FILES, write_idx
from img2dmp.data.recorded import parse_recorded

#: Debian's Chromium (make test installs it); another build may be named in $IMG2DMP_CHROMIUM.
CHROMIUM = Path(os.environ.get("IMG2DMP_CHROMIUM") or "/usr/bin/chromium")
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    # Two names resolved to this machine, as an attacker's DNS (rebinding) or a LAN's would.
    "--host-resolver-rules=MAP rebind.test 127.0.0.1, MAP lan.test 127.0.0.1",
]
REQUIRE = os.environ.get("IMG2DMP_REQUIRE_BROWSER") == "1"
#: MNIST labels of the tiny image folder.
LABELS = [7, 1, 7, 1]
#: A "7" in fractions of the drawing area: one stroke.
SEVEN = [[(0.25, 0.22), (0.75, 0.22), (0.45, 0.82)]]


def _missing() -> str | None:
    """Why the browser tests cannot run here, or None."""
    if importlib.util.find_spec("playwright") is None:
        return "the playwright package is not installed (pip install playwright)"
    if not CHROMIUM.exists():
        return f"{CHROMIUM} is missing (apt-get install chromium)"
    for mod in ("fastapi", "uvicorn"):
        if importlib.util.find_spec(mod) is None:
            return (f"the web extra is not installed ({mod} missing: "
                    "pip install -e '/path/to/img2dmp[web]')")  # fmt: skip
    return None


@pytest.fixture(scope="module", autouse=True)
def _need_browser():
    why = _missing()
    if why and REQUIRE:
        pytest.fail(f"IMG2DMP_REQUIRE_BROWSER=1 but {why}")
    if why:
        pytest.skip(why)


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("web")


@pytest.fixture(scope="module")
def shots(work) -> Path:
    """Where the screenshots go: $IMG2DMP_SCREENSHOTS, else the module's tmp dir."""
    out = Path(os.environ.get("IMG2DMP_SCREENSHOTS") or work / "screenshots")
    out.mkdir(parents=True, exist_ok=True)
    return out


@pytest.fixture(scope="module")
def runs(work, train_tiny_runs) -> dict[int, Path]:
    """Run directories of networks with one and with two hypotheses (one epoch each)."""
    return train_tiny_runs(work, lambda k: work / f"hyp{k}" / "run")


@pytest.fixture(scope="module")
def mnist(work) -> Path:
    """A tiny MNIST folder: four 28 x 28 training images (7, 1, 7, 1) with their labels."""
    folder = work / "mnist"
    folder.mkdir()
    images = np.zeros((len(LABELS), 28, 28), dtype=np.uint8)
    for i, label in enumerate(LABELS):
        if label == 7:
            images[i, 6:9, 7:21] = 255
            for r in range(9, 23):
                c = 20 - (r - 9) // 2
                images[i, r, c - 1 : c + 2] = 255
        else:
            images[i, 5:23, 13:16] = 255
    for split in ("train", "test"):
        img_name, lab_name = MNIST_FILES[split]
        write_idx(folder / f"{img_name}.gz", images)
        write_idx(folder / f"{lab_name}.gz", np.asarray(LABELS, dtype=np.uint8))
    return folder


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _get_json(url: str, body: dict | None = None) -> tuple[int, dict]:
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(url, data=data, headers={"Content-Type": "application/json"})
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read() or b"{}")


@pytest.fixture(scope="module")
def server(work, runs, mnist, stroke_run):
    """``img2dmp serve`` on a free port: {"url", "data_dir", "port", "strokes"} (the id of
    the third model, conftest's tiny stroke model); stopped at the end."""
    exe = shutil.which("img2dmp", path=str(Path(sys.executable).parent)) or "img2dmp"
    port = _free_port()
    data_dir = work / "recordings"
    cmd = [exe, "serve", "--model", str(runs[2]), "--model", str(runs[1]),
           "--model", str(stroke_run), "--mnist", str(mnist), "--data-dir", str(data_dir),
           "--jobs-dir", str(work / "jobs"), "--host", "127.0.0.1", "--port", str(port),
           "--allowed-host", "lan.test"]  # fmt: skip
    log = open(work / "server.log", "wb")
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 60
    try:
        while True:
            if proc.poll() is not None:
                pytest.fail(f"img2dmp serve exited ({proc.returncode}):\n{_tail(work)}")
            try:
                if _get_json(f"{url}/api/models")[0] == 200:
                    break
            except OSError:
                pass
            if time.monotonic() > deadline:
                pytest.fail(f"img2dmp serve did not answer within 60 s:\n{_tail(work)}")
            time.sleep(0.2)
        yield {"url": url, "data_dir": data_dir, "port": port, "strokes": stroke_run.parent.name}
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()


def _tail(work: Path) -> str:
    return (work / "server.log").read_text(errors="replace")[-3000:]


@pytest.fixture(scope="module")
def browser():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), headless=True, args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture
def page(browser, server):
    """A fresh page (1100 x 900); uncaught JavaScript errors fail the test."""
    context = browser.new_context(viewport={"width": 1100, "height": 900}, accept_downloads=True)
    page = context.new_page()
    page.set_default_timeout(20_000)
    errors = []
    page.on("pageerror", lambda e: errors.append(str(e)))
    yield page
    context.close()
    assert not errors, f"JavaScript errors in the page: {errors}"


def _strokes_on(page, selector: str, strokes, steps: int = 6) -> None:
    """Draw strokes (lists of (fx, fy) fractions of the element) with the mouse."""
    box = page.locator(selector).bounding_box()
    at = [[(box["x"] + fx * box["width"], box["y"] + fy * box["height"]) for fx, fy in s]
          for s in strokes]  # fmt: skip
    for stroke in at:
        page.mouse.move(*stroke[0])
        page.mouse.down()
        for p in stroke[1:]:
            page.mouse.move(*p, steps=steps)
        page.mouse.up()


def _predicted(page, n_hypotheses: int) -> None:
    """Wait for a prediction with n hypotheses and its trajectory drawn over the model's
    input and over the drawing."""
    page.locator(f'#result[data-hypotheses="{n_hypotheses}"]').wait_for()
    for overlay in ("seen-overlay", "drawing-overlay"):
        page.wait_for_function(
            """(id) => {
              const c = document.getElementById(id);
              const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
              for (let i = 3; i < d.length; i += 4) if (d[i] > 0) return true;
              return false;
            }""",
            arg=overlay,
        )


def _wait_played(page, timeout_ms: int = 15_000) -> None:
    """Wait for the animation to finish (it plays in real time, tau seconds)."""
    page.locator('#result[data-state="done"]').wait_for(timeout=timeout_ms)


# -- Draw ----------------------------------------------------------------------------------


def test_draw_with_the_mouse_predicts_plays_and_downloads_the_dmp(page, server, shots, tmp_path):
    page.goto(server["url"] + "/")
    page.locator("#site-header .tabs a", has_text="Draw").wait_for()
    _strokes_on(page, "#drawing", SEVEN)
    assert page.locator("#drawing").get_attribute("data-strokes") == "1"
    # no click on Predict: it predicts by itself after the pen lifts
    _predicted(page, 2)
    items = page.locator("#hypotheses li")
    assert items.count() == 2
    assert "%" in items.first.inner_text()
    assert page.locator("#input-image").evaluate("i => i.naturalWidth") > 0
    assert page.locator("#draw-error").is_hidden()
    flags = page.locator("#result").get_attribute("data-flags")
    note = page.locator("#fit-note")
    assert note.is_visible() == bool(flags)  # the note when flagged, nothing otherwise
    if flags:
        assert note.inner_text().startswith("This does not look like one character: ")
    _wait_played(page)
    page.screenshot(path=str(shots / "draw-predicted.png"), full_page=True)

    items.nth(1).locator("button").click()  # the second hypothesis plays
    assert page.locator("#result").get_attribute("data-selected") == "2"
    with page.expect_download() as dl:
        page.locator("#download-dmp").click()
    assert dl.value.suggested_filename == "drawing.dmp.json"
    dmp = tmp_path / dl.value.suggested_filename
    dl.value.save_as(dmp)
    f = read_dmp_file(dmp)
    assert f.params.w.shape[-1] in (2, 3)
    assert len(json.loads(dmp.read_text())["hypotheses"]) == 2
    with page.expect_download() as dl:
        page.locator("#download-csv").click()
    assert dl.value.suggested_filename == "drawing.csv"


def test_the_unfamiliar_note_is_worded_for_the_model_s_kind(page, server):
    """The digit model's note said "its strokes and their count are a guess"."""
    page.goto(server["url"] + "/")
    page.locator("#site-header .tabs a", has_text="Draw").wait_for()
    dmp, strokes = page.evaluate(
        """async () => {
          const { flagText } = await import('/static/common.js');
          return [flagText(['unfamiliar'], {}, 'dmp'), flagText(['unfamiliar'], {}, 'strokes')];
        }"""
    )
    assert dmp.endswith("so its path is a guess") and "stroke" not in dmp, dmp
    assert strokes.endswith("so its strokes and their count are a guess"), strokes


def _cdp_pen_stroke(cdp, points) -> None:
    """One stroke of a pen through Chromium's input pipeline (real pointer events)."""
    kind = ["mousePressed"] + ["mouseMoved"] * (len(points) - 2) + ["mouseReleased"]
    for (x, y), k in zip(points, kind, strict=True):
        event = {"type": k, "x": x, "y": y, "button": "left", "pointerType": "pen"}
        event["buttons"] = 0 if k == "mouseReleased" else 1
        event["clickCount"] = 0 if k == "mouseMoved" else 1
        cdp.send("Input.dispatchMouseEvent", event)


def _cdp_touch_stroke(cdp, points) -> None:
    """One stroke of a finger on a touch screen (real touch -> pointer events)."""
    kind = ["touchStart"] + ["touchMove"] * (len(points) - 1)
    for (x, y), k in zip(points, kind, strict=True):
        cdp.send("Input.dispatchTouchEvent", {"type": k, "touchPoints": [{"x": x, "y": y}]})
    cdp.send("Input.dispatchTouchEvent", {"type": "touchEnd", "touchPoints": []})


def test_a_pen_and_a_finger_draw_too(page, server):
    """Chromium's own input pipeline (DevTools protocol), not synthetic DOM events."""
    page.goto(server["url"] + "/")
    drawing = page.locator("#drawing")
    drawing.wait_for()
    box = drawing.bounding_box()
    cdp = page.context.new_cdp_session(page)
    x, y, w, h = box["x"], box["y"], box["width"], box["height"]
    points = [(x + (0.3 + 0.4 * f) * w, y + (0.2 + 0.6 * f) * h) for f in np.linspace(0, 1, 12)]
    _cdp_pen_stroke(cdp, points)
    assert drawing.get_attribute("data-pointer-type") == "pen"
    assert drawing.get_attribute("data-strokes") == "1"
    _predicted(page, 2)

    page.locator("#clear").click()
    assert drawing.get_attribute("data-strokes") == "0"
    _cdp_touch_stroke(cdp, points[::-1])
    assert drawing.get_attribute("data-pointer-type") == "touch"
    assert drawing.get_attribute("data-strokes") == "1"
    page.locator('#result[data-answers="2"]').wait_for()  # predicted again


def test_an_api_error_shows_its_detail_in_the_page(page, server):
    text = b"this is not an image\n"
    status, answer = _get_json(
        server["url"] + "/api/predict",
        {"image": "data:text/plain;base64," + base64.b64encode(text).decode()},
    )
    assert 400 <= status < 500 and answer["detail"]
    page.goto(server["url"] + "/")
    page.locator("#file").set_input_files(
        files=[{"name": "notes.txt", "mimeType": "text/plain", "buffer": text}]
    )
    error = page.locator("#draw-error")
    error.wait_for()
    assert answer["detail"] in error.inner_text()
    assert page.locator("#result").get_attribute("data-state") == "error"


def test_the_model_switcher_switches(page, server):
    from playwright.sync_api import expect

    page.goto(server["url"] + "/")
    select = page.locator("#model-select")
    select.wait_for()
    assert select.locator("option").all_inner_texts()[0].startswith("hyp2")
    _strokes_on(page, "#drawing", SEVEN)
    _predicted(page, 2)
    select.select_option("hyp1")
    # switching predicts the drawing again, with the other network
    _predicted(page, 1)
    assert page.locator("#hypotheses").is_hidden()
    assert page.locator("#result-meta").inner_text().startswith("Model hyp1")
    page.reload()
    expect(page.locator("#model-select")).to_have_value("hyp1")  # remembered


def test_the_robot_writes_the_prediction(page, server, shots):
    pytest.importorskip("pybullet", reason="the robot extra is not installed")
    page.goto(server["url"] + "/")
    _strokes_on(page, "#drawing", SEVEN)
    _predicted(page, 2)
    page.locator("#write").click()
    job = page.locator("#job")
    job.wait_for()
    page.locator('#job[data-status="done"], #job[data-status="failed"]').wait_for(timeout=60_000)
    assert job.get_attribute("data-status") == "done", page.locator("#robot-error").inner_text()
    page.wait_for_function("() => document.getElementById('paper').naturalWidth > 0")
    assert page.locator("#summary").inner_text().strip()
    page.locator("#paper").scroll_into_view_if_needed()
    page.screenshot(path=str(shots / "draw-robot.png"), full_page=True)
    # a new drawing's prediction clears the run that wrote the previous one
    answers = int(page.locator("#result").get_attribute("data-answers"))
    page.locator("#clear").click()
    _strokes_on(page, "#drawing", SEVEN)
    page.locator(f'#result[data-answers="{answers + 1}"]').wait_for()
    assert page.locator("#job").is_hidden()


def _xy(text: str) -> np.ndarray:
    return np.array([float(v) for v in text.split(",")])


def test_the_goal_dragged_bends_the_path_the_speed_retimes_it_and_the_robot_writes_it(
    page, server, shots, tmp_path
):
    page.goto(server["url"] + "/")
    _strokes_on(page, "#drawing", SEVEN)
    _predicted(page, 2)
    _wait_played(page)
    result, overlay = page.locator("#result"), page.locator("#seen-overlay")
    assert result.get_attribute("data-bent") == "0"
    end0, tau0 = _xy(result.get_attribute("data-end")), float(result.get_attribute("data-tau"))
    goal = _xy(overlay.get_attribute("data-goal-page"))
    box = overlay.bounding_box()
    centre = np.array([box["x"] + box["width"] / 2, box["y"] + box["height"] / 2])
    drag = 70.0 * (centre - goal) / np.linalg.norm(centre - goal)  # toward the middle
    page.mouse.move(*goal)
    page.mouse.down()
    page.mouse.move(*(goal + drag), steps=8)
    page.mouse.up()
    page.locator('#result[data-bent="1"][data-state="done"]').wait_for()
    # the marker followed the pointer, and the path's end moved along with it
    np.testing.assert_allclose(_xy(overlay.get_attribute("data-goal-page")), goal + drag, atol=1.5)
    end1 = _xy(result.get_attribute("data-end"))
    drag_px = drag * 40 / box["width"]  # the model's input is 40 x 40, the overlay square
    along = float(np.dot(end1 - end0, drag_px / np.linalg.norm(drag_px)))
    assert along > 0.5 * np.linalg.norm(drag_px), (end0, end1, drag_px)
    assert page.locator("#bend-meta").inner_text().startswith("Bent: goal (")
    # twice the speed: half the duration, the same path (tempo is exact)
    page.locator("#speed").evaluate(
        "s => { s.value = '1'; s.dispatchEvent(new Event('input'));"
        " s.dispatchEvent(new Event('change')); }"
    )
    page.wait_for_function(
        "(t) => Number(document.getElementById('result').dataset.tau) < 0.6 * t", arg=tau0
    )
    assert float(result.get_attribute("data-tau")) == pytest.approx(tau0 / 2, rel=1e-6)
    np.testing.assert_allclose(_xy(result.get_attribute("data-end")), end1, atol=2e-3)
    assert "speed 2\u00d7" in page.locator("#bend-meta").inner_text()
    page.screenshot(path=str(shots / "draw-bent.png"), full_page=True)
    with page.expect_download() as dl:
        page.locator("#download-dmp").click()
    assert dl.value.suggested_filename == "drawing-bent.dmp.json"
    dl.value.save_as(tmp_path / "bent.dmp.json")
    f = read_dmp_file(tmp_path / "bent.dmp.json")
    bent = json.loads((tmp_path / "bent.dmp.json").read_text())["bent"]
    assert bent["hypothesis"] == 1 and bent["tempo"] == 2.0
    np.testing.assert_allclose(f.params.g[:2], bent["goal"])
    assert float(f.params.tau) == pytest.approx(tau0 / 2, rel=1e-5)

    pytest.importorskip("pybullet", reason="the robot extra is not installed")
    with page.expect_request("**/api/write") as request:
        page.locator("#write").click()
    sent = request.value.post_data_json
    assert sent["hypothesis"] == 1 and sent["dmp"]["bent"] == bent  # the bent DMP
    assert sent["image"].startswith("data:image/png;base64,")  # shown in paper.png
    page.locator('#job[data-status="done"], #job[data-status="failed"]').wait_for(timeout=90_000)
    assert page.locator("#job").get_attribute("data-status") == "done", page.locator(
        "#robot-error"
    ).inner_text()
    page.wait_for_function("() => document.getElementById('paper').naturalWidth > 0")
    # the four-panel figure across the card, near its own size: its text is readable
    shown_w, natural_w = page.locator("#paper").evaluate("i => [i.width, i.naturalWidth]")
    assert shown_w >= 0.85 * natural_w, (shown_w, natural_w)
    page.locator("#paper").scroll_into_view_if_needed()
    page.screenshot(path=str(shots / "draw-bent-robot.png"), full_page=True)


def test_a_model_of_one_hypothesis_says_its_probability_means_nothing(page, server):
    page.goto(server["url"] + "/")
    _strokes_on(page, "#drawing", SEVEN)
    _predicted(page, 2)
    note = page.locator("#confidence-note")
    assert note.is_hidden()  # two hypotheses: their probabilities are shown, and mean something
    page.locator("#model-select").select_option("hyp1")
    _predicted(page, 1)
    note.wait_for()
    text = note.inner_text()
    assert text.startswith("This model proposes one movement per image")
    assert "says nothing about how sure it is" in text and "on ink " in text
    assert len(text.splitlines()) == 1


#: A hook and a tick (test_omniglot's odd characters) in fractions of the drawing area.
HOOK_AND_TICK = [[(0.29, 0.24), (0.29, 0.5), (0.29, 0.76), (0.5, 0.76), (0.71, 0.76)],
                 [(0.57, 0.38), (0.6, 0.42), (0.63, 0.46)]]  # fmt: skip

#: The alpha of the Draw page's model-frame overlay at points ``[x, y]`` of the model's
#: input (each a pixel's centre, as the page maps them).
_ALPHA_AT = """([points, mw, mh]) => {
  const c = document.getElementById('seen-overlay');
  const r = c.getBoundingClientRect();
  const k = c.width / r.width;
  const s = Math.min(r.width / mw, r.height / mh);
  const ox = (r.width - mw * s) / 2, oy = (r.height - mh * s) / 2;
  const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  return points.map(([x, y]) => {
    const px = Math.floor((ox + (x + 0.5) * s) * k), py = Math.floor((oy + (y + 0.5) * s) * k);
    return d[(py * c.width + px) * 4 + 3];
  });
}"""


def test_a_stroke_model_writes_a_character_stroke_by_stroke_lifting_the_pen(page, server, shots):
    answers = []
    page.on(
        "response",
        lambda r: answers.append(r) if r.url.endswith("/api/predict") and r.ok else None,
    )
    page.goto(server["url"] + "/")
    page.locator("#model-select").select_option(server["strokes"])
    assert page.locator("#draw-title").inner_text().endswith("Draw a character")
    assert page.locator("#draw-placeholder").inner_text().startswith("Draw a character here")
    _strokes_on(page, "#drawing", HOOK_AND_TICK)
    assert page.locator("#drawing").get_attribute("data-strokes") == "2"
    _predicted(page, 1)
    _wait_played(page)
    a = answers[-1].json()
    n, (h,) = a["n_strokes"], a["hypotheses"]
    assert a["kind"] == "strokes" and n >= 2
    assert page.locator("#result").get_attribute("data-strokes") == str(n)
    note = page.locator("#stroke-note").inner_text()
    assert note.startswith(f"{n} strokes read (this model reads up to 8)")
    sure = round(100 * a["dmp"]["count"]["probability"])
    assert note.endswith(f"; of the count: {sure}\u00a0%.")
    assert page.locator("#bend").is_hidden()
    assert page.locator("#bend-off").inner_text().startswith("Bending is for one-DMP models")
    assert page.locator("#download-dmp").inner_text() == "Download strokes"
    page.screenshot(path=str(shots / "draw-strokes.png"), full_page=True)
    # as drawn: each stroke opaque at its middle; between two strokes the pen's travel
    # faint and dashed (drawn in part, gaps between the dashes)
    xy, size = np.array(h["model"]), a["model_size"]
    middles = [xy[(s["rows"][0] + s["rows"][1]) // 2].tolist() for s in h["strokes"]]
    assert min(page.evaluate(_ALPHA_AT, [middles, size[1], size[0]])) >= 250
    for s, t in zip(h["strokes"][:-1], h["strokes"][1:], strict=True):
        assert h["pen"][s["rows"][1] + 1] == 0  # the pen is up between them
        f = np.linspace(0.25, 0.75, 200)[:, None]
        line = (1 - f) * xy[s["rows"][1]] + f * xy[t["rows"][0]]
        alpha = np.array(page.evaluate(_ALPHA_AT, [line.tolist(), size[1], size[0]]))
        assert alpha.max() < 200 and np.mean(alpha > 0) > 0.3 and np.mean(alpha == 0) > 0.1


# -- Page ----------------------------------------------------------------------------------


def _css_box(page, selector: str) -> tuple[float, float, float, float]:
    b = page.locator(selector).bounding_box()
    return b["x"], b["y"], b["x"] + b["width"], b["y"] + b["height"]


def _paths_drawn(page) -> int:
    """Painted pixels of the Page view's layer of written paths."""
    return page.evaluate(
        """() => {
          const c = document.getElementById('paths');
          const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
          let n = 0;
          for (let i = 3; i < d.length; i += 4) if (d[i] > 0) n++;
          return n;
        }"""
    )


def test_a_page_photographed_askew_says_it_was_turned(page, server, tmp_path):
    """A page read turned level (the document's ``turned_deg``) says so beside its counts;
    one read as it stands does not."""
    from PIL import Image

    from test_page_reading import _askew

    for angle, said in ((-14.0, True), (0.0, False)):
        photo = tmp_path / f"askew{angle:g}.png"
        Image.fromarray(_askew(angle)[0]).save(photo)
        page.goto(server["url"] + "/page")
        page.locator("#photo-file").set_input_files(str(photo))
        page.locator('#page-card[data-characters="11"]').wait_for()
        assert page.locator("#page-count").inner_text() == "11\u00a0characters in 3\u00a0lines"
        if said:
            text = page.locator("#page-turned").inner_text()
            assert re.fullmatch(r"turned 1[345]\.\d\u00b0 counter-clockwise to level its lines",
                                text), text  # fmt: skip
        else:
            assert page.locator("#page-turned").count() == 0


def test_a_page_says_which_shake_was_undone_and_what_glare_was_given_back(page, server, tmp_path):
    """The document's ``shake`` and ``glare_gain`` said beside the counts; a page read as
    it was says neither."""
    from PIL import Image

    from drawn import glare, grainy_page, moved

    img, _ = grainy_page()
    for name, photo, said in (("plain", img, ()), ("shaken", moved(img, 9, 30), ("shake",)),
                              ("glared", glare(img, 0.8), ("glare",))):  # fmt: skip
        path = tmp_path / f"{name}.png"
        Image.fromarray((np.clip(photo, 0, 1) * 255).astype(np.uint8)).save(path)
        page.goto(server["url"] + "/page")
        page.locator("#photo-file").set_input_files(str(path))
        page.locator('#page-card[data-characters="9"]').wait_for()
        if "shake" in said:
            text = page.locator("#page-shake").inner_text()
            assert re.fullmatch(r"a shake of (8\.\d|9\.\d)\u00a0px at 3[01]\u00b0 undone", text), (
                text
            )
        if "glare" in said:
            text = page.locator("#page-glare").inner_text()
            assert re.fullmatch(r"a glare's contrast given back, up to \d\.\d\u00d7", text), text
        for kind in ("shake", "glare"):
            assert (page.locator(f"#page-{kind}").count() == 1) == (kind in said), (name, kind)


def test_a_page_photo_is_boxed_counted_written_and_its_flagged_character_marked(
    page, server, shots, tmp_path, handwritten_page
):
    from PIL import Image

    image, boxes = handwritten_page
    photo = tmp_path / "page.png"
    Image.fromarray(image).save(photo)
    page.goto(server["url"] + "/page")
    page.locator('#site-header .tabs a[aria-current="page"]', has_text="Page").wait_for()
    # every value data-drawn takes, to see the characters written one after the other
    page.evaluate(
        """() => {
          window.drawn = [];
          const card = document.getElementById('page-card');
          new MutationObserver(() => window.drawn.push(Number(card.dataset.drawn)))
            .observe(card, { attributes: true, attributeFilter: ['data-drawn'] });
        }"""
    )
    page.locator("#photo-file").set_input_files(str(photo))
    page.locator('#page-card[data-characters="5"]').wait_for()
    card = page.locator("#page-card")
    assert card.get_attribute("data-lines") == "2"
    assert page.locator("#page-count").inner_text() == "5\u00a0characters in 2\u00a0lines"
    assert page.locator("#boxes .box").count() == 5
    x, y, x1, _ = _css_box(page, "#photo")
    s = (x1 - x) / image.shape[1]  # CSS pixels per photo pixel
    for i, (bx0, by0, bx1, by1) in enumerate(boxes):
        got = _css_box(page, f'#boxes .box[data-index="{i}"]')
        want = (x + bx0 * s, y + by0 * s, x + bx1 * s, y + by1 * s)
        assert np.abs(np.subtract(got, want)).max() <= 1.5 * s + 1, (i, got, want)
    page.select_option("#speed", "10")
    page.locator('#page-card[data-state="done"]').wait_for()
    assert page.locator("#play-status").inner_text() == "5 of 5 characters written"
    drawn = [d for i, d in enumerate(page.evaluate("window.drawn")) if i == 0 or d != 0]
    assert sorted(set(drawn)) == drawn and drawn[-1] == 5 and len(set(drawn)) >= 3, drawn
    assert _paths_drawn(page) > 0
    # the character cut by the border is flagged: a red box, why on hover, in the list
    box = page.locator('#boxes .box.flagged[data-index="4"]')
    assert "cut_by_border" in box.get_attribute("data-flags")
    assert "border" in box.get_attribute("title")
    item = page.locator('#flagged .flag-item[data-index="4"]')
    assert "border" in item.inner_text()
    hint = page.locator("#flagged-card .hint").inner_text()
    assert "border" in hint and "unfamiliar" in hint, hint
    item.hover()
    assert "focus" in box.get_attribute("class")
    page.screenshot(path=str(shots / "page-read.png"), full_page=True)
    with page.expect_download() as dl:
        page.locator("#download-page").click()
    assert dl.value.suggested_filename == "page_page.json"
    doc = json.loads(Path(dl.value.path()).read_text())
    assert doc["format"] == "img2dmp-page" and len(doc["characters"]) == 5
    assert all(c["dmp"]["format"] == "img2dmp-dmp" for c in doc["characters"])


def test_a_page_photo_dropped_on_the_page_view_is_read(page, server, tmp_path, handwritten_page):
    import io

    from PIL import Image

    image, boxes = handwritten_page
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    page.goto(server["url"] + "/page")
    page.locator("#page-card").wait_for()
    page.evaluate(
        """(b64) => {
          const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
          const dt = new DataTransfer();
          dt.items.add(new File([bytes], 'dropped.png', { type: 'image/png' }));
          const card = document.getElementById('page-card');
          card.dispatchEvent(new DragEvent('dragover', { dataTransfer: dt, bubbles: true }));
          card.dispatchEvent(new DragEvent('drop', { dataTransfer: dt, bubbles: true }));
        }""",
        base64.b64encode(buf.getvalue()).decode(),
    )
    page.locator(f'#page-card[data-characters="{len(boxes)}"]').wait_for()
    assert page.locator("#boxes .box").count() == len(boxes)


def test_a_page_read_by_a_stroke_model_boxes_each_character_once_and_plays_its_strokes(
    page, server, shots, tmp_path
):
    from PIL import Image, ImageDraw

    # the hook and tick twice, side by side, in dark ink on white
    im = Image.new("L", (520, 240), 255)
    draw = ImageDraw.Draw(im)
    for x0 in (20, 280):
        for stroke in HOOK_AND_TICK:
            pts = [(x0 + 220 * x, 10 + 220 * y) for x, y in stroke]
            draw.line(pts, fill=0, width=14, joint="curve")
    photo = tmp_path / "hooks.png"
    im.save(photo)
    page.goto(server["url"] + "/page")
    page.locator("#model-select").select_option(server["strokes"])
    page.locator("#photo-file").set_input_files(str(photo))
    page.locator('#page-card[data-characters="2"]').wait_for()
    card = page.locator("#page-card")
    n = int(card.get_attribute("data-strokes"))  # a stroke model's page: its strokes
    assert n >= 2
    strokes = f"{n}\u00a0stroke" + ("s" if n != 1 else "")
    assert (
        page.locator("#page-count").inner_text() == f"2\u00a0characters ({strokes}) in 1\u00a0line"
    )
    assert page.locator("#boxes .box").count() == 2  # one box a character, not a stroke
    title = page.locator('#boxes .box[data-index="0"]').get_attribute("title")
    assert re.match(r"#0: \d+\u00a0strokes? \(\d+\u00a0% sure\), path on ink", title), title
    page.select_option("#speed", "10")
    page.locator('#page-card[data-state="done"]').wait_for()
    assert page.locator("#play-status").inner_text() == f"{n} of {n} strokes written"
    assert _paths_drawn(page) > 0
    page.screenshot(path=str(shots / "page-strokes.png"), full_page=True)


def test_the_arm_writes_the_page_shown_and_a_new_reading_clears_it(
    page, server, shots, tmp_path, handwritten_page
):
    pytest.importorskip("pybullet", reason="the robot extra is not installed")
    from PIL import Image

    photo = tmp_path / "line.png"
    Image.fromarray(handwritten_page[0][:100]).save(photo)  # the first line: "1 7 0"
    page.goto(server["url"] + "/page")
    page.locator("#photo-file").set_input_files(str(photo))
    page.locator('#page-card[data-characters="3"]').wait_for()
    card = page.locator("#arm-card")
    assert card.is_visible() and page.locator("#arm-write").is_enabled()
    # a width at which the page leaves the sheet: the server's one line, nothing runs
    page.locator("#arm-width").fill("900")
    page.locator("#arm-write").click()
    error = page.locator("#arm-error.error")
    error.wait_for()
    assert "does not fit the sheet at a width of 900 mm" in error.inner_text()
    assert page.locator("#arm-job").is_hidden()
    # every status line the job shows, to see it name the characters
    page.evaluate(
        """() => {
          window.armStatus = [];
          new MutationObserver(() => window.armStatus.push(
            document.getElementById('arm-status').textContent))
            .observe(document.getElementById('arm-status'), { childList: true });
        }"""
    )
    page.locator("#arm-width").fill("60")
    page.locator("#arm-video").uncheck()  # the video would take longer than the writing
    page.locator("#arm-write").click()
    job = page.locator("#arm-job")
    job.wait_for()
    assert error.is_hidden()
    page.locator('#arm-job[data-status="done"], #arm-job[data-status="failed"]').wait_for(
        timeout=90_000
    )
    assert job.get_attribute("data-status") == "done", page.locator("#arm-error").inner_text()
    page.wait_for_function("() => document.getElementById('arm-paper').naturalWidth > 1000")
    named = [t for t in page.evaluate("window.armStatus") if " of 3 " in t]
    assert named and all(t.startswith("The arm is writing character ") for t in named), named
    href = page.locator("#arm-paper-link").get_attribute("href")
    assert (
        href.endswith("/paper.png")
        and page.locator("#arm-paper-open").get_attribute("target") == "_blank"
    )
    totals = page.locator("#arm-totals").inner_text()
    assert totals.startswith("3 of 3 characters written on 60.0") and "inked" in totals
    assert page.locator("#arm-table tbody tr").count() == 3
    assert page.locator("#arm-csv").get_attribute("download") == "line_page_characters.csv"
    assert page.locator("#arm-animation-figure").is_hidden()  # no video asked for
    page.locator("#arm-paper").scroll_into_view_if_needed()
    page.screenshot(path=str(shots / "page-robot.png"), full_page=True)
    # reading the photo again (a new page id) leaves nothing of the run behind
    page.locator("#photo-file").set_input_files(str(photo))
    page.locator("#arm-result").wait_for(state="hidden")
    page.locator('#page-card[data-characters="3"]').wait_for()
    assert (
        page.locator("#arm-job").is_hidden()
        and page.locator("#arm-paper").get_attribute("src") is None
    )
    assert page.locator("#arm-table tbody tr").count() == 0


# -- Record --------------------------------------------------------------------------------


def test_record_two_strokes_over_an_mnist_image(page, server, shots):
    page.goto(server["url"] + "/record")
    recorder = page.locator("#recorder")
    page.locator('#recorder:not([data-index=""])').wait_for()
    n = int(recorder.get_attribute("data-index"))
    assert page.locator("#label").input_value() == str(LABELS[n])
    page.locator("#trace-image").evaluate("i => i.decode()")
    # a 7: the bar, then (pen lifted) the stem
    _strokes_on(page, "#trace", [[(0.25, 0.27), (0.75, 0.27)], [(0.72, 0.3), (0.5, 0.8)]])
    assert recorder.get_attribute("data-strokes") == "2"
    points = int(recorder.get_attribute("data-points"))
    page.screenshot(path=str(shots / "record-mid-trace.png"), full_page=True)
    page.locator("#save").click()
    page.locator("#record-message.notice").wait_for()
    assert "Saved" in page.locator("#record-message").inner_text()
    page.locator(f'#recorder[data-index="{n + 1}"]').wait_for()
    assert "1 recorded" in page.locator("#recorded-count").inner_text()

    path = server["data_dir"] / f"image_{n}.json"
    doc = json.loads(path.read_text())
    assert len(doc["Strokes"]) == 2
    rec = parse_recorded(doc, path.name)
    assert rec.image_index == n and rec.label == LABELS[n]
    assert len(rec.xy) == points
    first, last = doc["Strokes"][0]
    assert last - first + 1 + doc["Strokes"][1][1] - doc["Strokes"][1][0] + 1 == points
    # the bar at 27 % of the height, from 25 % to 75 % of the width (corner convention)
    bar = rec.xy[first : last + 1] - (-0.5)
    assert np.allclose(bar[:, 1], 0.27 * 28, atol=0.6)
    assert bar[:, 0].min() == pytest.approx(0.25 * 28, abs=0.6)
    assert bar[:, 0].max() == pytest.approx(0.75 * 28, abs=0.6)

    # the same image again: 409, then Replace
    page.locator("#index").fill(str(n))
    page.locator("#index").press("Enter")
    page.locator(f'#recorder[data-index="{n}"]').wait_for()
    page.locator("#recorded-badge").wait_for()
    _strokes_on(page, "#trace", [[(0.3, 0.3), (0.7, 0.7)]])
    page.locator("#save").click()
    page.locator("#record-message.error button", has_text="Replace").click()
    page.locator("#record-message.notice").wait_for()
    assert len(json.loads(path.read_text())["Strokes"]) == 1


def test_the_api_reference_page_renders_offline(page, server, shots):
    """/docs (FastAPI's Swagger UI) loads its scripts from the server, not a CDN: every
    request the page makes stays on the server (this machine's browser has no internet
    anyway), and the endpoints are listed."""
    requested = []
    page.on("request", lambda r: requested.append(r.url))
    page.goto(server["url"] + "/docs")
    page.get_by_text("/api/predict").first.wait_for()
    page.get_by_text("/api/recordings").first.wait_for()
    outside = [u for u in requested if not u.startswith(server["url"]) and u.startswith("http")]
    assert not outside, outside
    page.screenshot(path=str(shots / "api-docs.png"), full_page=False)


# -- the server's names and origins (issue 31) ---------------------------------------------


def _recordings(server) -> dict:
    return {p.name: p.read_bytes() for p in sorted(server["data_dir"].glob("*.json"))}


_REPLACE = """async (url) => {
  const body = JSON.stringify({image: 0, strokes: [[[3, 3, 0], [20, 20, 40]]], replace: true});
  const r = await fetch(url, {method: 'POST', headers: {'Content-Type': 'application/json'}, body});
  return [r.status, (await r.json()).detail];
}"""


def test_a_rebound_name_gets_400_for_the_page_and_its_requests(page, server):
    """DNS rebinding for real: Chromium resolves rebind.test to 127.0.0.1, as the
    attacker's DNS would once the page is loaded. The page is then of its own origin to
    the browser, so its script may call the API and read the answers; only the Host
    header shows which name it used."""
    before = _recordings(server)
    other = f"http://rebind.test:{server['port']}"
    response = page.goto(other + "/record")
    assert response.status == 400
    assert "is not a name of this server" in page.inner_text("body")
    models = page.evaluate("async () => (await fetch('/api/models')).status")
    status, detail = page.evaluate(_REPLACE, other + "/api/recordings")
    assert (models, status) == (400, 400)
    assert detail.startswith(f"Host: 'rebind.test:{server['port']}' is not a name"), detail
    assert _recordings(server) == before


def test_a_page_of_another_origin_cannot_write(page, server):
    """A page of another origin on this machine (http://localhost:PORT is a name the
    server answers to, but another origin than http://127.0.0.1:PORT) posts a recording
    the way a cross-site form would: no-cors, text/plain, so no preflight stops it. The
    server refuses it (403) by its Origin; the browser shows the page nothing."""
    page.goto(f"http://localhost:{server['port']}/record")
    before = _recordings(server)
    target = server["url"] + "/api/recordings"
    with page.expect_response(lambda r: r.url == target) as answer:
        page.evaluate(
            """(url) => fetch(url, {method: 'POST', mode: 'no-cors',
                 headers: {'Content-Type': 'text/plain'},
                 body: JSON.stringify({image: 0, strokes: [[[3, 3, 0], [20, 20, 40]]],
                                       replace: true})}).catch(() => null)""",
            target,
        )
    assert answer.value.status == 403
    assert _recordings(server) == before


def test_a_name_given_with_allowed_host_draws_and_predicts(page, server):
    page.goto(f"http://lan.test:{server['port']}/")
    _strokes_on(page, "#drawing", SEVEN)
    _predicted(page, 2)  # its POST carries Origin http://lan.test:PORT: the page's own
    assert page.locator("#draw-error").is_hidden()
