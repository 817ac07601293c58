"""A stroke model served by ``img2dmp serve`` (docs/WEB.md, "Stroke models"), through
FastAPI's TestClient.

- ``GET /api/models`` says it is a stroke model and how many strokes it can read;
- ``POST /api/predict`` of a drawn two-stroke character and of an uploaded image is the
  library's own :class:`~img2dmp.predict.StrokePrediction` of the same image: the whole
  path with the pen lifted between the strokes in both frames, each stroke's DMP, tau
  and presence, the stroke document ``img2dmp predict`` writes and the page document of
  its strokes;
- what is for one DMP (bending, ``dmp`` for the arm) is a one-line 422 naming what to do
  or the model; the arm writes the strokes' page document stroke by stroke, the pen
  lifted between them, as ``img2dmp write`` does;
- ``POST /api/predict_page`` reads a page stroke by stroke, as the library does, and the
  arm writes it, lifting the pen between the strokes;
- ``img2dmp serve``'s warm-up takes a stroke model.

Everything runs on the tiny stroke model of conftest's ``stroke_run`` (about 15 s).
"""

from __future__ import annotations

import base64
import csv
import io
import json
import warnings

import numpy as np
import pytest
from PIL import Image

pytest.importorskip("fastapi")
pytest.importorskip("httpx")
with warnings.catch_warnings():  # starlette's note that it prefers httpx2 to httpx
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from img2dmp import load_model
from img2dmp.nn.strokes import pen_spans
from img2dmp.robot import available
from img2dmp.robot.pagefile import check_page_document
from img2dmp.web import create_app
from img2dmp.web.models import load_models, warm_up
from img2dmp.web.strokes import render_strokes

#: A hook and a tick (the odd characters of test_omniglot's tree) drawn in a 320 x 320
#: canvas: [x, y, t_ms] points, two strokes.
HOOK_AND_TICK = [
    [[91.0, 76.0, 0.0], [91.0, 160.0, 80.0], [91.0, 244.0, 160.0], [160.0, 244.0, 230.0],
     [229.0, 244.0, 300.0]],
    [[183.0, 122.0, 700.0], [192.0, 134.0, 730.0], [201.0, 146.0, 760.0]],
]  # fmt: skip
CANVAS = [320, 320]
LOCAL = "http://127.0.0.1:8000"


@pytest.fixture(scope="module")
def client(stroke_run, tmp_path_factory):
    work = tmp_path_factory.mktemp("web-strokes")
    app = create_app([stroke_run], data_dir=work / "recordings", jobs_dir=work / "jobs")
    with TestClient(app, base_url=LOCAL) as c:
        yield c


@pytest.fixture(scope="module")
def drawn(client):
    """The answer of ``POST /api/predict`` for :data:`HOOK_AND_TICK`, 30 points a stroke."""
    r = client.post("/api/predict", json={"strokes": HOOK_AND_TICK, "canvas": CANVAS,
                                          "n_points": 30})  # fmt: skip
    assert r.status_code == 200, r.text
    return r.json()


def _one_line_error(r, status: int) -> str:
    assert r.status_code == status, (r.status_code, r.text)
    body = r.json()
    assert set(body) == {"detail"} and isinstance(body["detail"], str), body
    assert body["detail"] and "\n" not in body["detail"]
    return body["detail"]


def test_a_stroke_model_is_listed_as_one_with_its_slots(client, stroke_run):
    (m,) = client.get("/api/models").json()["models"]
    assert m["id"] == stroke_run.parent.name and m["path"] == str(stroke_run)
    assert m["kind"] == "strokes" and m["stroke_slots"] == 8 and m["n_hypotheses"] == 1


def test_a_drawn_character_is_the_librarys_strokes_with_the_pen_lifted_between(
    client, drawn, stroke_run
):
    a = drawn
    image = render_strokes([np.array(s) for s in HOOK_AND_TICK], (320, 320))
    pred = load_model(stroke_run).predict(image, n_points=30)
    assert a["kind"] == "strokes" and a["n_strokes"] == pred.n_strokes >= 2
    (h,) = a["hypotheses"]
    assert h["rank"] == 1 and h["probability"] == 1.0
    np.testing.assert_allclose(h["t"], pred.times, atol=1e-6)
    np.testing.assert_allclose(h["tau_s"], pred.times[-1], atol=1e-6)
    np.testing.assert_allclose(h["model"], pred.path_model[0, :, :2], atol=1e-5)
    np.testing.assert_allclose(h["image"], pred.path_image[0, :, :2], atol=1e-5)
    assert h["pen"] == pred.path_model[0, :, 2].tolist()
    runs = pen_spans(np.column_stack([h["model"], h["pen"]]))
    assert len(runs) == a["n_strokes"]  # a pen-up gap between each two strokes
    assert [s["rows"] for s in h["strokes"]] == [list(r) for r in runs]
    for j, s in enumerate(h["strokes"]):
        assert s["index"] == j + 1 and len(range(*s["rows"])) + 1 == 30
        np.testing.assert_allclose(s["tau_s"], pred.strokes.tau[j], rtol=1e-9)
        np.testing.assert_allclose(s["presence"], pred.presence[j], atol=1e-6)
        np.testing.assert_allclose(s["params"]["w"], pred.strokes[j].to_dict()["w"], rtol=1e-9)
        np.testing.assert_allclose(s["params_image"]["g"], pred.strokes_image[j].g, rtol=1e-9)
    # the documents img2dmp predict writes and img2dmp write reads, unchanged
    assert a["dmp"] == json.loads(pred.to_json())
    assert a["strokes_page"] == json.loads(json.dumps(pred.to_page_document()))
    page = check_page_document(a["strokes_page"], "strokes_page")
    assert len(page.characters) == a["n_strokes"]
    assert a["csv"].splitlines()[0].endswith(",pen") and a["fit"] == pred.fit


def test_an_uploaded_image_is_predicted_in_its_own_pixels(client, omni_root, stroke_run):
    path = omni_root / "images_test" / "Alpha" / "character02" / "0102_20.png"
    url = "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode()
    r = client.post("/api/predict", json={"image": url})
    assert r.status_code == 200, r.text
    a = r.json()
    pred = load_model(stroke_run).predict(np.asarray(Image.open(io.BytesIO(path.read_bytes()))))
    assert a["image_size"] == [105, 105] and a["n_strokes"] == pred.n_strokes
    np.testing.assert_allclose(a["hypotheses"][0]["image"], pred.path_image[0, :, :2], atol=1e-5)
    assert len(a["hypotheses"][0]["t"]) == pred.n_strokes * 100 + (pred.n_strokes - 1) * 4


def test_what_is_for_one_dmp_is_refused_in_one_line(client, drawn):
    r = client.post("/api/bend", json={"dmp": drawn["dmp"], "goal": [20.0, 20.0]})
    assert _one_line_error(r, 422).endswith("not one DMP; bending is for one-DMP models")
    if available():
        r = client.post("/api/write", json={"dmp": drawn["dmp"]})
        assert "from strokes_page" in _one_line_error(r, 422)
        r = client.post("/api/write", json={"strokes_page": drawn["strokes_page"], "hypothesis": 2})
        assert _one_line_error(r, 422).startswith("hypothesis: a stroke model's character has one")
        r = client.post("/api/write", json={"strokes_page": {"format": "img2dmp-page"}})
        assert _one_line_error(r, 422).startswith("strokes_page")
    both = {"dmp": drawn["dmp"], "strokes_page": drawn["strokes_page"]}
    for body in (both, {}):
        r = client.post("/api/write", json=body)
        assert _one_line_error(r, 422) == "body: give exactly one of dmp and strokes_page"


def _hook_and_tick_page() -> bytes:
    """A PNG page with the hook and tick written twice, side by side."""
    one = render_strokes([np.asarray(a) for a in HOOK_AND_TICK], CANVAS)
    page = np.full((one.shape[0], 2 * one.shape[1] + 40), 255, np.uint8)
    page[:, : one.shape[1]] = one
    page[:, one.shape[1] + 40 :] = one
    buf = io.BytesIO()
    Image.fromarray(page).save(buf, format="PNG")
    return buf.getvalue()


def test_a_page_read_by_a_stroke_model_lists_its_strokes_as_the_library_does(client, stroke_run):
    raw = _hook_and_tick_page()
    r = client.post("/api/predict_page", content=raw, headers={"Content-Type": "image/png"},
                    params={"name": "hooks.png"})  # fmt: skip
    assert r.status_code == 200, r.text
    a = r.json()
    page = a["page"]
    ref = load_model(stroke_run).predict_page(np.asarray(Image.open(io.BytesIO(raw))))
    assert page["entries"] == "strokes" and page["n_characters"] == len(ref.characters) == 2
    entries = ref.to_document(dmps=False)["characters"]
    assert [(e["character"], e["stroke"]) for e in page["characters"]] == [
        (e["character"], e["stroke"]) for e in entries
    ]  # fmt: skip
    for e, f in zip(page["characters"], entries, strict=True):
        np.testing.assert_allclose(e["path_image_px"], f["path_image_px"], atol=1e-3)
        assert "dmp" not in e
    whole = client.get(a["document"]).json()  # every stroke's DMP, as predict --page writes
    checked = check_page_document(whole, "hooks_page.json")
    assert len(checked.characters) == len(entries)


@pytest.mark.skipif(not available(), reason="needs pybullet (img2dmp[robot])")
def test_the_arm_writes_each_stroke_and_lifts_the_pen_between(client, drawn):
    r = client.post("/api/write", json={"strokes_page": drawn["strokes_page"], "video": False})
    assert r.status_code == 202, r.text
    job = client.app.state.img2dmp.jobs.wait(r.json()["id"], 120)
    assert job["status"] == "done", job["error"]
    n = drawn["n_strokes"]
    assert job["kind"] == "strokes" and len(job["page"]["characters"]) == n
    assert job["summary"][0].startswith(f"character: {n} of {n} strokes written")
    assert "no ink between strokes" in job["summary"][0]
    assert job["page"]["totals"]["travel_contact_s"] == 0
    assert all(c["written"] for c in job["page"]["characters"])
    paper = client.get(job["files"]["paper"])
    assert paper.status_code == 200 and paper.headers["content-type"] == "image/png"


@pytest.mark.skipif(not available(), reason="needs pybullet (img2dmp[robot])")
def test_the_arm_writes_a_page_read_by_a_stroke_model_stroke_by_stroke(client):
    png = {"Content-Type": "image/png"}
    r = client.post("/api/predict_page", content=_hook_and_tick_page(), headers=png,
                    params={"name": "hooks.png"})  # fmt: skip
    assert r.status_code == 200, r.text
    a = r.json()
    n = len(a["page"]["characters"])
    r = client.post(f"/api/pages/{a['id']}/write", json={"width_mm": 80, "video": False})
    assert r.status_code == 202, r.text
    job = client.app.state.img2dmp.jobs.wait(r.json()["id"], 120)
    assert job["status"] == "done", job["error"]
    assert job["summary"][0].startswith(f"hooks_page: {n} of {n} strokes written"), job["summary"]
    assert "no ink between strokes" in job["summary"][0]
    assert any(", character 0: 1 of " in line for line in job["summary"])
    table = client.get(job["files"]["characters"])  # each stroke's character and place
    assert table.status_code == 200
    rows = [r for r in csv.DictReader(io.StringIO(table.text)) if r["index"] != "page"]
    assert [(int(r["character"]), int(r["stroke"])) for r in rows] == [
        (e["character"], e["stroke"]) for e in a["page"]["characters"]
    ]  # fmt: skip


def test_the_warm_up_of_img2dmp_serve_takes_a_stroke_model(stroke_run):
    (model,) = load_models([stroke_run]).values()
    warm_up(model)  # predicts a character and reads a page of two
    assert model.describe()["kind"] == "strokes"


def test_served_models_refine_unfamiliar_characters_as_asked(stroke_run):
    """``img2dmp serve --refine/--refine-unfamiliar`` reach every model it loads: a
    shipped one takes its card's steps, a run its own familiarity (img2dmp train's)."""
    card = load_models(["omniglot-strokes"])["omniglot-strokes"].predictor
    assert (card.refine_options.steps, card.refine_unfamiliar) == (60, 150)
    (run, both) = load_models([stroke_run, "omniglot-strokes"], 5, 7).values()
    assert (run.predictor.refine_options.steps, run.predictor.refine_unfamiliar) == (5, 7)
    assert (both.predictor.refine_options.steps, both.predictor.refine_unfamiliar) == (5, 7)
    (alone,) = load_models(["omniglot-strokes"], 5).values()  # --refine alone: all images
    assert alone.predictor.refine_unfamiliar is None
