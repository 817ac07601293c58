"""The HTTP API of ``img2dmp serve`` (docs/WEB.md), through FastAPI's TestClient.

- predictions of drawn strokes and uploaded images are the library's own
  (``Predictor.predict`` on the same image), for networks of one and two hypotheses;
- every bad request is a 4xx answer ``{"detail": one line}`` naming the field or value,
  never a 500, never a write outside the data directory;
- recordings round-trip through ``parse_recorded`` / ``load_recorded`` and make a data
  set with ``prepare_dataset``; concurrent writers all land, one image is written once;
- robot runs run in their own processes, in turn, and serve only their fixed files;
- ``img2dmp serve`` prints its URL and answers.

Everything runs on two tiny networks trained here for one epoch (a few seconds), a tiny
MNIST folder and a folder of PNGs.
"""

from __future__ import annotations

import base64
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
import warnings
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

pytest.importorskip("fastapi")
pytest.importorskip("httpx")
with warnings.catch_warnings():  # starlette's note that it prefers httpx2 to httpx
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from img2dmp import cli, load_model
from img2dmp.data.dmpfile import check_dmp_document
from img2dmp.data.mnist import write_idx
from img2dmp.data.recorded import load_recorded, parse_recorded
from img2dmp.data.render import render_paths
from img2dmp.robot import available
from img2dmp.web import create_app
from img2dmp.web.models import model_id
from img2dmp.web.strokes import render_strokes

#: A "7" drawn in a 280 x 280 canvas: [x, y, t_ms] points.
SEVEN = [[[70.0, 60.0, 0.0], [150.0, 58.0, 40.0], [215.0, 62.0, 80.0],
          [170.0, 150.0, 140.0], [130.0, 235.0, 200.0]]]  # fmt: skip
CANVAS = [280, 280]
#: Labels of the tiny MNIST's images.
LABELS = [7, 1, 4, 7, 0, 3, 9, 2, 5, 6, 8, 1]
#: Where the test clients send their requests: a name the server answers to (its Host).
LOCAL = "http://127.0.0.1:8000"


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("web")


@pytest.fixture(scope="module")
def runs(work, train_tiny_runs) -> dict[int, Path]:
    """Run directories of networks with one and with two hypotheses (one epoch each)."""
    return train_tiny_runs(work, lambda k: work / f"net{k}" / "run")


def _zigzag(k: int) -> np.ndarray:
    """A path ``[T, 2]`` inside 28 x 28 (centre convention), different for each ``k``."""
    rng = np.random.default_rng(k)
    corners = rng.uniform(6.0, 21.0, size=(3, 2))
    return np.concatenate([np.linspace(corners[i], corners[i + 1], 20) for i in range(2)])


@pytest.fixture(scope="module")
def mnist_dir(work) -> Path:
    """A tiny MNIST: 12 training images (light ink on black) and their labels."""
    d = work / "mnist"
    d.mkdir()
    paths = np.stack([_zigzag(k) for k in range(len(LABELS))])
    ink = render_paths(paths, 28, 2.0).numpy()
    write_idx(d / "train-images-idx3-ubyte.gz", np.round(255 * ink).astype(np.uint8))
    write_idx(d / "train-labels-idx1-ubyte", np.array(LABELS, np.uint8))
    return d


@pytest.fixture(scope="module")
def png_dir(work) -> Path:
    """Three images of different sizes and polarities (and a file that is no image)."""
    d = work / "pngs"
    d.mkdir()
    ink = render_paths(_zigzag(1)[None] * 1.5, (40, 42), 3.0).numpy()[0]
    Image.fromarray(np.round(255 * (1 - ink)).astype(np.uint8)).save(d / "b_dark_on_light.png")
    Image.fromarray(np.round(255 * ink).astype(np.uint8)).save(d / "a_light_on_dark.png")
    Image.fromarray(np.round(255 * (1 - ink)).astype(np.uint8)).convert("RGB").save(d / "c.jpg")
    (d / "notes.txt").write_text("not an image")
    return d


@pytest.fixture(scope="module")
def client(runs, mnist_dir, work):
    """One server of both networks and the tiny MNIST, for the tests that write nothing
    or only their own recordings."""
    app = create_app([runs[1], runs[2]], mnist=mnist_dir, data_dir=work / "recordings")
    with TestClient(app, base_url=LOCAL) as c:
        yield c


@pytest.fixture
def serve(tmp_path, runs):
    """``serve(**options)``: a TestClient of a fresh server writing into ``tmp_path``."""
    clients = []

    def make(**options):
        options.setdefault("data_dir", tmp_path / "recordings")
        options.setdefault("jobs_dir", tmp_path / "jobs")
        c = TestClient(create_app(options.pop("models", [runs[1]]), **options), base_url=LOCAL)
        clients.append(c.__enter__())
        return c

    yield make
    for c in clients:
        c.__exit__(None, None, None)


def _data_url(array: np.ndarray, fmt: str = "PNG") -> str:
    buf = io.BytesIO()
    Image.fromarray(array).save(buf, format=fmt)
    mime = "png" if fmt == "PNG" else "jpeg"
    return f"data:image/{mime};base64," + base64.b64encode(buf.getvalue()).decode()


def _decode_png(url: str) -> np.ndarray:
    assert url.startswith("data:image/png;base64,")
    return np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",", 1)[1]))))


def _one_line_error(r, status: int) -> str:
    assert r.status_code == status, (r.status_code, r.text)
    assert r.headers["content-type"].startswith("application/json")
    body = r.json()
    assert set(body) == {"detail"} and isinstance(body["detail"], str), body
    assert body["detail"] and "\n" not in body["detail"]
    return body["detail"]


# --- models and predictions ---------------------------------------------------------------


def test_model_ids_are_the_run_names_and_unique(runs, tmp_path):
    assert model_id("out/demo/run") == "demo" and model_id("runs/paper") == "paper"
    assert model_id("runs/x/run/checkpoints/best.safetensors") == "x"
    assert model_id("nets/mine.safetensors") == "mine"
    app = create_app([runs[1], runs[1], runs[2]], data_dir=tmp_path / "r")
    with TestClient(app, base_url=LOCAL) as c:
        answer = c.get("/api/models").json()
    assert answer["default"] == "net1"
    assert [m["id"] for m in answer["models"]] == ["net1", "net1-2", "net2"]
    assert [m["n_hypotheses"] for m in answer["models"]] == [1, 1, 2]
    assert {(m["kind"], m["stroke_slots"]) for m in answer["models"]} == {("dmp", None)}
    assert answer["models"][0]["image_size"] == [40, 40]
    assert answer["models"][0]["path"] == str(runs[1])


@pytest.mark.parametrize("k", [1, 2])
def test_predicting_strokes_is_the_library_prediction_of_the_drawn_image(client, runs, k):
    r = client.post("/api/predict", json={"strokes": SEVEN, "canvas": CANVAS,
                                          "model": f"net{k}", "n_points": 50})  # fmt: skip
    assert r.status_code == 200, r.text
    a = r.json()
    assert a["model"] == f"net{k}" and a["elapsed_ms"] > 0
    assert a["model_size"] == [40, 40] and a["image_size"] == [280, 280]
    image = render_strokes([np.array(s) for s in SEVEN], (280, 280))
    pred = load_model(runs[k]).predict(image, n_points=50, clean=False)  # a blank canvas
    assert len(a["hypotheses"]) == k
    for rank, h in enumerate(a["hypotheses"], start=1):
        assert h["rank"] == rank and len(h["t"]) == 50 and h["pen"] is None
        np.testing.assert_allclose(h["probability"], pred.probabilities[rank - 1], atol=1e-6)
        np.testing.assert_allclose(h["tau_s"], pred.params[rank - 1].tau, rtol=1e-6)
        np.testing.assert_allclose(h["model"], pred.path_model[rank - 1], atol=1e-5)
        np.testing.assert_allclose(h["image"], pred.path_image[rank - 1], atol=1e-5)
    assert [h["probability"] for h in a["hypotheses"]] == sorted(
        (h["probability"] for h in a["hypotheses"]), reverse=True
    )
    doc = check_dmp_document(a["dmp"], "answer")  # the one DMP document, as predict writes it
    assert len(doc.hypotheses) == k and doc.image_size == (40, 40)
    assert doc.image_frame.image_size == (280, 280)
    assert a["csv"].splitlines()[0].startswith("rank,probability,t_s,x_model_px")
    assert len(a["csv"].splitlines()) == 1 + 50 * k
    shown = _decode_png(a["input_image"])  # the model's input, dark ink on white
    np.testing.assert_allclose(shown / 255.0, 1.0 - pred.image, atol=1 / 255 + 1e-6)


def test_a_drawing_is_read_as_drawn_without_the_paper_cleaning_of_photos(client, runs):
    """The canvas is blank: every stroke drawn is ink, also one that runs to its edge,
    which the cleaning meant for photos takes for the sheet's edge and removes."""
    hook = [[[160, 177, 0], [128, 215, 20], [162, 235, 40], [168, 227, 60], [205, 275, 80],
             [250, 275, 100], [259, 275, 120]],
            [[140, 156, 200], [108, 166, 220], [118, 184, 240], [89, 167, 260], [78, 138, 280],
             [121, 126, 300], [130, 119, 320], [169, 152, 340]]]  # fmt: skip
    image = render_strokes([np.array(s) for s in hook], (280, 280))
    model = load_model(runs[1])
    drawn, cleaned = model.predict(image, clean=False), model.predict(image)
    assert np.abs(drawn.image - cleaned.image).max() > 0.5  # the cleaning lost a stroke
    assert drawn.frame.image_to_model[1, 2] != cleaned.frame.image_to_model[1, 2]
    r = client.post("/api/predict", json={"strokes": hook, "canvas": CANVAS, "model": "net1"})
    assert r.status_code == 200, r.text
    shown = _decode_png(r.json()["input_image"])
    np.testing.assert_allclose(shown / 255.0, 1.0 - drawn.image, atol=1 / 255 + 1e-6)


@pytest.mark.parametrize("fmt", ["PNG", "JPEG"])
def test_predicting_an_uploaded_image_is_the_library_prediction(client, runs, fmt):
    image = render_strokes([np.array(s) for s in SEVEN], (280, 280))[20:250, 30:240]
    url = _data_url(image, fmt)
    r = client.post("/api/predict", json={"image": url, "model": "net2"})
    assert r.status_code == 200, r.text
    a = r.json()
    decoded = np.asarray(Image.open(io.BytesIO(base64.b64decode(url.split(",")[1]))))
    pred = load_model(runs[2]).predict(decoded)
    assert a["image_size"] == [230, 210] and len(a["hypotheses"][0]["t"]) == 100
    np.testing.assert_allclose(a["hypotheses"][0]["image"], pred.path_image[0], atol=1e-5)


def test_an_uploaded_phone_photo_is_predicted_upright_in_the_frame_the_browser_shows(client, runs):
    upright = render_strokes([np.array(s) for s in SEVEN], (280, 280))[20:250, 30:240]
    exif = Image.Exif()
    exif[0x0112] = 6  # the browser turns the raster 90 degrees clockwise to show it
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(np.rot90(upright, 1))).save(buf, "JPEG", exif=exif)
    url = "data:image/jpeg;base64," + base64.b64encode(buf.getvalue()).decode()
    r = client.post("/api/predict", json={"image": url, "model": "net2"})
    assert r.status_code == 200, r.text
    a = r.json()
    want = client.post("/api/predict", json={"image": _data_url(upright, "JPEG"), "model": "net2"})
    assert a["image_size"] == [230, 210]
    got, ref = (
        np.array(a["hypotheses"][0]["image"]),
        np.array(want.json()["hypotheses"][0]["image"]),
    )
    assert np.abs(got - ref).max() < 1.0  # pixels of the upright image; JPEG noise differs


def test_strokes_are_drawn_with_a_round_pen_of_a_fourteenth_of_the_canvas():
    dot = render_strokes([np.array([[100.0, 50.0, 0.0]])], (280, 140))  # W = 280: pen 20
    assert dot.shape == (140, 280) and dot.dtype == np.uint8
    rows, cols = np.nonzero(dot < 128)
    assert abs(rows.mean() - 50) < 0.6 and abs(cols.mean() - 100) < 0.6
    assert 18 <= np.ptp(cols) + 1 <= 22 and 18 <= np.ptp(rows) + 1 <= 22
    line = render_strokes([np.array([[20.0, 70.0, 0.0], [260.0, 70.0, 9.0]])], (280, 140))
    column = line[:, 140] < 128
    assert 19 <= column.sum() <= 21 and column[70]
    assert line[70, 11] < 128 and line[70, 269] < 128  # round ends reach r = 10 past the ends
    assert (line[:40] == 255).all()  # white paper


def test_no_model_means_409_for_predictions_but_the_rest_works(tmp_path, mnist_dir):
    app = create_app([], mnist=mnist_dir, data_dir=tmp_path / "r")
    with TestClient(app, base_url=LOCAL) as c:
        assert c.get("/api/models").json() == {"default": None, "models": []}
        detail = _one_line_error(c.post("/api/predict", json={"strokes": SEVEN,
                                                              "canvas": CANVAS}), 409)  # fmt: skip
        assert "--model" in detail
        assert c.get("/api/images").json()["count"] == len(LABELS)


# --- bad requests: one line, 4xx ---------------------------------------------------------

_BOMB = np.zeros((6000, 6000), np.uint8)  # 36 megapixels, a few kB as PNG
_POINT = [10.0, 10.0, 0.0]


def _predict(**body):
    return ("post", "/api/predict", {"strokes": SEVEN, "canvas": CANVAS} | body)


def _record(**body):
    return ("post", "/api/recordings", {"image": 0, "strokes": [[_POINT, [12.0, 14.0, 20.0]]]}
            | body)  # fmt: skip


BAD_REQUESTS = {
    "empty strokes": (_predict(strokes=[]), 422, "strokes"),
    "stroke without points": (_predict(strokes=[[]]), 422, "strokes[0]"),
    "too many points": (
        _predict(strokes=[[[5.0, 5.0, float(i)] for i in range(20_001)]]),
        422,
        "strokes",
    ),  # fmt: skip
    "coordinate is a string": (_predict(strokes=[[["10", 10, 0]]]), 422, "strokes[0][0][0]"),
    "coordinate is a boolean": (_predict(strokes=[[[10, True, 0]]]), 422, "strokes[0][0][1]"),
    "point of two numbers": (_predict(strokes=[[[10, 10]]]), 422, "strokes[0][0]"),
    "point far outside": (_predict(strokes=[[[1e9, 10, 0]]]), 422, "strokes[0][0]"),
    "no canvas": (_predict(canvas=None), 422, "canvas"),
    "canvas of zero": (_predict(canvas=[0, 280]), 422, "canvas"),
    "canvas too large": (_predict(canvas=[100_000, 280]), 422, "canvas"),
    "canvas of three numbers": (_predict(canvas=[280, 280, 3]), 422, "canvas"),
    "strokes and image": (_predict(image="data:image/png;base64,AAAA"), 422, "exactly one"),
    "neither strokes nor image": (("post", "/api/predict", {"n_points": 10}), 422, "exactly one"),
    "unknown model": (_predict(model="nope"), 422, "model: no model 'nope'"),
    "model id not a string": (_predict(model=3), 422, "model"),
    "n_points too small": (_predict(n_points=1), 422, "n_points"),
    "n_points too large": (_predict(n_points=1001), 422, "n_points"),
    "n_points a string": (_predict(n_points="100"), 422, "n_points"),
    "n_points a fraction": (_predict(n_points=5.5), 422, "n_points"),
    "blank drawing": (_predict(strokes=[[[-200, -200, 0]]]), 422, "no ink"),
    "not an image URL": (
        ("post", "/api/predict", {"image": "data:text/plain;base64,aGk="}),
        422,
        "image",
    ),  # fmt: skip
    "bad base64": (
        ("post", "/api/predict", {"image": "data:image/png;base64,@@@"}),
        422,
        "image: the base64",
    ),  # fmt: skip
    "base64 of no image": (
        ("post", "/api/predict", {"image": "data:image/png;base64,aGVsbG8="}),
        422,
        "image: cannot be decoded",
    ),  # fmt: skip
    "decompression bomb": (
        ("post", "/api/predict", {"image": _data_url(_BOMB)}),
        422,
        "6000 x 6000 pixels",
    ),  # fmt: skip
    "body is a list": (("post", "/api/predict", [1, 2]), 422, "body"),
    "recording of image -1": (_record(image=-1), 422, "image"),
    "recording beyond the images": (_record(image=10**6), 422, "image: no image 1000000"),
    "recording of image '../x'": (_record(image="../x"), 422, "image"),
    "recording of image 1.0": (_record(image=1.0), 422, "image"),
    "label 10": (_record(label=10), 422, "label"),
    "label -1": (_record(label=-1), 422, "label"),
    "label true": (_record(label=True), 422, "label"),
    "label disagreeing with MNIST": (_record(label=3), 422, "disagrees with MNIST's label 7"),
    "recording without strokes": (_record(strokes=[]), 422, "strokes"),
    "recording of one point": (_record(strokes=[[_POINT]]), 422, "at least 2 points"),
    "time going back": (
        _record(strokes=[[_POINT, [11, 11, 30]], [[12, 12, 20]]]),
        422,
        "strokes[1][0]: t_ms 20",
    ),  # fmt: skip
    "recording point outside": (
        _record(strokes=[[_POINT, [60.0, 10.0, 9.0]]]),
        422,
        "strokes[0][1]",
    ),  # fmt: skip
    "replace not a boolean": (_record(replace="yes"), 422, "replace"),
    "image index not a number": (("get", "/api/images/x", None), 422, "n:"),
    "image index out of range": (("get", "/api/images/12", None), 404, "no image 12"),
    "negative image index": (("get", "/api/images/-1", None), 404, "no image -1"),
    "meta out of range": (("get", "/api/images/99/meta", None), 404, "no image 99"),
    "unknown job": (("get", "/api/jobs/0123456789abcdef", None), 404, "no job"),
    "job id leaving the folder": (("get", "/api/jobs/..%2F..%2Fetc", None), 404, ""),
    "file of an unknown job": (("get", "/api/jobs/nope/files/paper.png", None), 404, "no job"),
    "write: dmp not an object": (("post", "/api/write", {"dmp": [1]}), 422, "dmp"),
    "write: dmp without params": (
        ("post", "/api/write", {"dmp": {"image_size": [40, 40]}}),
        422,
        "dmp",
    ),  # fmt: skip
    "write: hypothesis 0": (
        ("post", "/api/write", {"dmp": {}, "hypothesis": 0}),
        422,
        "hypothesis",
    ),  # fmt: skip
    "write: video not a boolean": (("post", "/api/write", {"dmp": {}, "video": 1}), 422, "video"),
}


@pytest.mark.parametrize("case", list(BAD_REQUESTS), ids=list(BAD_REQUESTS))
def test_bad_requests_get_one_line_naming_the_field(client, case):
    (method, url, body), status, needle = BAD_REQUESTS[case]
    if body is not None and "canvas" in body and body["canvas"] is None:
        body = {k: v for k, v in body.items() if k != "canvas"}
    r = client.request(method, url, json=body) if body is not None else client.request(method, url)
    assert needle in _one_line_error(r, status)


RAW_BODIES = {
    "NaN literal": (b'{"strokes": [[[NaN, 1, 0]]], "canvas": [280, 280]}', 400, "NaN"),
    "Infinity literal": (
        b'{"strokes": [[[1, 1, 0]]], "canvas": [Infinity, 280]}',
        400,
        "Infinity",
    ),  # fmt: skip
    "-Infinity in a DMP": (b'{"dmp": {"params": {"tau": -Infinity}}}', 400, "-Infinity"),
    "1e999 (infinity as a double)": (
        b'{"strokes": [[[1, 1, 0]]], "canvas": [1e999, 280]}',
        400,
        "body: canvas[0] is a number too large for a double (it reads as infinity)",
    ),  # fmt: skip
    "-1e400 in a DMP": (b'{"dmp": {"params": {"tau": -1e400}}}', 400, "dmp.params.tau"),
    "malformed JSON": (b'{"strokes": [[[1, 1, 0]]], "canvas": [280, 280]', 400, "not valid JSON"),
    "not UTF-8": (b'{"image": "\xff\xfe"}', 400, "body"),
    "nested too deeply": (b"[" * 100_000 + b"]" * 100_000, 400, "body"),
    "empty body": (b"", 422, "body"),
}


@pytest.mark.parametrize("case", list(RAW_BODIES), ids=list(RAW_BODIES))
def test_bodies_that_are_not_strict_json_are_refused(client, case):
    raw, status, needle = RAW_BODIES[case]
    url = "/api/write" if b"dmp" in raw else "/api/predict"
    r = client.post(url, content=raw, headers={"content-type": "application/json"})
    assert needle in _one_line_error(r, status)


def test_a_body_of_another_type_is_refused(client):
    """A PNG posted as image/png got 422 "body: Input should be a valid dictionary ...
    got b'\\x89PNG..."; /api/predict_page answered the same mistake with 415."""
    r = client.post("/api/predict", content=b"strokes", headers={"content-type": "text/plain"})
    assert _one_line_error(r, 415) == (
        "Content-Type: /api/predict takes a JSON body, sent as application/json, got 'text/plain'"
    )
    png = {"content-type": "image/png"}
    raw = base64.b64decode(_data_url(np.zeros((8, 8), np.uint8)).split(",", 1)[1])
    detail = _one_line_error(client.post("/api/predict", content=raw, headers=png), 415)
    assert "as \"image\": a data:image/png;base64,... URL), got 'image/png'" in detail, detail
    for url in ("/api/bend", "/api/write", "/api/recordings", "/api/pages/x/write"):
        detail = _one_line_error(client.post(url, content=raw, headers=png), 415)
        assert detail.startswith(f"Content-Type: {url} takes a JSON body"), detail
        assert "POST /api/predict_page" in detail, detail
    r = client.post("/api/predict", content=b'{"strokes": []}')  # no Content-Type
    assert _one_line_error(r, 415).endswith("got none")
    body = json.dumps({"strokes": SEVEN, "canvas": CANVAS})
    for kind in ("application/json; charset=utf-8", "application/merge-patch+json"):
        r = client.post("/api/predict", content=body, headers={"content-type": kind})
        assert r.status_code == 200, r.text


def test_bodies_above_the_limit_get_413_before_they_are_read(serve):
    c = serve(max_upload_mb=0.01)  # 10,485 bytes
    big = {"strokes": [[[5.0, 5.0, float(i)] for i in range(2000)]], "canvas": CANVAS}
    detail = _one_line_error(c.post("/api/predict", json=big), 413)
    assert "0.01 MB" in detail and "--max-upload-mb" in detail and "Content-Length" in detail

    def chunks():  # no Content-Length: counted while read
        yield b'{"strokes": [[' + b"[5, 5, 0], " * 1000
        yield b"[5, 5, 0], " * 1000
        yield b"[5, 5, 0]]]}"

    r = c.post("/api/predict", content=chunks(), headers={"content-type": "application/json"})
    assert "bytes read" in _one_line_error(r, 413)
    assert c.post("/api/predict", json={"strokes": SEVEN, "canvas": CANVAS}).status_code == 200


# --- images and recordings -----------------------------------------------------------------


def test_mnist_images_are_served_dark_on_white_with_their_labels(client, mnist_dir):
    from img2dmp.data.mnist import load_mnist

    images, labels = load_mnist(mnist_dir, "train")
    summary = client.get("/api/images").json()
    assert summary["source"] == "mnist" and summary["count"] == len(LABELS)
    meta = client.get("/api/images/3/meta").json()
    assert meta == {"index": 3, "label": 7, "width": 28, "height": 28,
                    "name": "train-images-idx3-ubyte[3]", "recorded": meta["recorded"]}  # fmt: skip
    r = client.get("/api/images/3")
    assert r.status_code == 200 and r.headers["content-type"] == "image/png"
    png = np.asarray(Image.open(io.BytesIO(r.content)))
    np.testing.assert_allclose(png / 255.0, 1.0 - images[3], atol=1 / 255 + 1e-6)


def test_folder_images_are_sorted_unlabelled_and_dark_on_white(serve, png_dir):
    c = serve(images=png_dir)
    assert c.get("/api/images").json() == {"source": "folder", "count": 3, "recorded": 0,
                                           "next": 0}  # fmt: skip
    names = [c.get(f"/api/images/{n}/meta").json()["name"] for n in range(3)]
    assert names == ["a_light_on_dark.png", "b_dark_on_light.png", "c.jpg"]
    meta = c.get("/api/images/0/meta").json()
    assert meta["label"] is None and (meta["height"], meta["width"]) == (40, 42)
    for n in range(3):
        png = np.asarray(Image.open(io.BytesIO(c.get(f"/api/images/{n}").content)))
        assert png.shape == (40, 42) and np.median(png) > 200  # white paper, whatever the file


def test_no_image_source_answers_409(serve):
    c = serve()
    assert c.get("/api/images").json() == {"source": None, "count": 0, "recorded": 0,
                                           "next": None}  # fmt: skip
    for r in (c.get("/api/images/0"), c.get("/api/images/0/meta"),
              c.post("/api/recordings", json=_record()[2])):  # fmt: skip
        assert "--mnist" in _one_line_error(r, 409)


def _strokes_of(k: int, dt_ms: float = 16.0) -> list:
    """Image ``k``'s path in the corner convention as two strokes of [x, y, t_ms]."""
    xy = _zigzag(k) + 0.5
    t = 1000.0 + dt_ms * np.arange(len(xy))
    t[25:] += 300.0  # the pen is up between the strokes
    pts = np.column_stack([xy, t]).round(3).tolist()
    return [pts[:25], pts[25:]]


def test_a_recording_is_written_in_the_shared_format_and_read_back(serve, mnist_dir):
    c = serve(mnist=mnist_dir)
    strokes = _strokes_of(3)
    strokes[0][5][2] = strokes[0][4][2]  # two points in one millisecond
    r = c.post("/api/recordings", json={"image": 3, "strokes": strokes})
    assert r.status_code == 201, r.text
    assert r.json() == {"file": "image_3.json", "points": 40, "strokes": 2, "recorded": 1,
                        "next": 0}  # fmt: skip
    data_dir = Path(c.app.state.img2dmp.recordings.data_dir)
    raw = (data_dir / "image_3.json").read_bytes()
    doc = json.loads(raw)
    assert doc["Image number"] == 3 and doc["Image shape"] == 7
    assert doc["Strokes"] == [[0, 24], [25, 39]] and doc["Recorded with"].startswith("img2dmp ")
    assert doc["Recorded at"].endswith("Z") and "Image file" not in doc
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no time repairs: the times increase
        rec = parse_recorded(raw, "image_3.json")
    sent = np.concatenate([np.array(s) for s in strokes])
    np.testing.assert_allclose(rec.xy, sent[:, :2] - 0.5, atol=1e-9)  # corner -> centre
    assert rec.t_s[0] == 0 and (np.diff(rec.t_s) > 0).all()
    np.testing.assert_allclose(rec.t_s[-1], (sent[-1, 2] - sent[0, 2]) / 1000.0)
    assert [r.image_index for r in load_recorded(data_dir)] == [3]
    assert c.get("/api/images/3/meta").json()["recorded"] is True


def test_a_recorded_image_is_replaced_only_when_asked(serve, mnist_dir):
    c = serve(mnist=mnist_dir)
    first = {"image": 5, "strokes": _strokes_of(5)}
    assert c.post("/api/recordings", json=first).status_code == 201
    again = {"image": 5, "strokes": _strokes_of(6)}
    assert "already recorded" in _one_line_error(c.post("/api/recordings", json=again), 409)
    path = Path(c.app.state.img2dmp.recordings.data_dir) / "image_5.json"
    assert parse_recorded(path.read_bytes(), path.name).xy[0, 0] == _strokes_of(5)[0][0][0] - 0.5
    r = c.post("/api/recordings", json=again | {"replace": True})
    assert r.status_code == 201
    assert parse_recorded(path.read_bytes(), path.name).xy[0, 0] == _strokes_of(6)[0][0][0] - 0.5


def test_a_folder_recording_needs_a_label_and_names_its_file(serve, png_dir):
    c = serve(images=png_dir)
    body = {"image": 1, "strokes": _strokes_of(1)}
    assert "label: required" in _one_line_error(c.post("/api/recordings", json=body), 422)
    assert c.post("/api/recordings", json=body | {"label": 4}).status_code == 201
    data_dir = Path(c.app.state.img2dmp.recordings.data_dir)
    doc = json.loads((data_dir / "image_1.json").read_text())
    assert doc["Image shape"] == 4 and doc["Image file"] == "b_dark_on_light.png"
    assert doc["Image size"] == [40, 42]
    assert parse_recorded(json.dumps(doc), "image_1.json").label == 4


def test_recordings_of_a_folder_import_as_a_data_set(serve, png_dir):
    from img2dmp.data.importer import ImportOptions, import_dataset

    c = serve(images=png_dir)
    xy = _zigzag(1) * 1.5 + 0.5  # the drawn zigzag, in the corner convention
    t = 1000.0 + 16.0 * np.arange(len(xy))
    t[25:] += 300.0  # two strokes
    pts = np.column_stack([xy, t]).round(3).tolist()
    for n in range(3):
        body = {"image": n, "strokes": [pts[:25], pts[25:]], "label": 4}
        assert c.post("/api/recordings", json=body).status_code == 201
    data_dir = Path(c.app.state.img2dmp.recordings.data_dir)
    data = import_dataset(data_dir, ImportOptions(seed=0), images=png_dir)
    assert len(data) == 3 and set(data.labels.tolist()) == {4}
    assert data.trajectories.shape[-1] == 3  # x, y and the pen of the two strokes
    assert data.meta["fit"]["mean_error_px"] < 0.5


def test_concurrent_recordings_all_land_and_one_image_is_written_once(serve, mnist_dir):
    c = serve(mnist=mnist_dir)
    data_dir = Path(c.app.state.img2dmp.recordings.data_dir)
    answers = {}
    start = threading.Barrier(len(LABELS))

    def post(n: int, k: int) -> None:
        start.wait()
        answers[(n, k)] = c.post("/api/recordings", json={"image": n, "strokes": _strokes_of(k)})

    threads = [threading.Thread(target=post, args=(n, n)) for n in range(len(LABELS))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(r.status_code for r in answers.values()) == [201] * len(LABELS)
    assert len(load_recorded(data_dir)) == len(LABELS)
    assert c.get("/api/images").json()["next"] is None
    answers.clear()
    start = threading.Barrier(2)
    os.remove(data_dir / "image_2.json")
    threads = [threading.Thread(target=post, args=(2, k)) for k in (2, 9)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(r.status_code for r in answers.values()) == [201, 409]
    parse_recorded((data_dir / "image_2.json").read_bytes(), "image_2.json")
    assert sorted(p.name for p in data_dir.iterdir()) == sorted(
        [".lock"] + [f"image_{n}.json" for n in range(len(LABELS))]
    )  # no temporary left behind


def test_sixteen_writers_at_once(serve, tmp_path):
    d = tmp_path / "mnist16"
    d.mkdir()
    paths = np.stack([_zigzag(k) for k in range(16)])
    write_idx(d / "train-images-idx3-ubyte", np.round(255 * render_paths(paths, 28, 2.0).numpy()))
    write_idx(d / "train-labels-idx1-ubyte", np.arange(16, dtype=np.uint8) % 10)
    c = serve(mnist=d)
    with_barrier = threading.Barrier(16)
    codes = []

    def post(n: int) -> None:
        with_barrier.wait()
        codes.append(c.post("/api/recordings", json={"image": n, "strokes": _strokes_of(n)}))

    threads = [threading.Thread(target=post, args=(n,)) for n in range(16)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert [r.status_code for r in codes] == [201] * 16
    assert sorted(r.json()["recorded"] for r in codes)[-1] == 16
    recs = load_recorded(Path(c.app.state.img2dmp.recordings.data_dir))
    assert [r.image_index for r in recs] == list(range(16))


def test_two_servers_on_one_data_directory_write_an_image_once(tmp_path, mnist_dir):
    apps = [create_app([], mnist=mnist_dir, data_dir=tmp_path / "shared") for _ in range(2)]
    answers = []
    for _ in range(5):  # each round: both servers at once, for a fresh image
        n = len(answers) // 2
        start = threading.Barrier(2)

        def post(c, k, n=n, start=start):
            start.wait()
            answers.append(c.post("/api/recordings", json={"image": n, "strokes": _strokes_of(k)}))

        with TestClient(apps[0], base_url=LOCAL) as a, TestClient(apps[1], base_url=LOCAL) as b:
            threads = [threading.Thread(target=post, args=(c, k)) for c, k in ((a, 1), (b, 2))]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
        assert sorted(r.status_code for r in answers[-2:]) == [201, 409]
    assert [r.image_index for r in load_recorded(tmp_path / "shared")] == list(range(5))


def test_recordings_made_here_prepare_into_a_data_set(serve, mnist_dir):
    from img2dmp.data.prepare import PrepareOptions, prepare_dataset

    c = serve(mnist=mnist_dir)
    for n in range(6):
        assert (
            c.post("/api/recordings", json={"image": n, "strokes": _strokes_of(n)}).status_code
            == 201
        )
    data_dir = Path(c.app.state.img2dmp.recordings.data_dir)
    data = prepare_dataset(
        PrepareOptions(n_times=50), mnist_dir=mnist_dir, recorded_path=data_dir, progress=False
    )
    assert sorted(data.labels.tolist()) == sorted(LABELS[:6])
    assert data.images.shape == (6, 28, 28) and data.trajectories.shape == (6, 50, 2)
    assert float(np.max(data.fit_error_px)) < 1.0


# --- the robot ---------------------------------------------------------------------------


def test_write_without_the_robot_answers_503(client, monkeypatch):
    import img2dmp.robot

    monkeypatch.setattr(img2dmp.robot, "available", lambda: False)
    dmp = client.post("/api/predict", json={"strokes": SEVEN, "canvas": CANVAS}).json()["dmp"]
    assert "img2dmp[robot]" in _one_line_error(client.post("/api/write", json={"dmp": dmp}), 503)


def test_a_hypothesis_beyond_the_document_is_refused(client):
    dmp = client.post("/api/predict", json={"strokes": SEVEN, "canvas": CANVAS,
                                            "model": "net2"}).json()["dmp"]  # fmt: skip
    r = client.post("/api/write", json={"dmp": dmp, "hypothesis": 3})
    assert "rank in 1..2, got 3" in _one_line_error(r, 422)


@pytest.mark.skipif(not available(), reason="needs pybullet (img2dmp[robot])")
def test_robot_runs_wait_their_turn_and_serve_only_their_files(serve):
    c = serve(models=[], max_jobs=1)
    dmp = _seven_dmp()
    off_paper = json.loads(json.dumps(dmp))
    off_paper["params"]["y0"] = [5000.0, 5000.0]  # starts far off the paper
    first = c.post("/api/write", json={"dmp": dmp, "video": True})
    second = c.post("/api/write", json={"dmp": off_paper, "video": False})
    assert first.status_code == 202 and second.status_code == 202, second.text
    a, b = first.json(), second.json()
    assert a["status"] == b["status"] == "queued" and b["position"] in (1, 2)
    assert a["files"] == {"paper": None, "animation": None, "log": None}
    seen = set()
    end = time.monotonic() + 120
    while time.monotonic() < end:
        sa, sb = c.get(f"/api/jobs/{a['id']}").json(), c.get(f"/api/jobs/{b['id']}").json()
        seen.add((sa["status"], sb["status"]))
        if sb["status"] in ("done", "failed"):
            break
        time.sleep(0.05)
    # --max-jobs 1: the second started after the first ended (two GETs in a row are no
    # snapshot of both, so the times the server kept are compared).
    assert sb["started_at"] >= sa["ended_at"] >= sa["started_at"], (sa, sb)
    assert ("running", "queued") in seen
    assert sa["status"] == "done" and sa["progress"] == 1.0 and sa["position"] is None, sa
    assert sa["summary"][0].startswith("hypothesis 1: tracking error")
    assert sb["status"] == "failed" and "\n" not in sb["error"], sb
    assert sb["error"].startswith("the DMP path leaves the paper"), sb
    for key, mime in (("paper", "image/png"), ("animation", "image/gif"), ("log", "text/csv")):
        r = c.get(sa["files"][key])
        assert r.status_code == 200 and r.headers["content-type"].startswith(mime)
        assert len(r.content) > 100
    for name in ("dmp.json", "result.json", "job.log", "..%2Fdmp.json", "paper"):
        _one_line_error(c.get(f"/api/jobs/{a['id']}/files/{name}"), 404)
    _one_line_error(c.get(f"/api/jobs/{b['id']}/files/paper.png"), 404)


@pytest.mark.skipif(not available(), reason="needs pybullet (img2dmp[robot])")
def test_the_image_sent_with_a_dmp_is_under_its_path_in_the_paper_figure(serve):
    """The Draw page's run showed "no input image" though the page had it."""
    c = serve(models=[], max_jobs=2)
    ink = np.full((40, 40), 255, np.uint8)
    ink[8:32, 8:32] = 0  # a dark square behind the "7"
    runs = [c.post("/api/write", json={"dmp": _seven_dmp(), "video": False, **extra})
            for extra in ({"image": _data_url(ink)}, {})]  # fmt: skip
    assert [r.status_code for r in runs] == [202, 202], runs[0].text
    papers = []
    for r in runs:
        job = c.app.state.img2dmp.jobs.wait(r.json()["id"], 120)
        assert job["status"] == "done", job["error"]
        papers.append(np.asarray(Image.open(io.BytesIO(c.get(job["files"]["paper"]).content))))
    with_image, without = (p[..., :3].astype(float) for p in papers)
    assert with_image.shape == without.shape
    h, w = with_image.shape[:2]
    differs = np.abs(with_image - without).max(axis=2) > 60
    assert differs[: h // 2, : w // 2].mean() > 0.05  # the image panel: the square
    assert differs[:, w // 2 :].mean() < 0.01  # the paper and the measures: the same
    for body, detail in (
        ({"image": "data:image/png;base64,@@"}, "image: the base64"),
        ({"image": _data_url(np.zeros((1100, 20), np.uint8))}, "image: 20 x 1100 pixels"),
    ):
        r = c.post("/api/write", json={"dmp": _seven_dmp(), **body})
        assert _one_line_error(r, 422).startswith(detail)
    r = c.post("/api/write", json={"strokes_page": {}, "image": _data_url(ink)})
    assert _one_line_error(r, 422) == "image: goes with dmp, not with strokes_page"


@pytest.mark.skipif(not available(), reason="needs pybullet (img2dmp[robot])")
def test_the_arm_s_model_file_is_gone_once_loaded(tmp_path, monkeypatch):
    """A run ended by the server's stop left /tmp/img2dmp-robot-XXXX/iiwa_pen.urdf."""
    import tempfile

    from img2dmp.robot import WritingScene

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    scene = WritingScene()
    try:
        assert list(tmp_path.iterdir()) == []  # a process killed now leaves nothing
        picture = scene.render(64, 48)  # pybullet needs the file no longer
        assert picture.shape == (48, 64, 3) and picture.std() > 0
    finally:
        scene.close()


@pytest.mark.skipif(not available(), reason="needs pybullet (img2dmp[robot])")
def test_the_jobs_a_stop_ends_say_so_in_their_folders(tmp_path, monkeypatch):
    """... and a job beyond the waiting ones allowed (MAX_WAITING, here 1) is 429."""
    monkeypatch.setattr("img2dmp.web.jobs.MAX_WAITING", 1)
    app = create_app([], data_dir=tmp_path / "r", jobs_dir=tmp_path / "jobs")
    slow = {"dmp": _seven_dmp(), "video": False}
    slow["dmp"]["params"]["tau"] = 60.0  # 14,400 control steps: running when it stops
    with TestClient(app, base_url=LOCAL) as c:
        ids = [c.post("/api/write", json=slow).json()["id"]]
        end = time.monotonic() + 60
        while c.get(f"/api/jobs/{ids[0]}").json()["status"] == "queued":
            assert time.monotonic() < end
            time.sleep(0.05)
        ids.append(c.post("/api/write", json=slow).json()["id"])  # waits
        detail = _one_line_error(c.post("/api/write", json=slow), 429)
        assert detail == "1 robot runs are waiting already; try later"
    for job_id, was in zip(ids, ("running", "queued"), strict=True):
        d = tmp_path / "jobs" / job_id
        last = (d / "job.log").read_text().splitlines()[-1]
        assert last.startswith("img2dmp serve: interrupted: the server stopped"), last
        assert f"while the job was {was}" in last, last
        result = json.loads((d / "result.json").read_text())
        assert result == {"status": "failed", "error": "interrupted: the server stopped"}
        assert (d / "dmp.json").is_file()


def _seven_dmp() -> dict:
    """The DMP document of a "7" fitted in a 40 x 40 image (it stays on the paper)."""
    from img2dmp.data.dmpfile import dmp_document
    from img2dmp.dmp import DMPConfig, fit_dmp

    xy = np.concatenate([np.linspace([10.0, 10.0], [30.0, 10.0], 50),
                         np.linspace([30.0, 10.0], [18.0, 32.0], 50)])  # fmt: skip
    config = DMPConfig(n_kernels=10)
    params = fit_dmp(np.linspace(0.0, 1.5, len(xy)), xy, config).params
    return dmp_document(params, config, (40, 40))


# --- static pages and the command ---------------------------------------------------------


def test_pages_and_static_files_are_served_and_nothing_else(serve, tmp_path):
    static = tmp_path / "static"
    static.mkdir()
    (static / "index.html").write_text("<title>draw</title>")
    (static / "record.html").write_text("<title>record</title>")
    (static / "app.css").write_text("body {}")
    (tmp_path / "secret.txt").write_text("no")
    c = serve(static_dir=static)
    assert c.get("/").text == "<title>draw</title>"
    assert c.get("/").headers["content-type"].startswith("text/html")
    assert c.get("/record").text == "<title>record</title>"
    assert c.get("/static/app.css").text == "body {}"
    for url in ("/static/../secret.txt", "/static/..%2Fsecret.txt", "/static/nope.js", "/nope"):
        assert c.get(url).status_code == 404, url
    assert c.get("/openapi.json").json()["info"]["title"] == "img2dmp"
    # The API reference pages load Swagger UI and ReDoc from the server, not a CDN.
    for url in ("/docs", "/redoc"):
        html = c.get(url).text
        assert "/openapi.json" in html and "cdn" not in html.lower(), html
        for asset in re.findall(r'(?:src|href)="(/[^"]+)"', html):
            assert c.get(asset).status_code == 200, asset


def test_serve_without_the_web_extra_is_one_error_line(monkeypatch, capsys):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "uvicorn" else real(name, *a)
    )
    assert cli.main(["serve", "--model", "x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "img2dmp serve: error: install img2dmp[web] (pip install -e '/path/to/img2dmp[web]')"
    ]


def test_serve_options_are_checked_while_read(capsys):
    assert cli.main(["serve", "--help"]) == 0
    out = capsys.readouterr().out
    for option in ("--model", "--mnist", "--images", "--data-dir", "--host", "--port",
                   "--max-jobs", "--max-upload-mb", "--jobs-dir", "--verbose"):  # fmt: skip
        assert option in out
    assert cli.main(["serve", "--max-jobs", "0"]) == 2
    assert cli.main(["serve", "--port", "70000"]) == 2
    assert cli.main(["serve", "--max-upload-mb", "-1"]) == 2
    assert cli.main(["serve", "--mnist", "a", "--images", "b"]) == 2
    assert "not allowed with argument" in capsys.readouterr().err


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["Ctrl+C", "SIGTERM"])
def test_serve_stops_cleanly_on_ctrl_c_and_on_sigterm(runs, tmp_path, stop):
    """SIGTERM (kill, a service manager) as Ctrl+C: a clean stop, exit 0, "stopped", and
    multiprocessing's temporary folder gone (a process killed by the signal left it)."""
    exe = Path(sys.executable).with_name("img2dmp")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "img2dmp"]
    cmd += ["serve", "--model", str(runs[1]), "--port", "0", "--jobs-dir", str(tmp_path / "j")]
    # A short TMPDIR of its own (under pytest's long paths multiprocessing's socket name
    # would pass the 108 bytes an AF_UNIX address may have).
    tmp = Path(tempfile.mkdtemp(prefix="img2dmp-t"))
    try:
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                text=True, env={**os.environ, "TMPDIR": str(tmp)})  # fmt: skip
        try:
            line = proc.stdout.readline()
        finally:
            proc.send_signal(stop)
            out, err = proc.communicate(timeout=60)
        assert line.startswith("img2dmp serve: listening on"), err
        assert proc.returncode == 0, err
        assert out.strip() == "img2dmp serve: stopped", out
        assert list(tmp.iterdir()) == []
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def test_serve_prints_its_url_and_answers_quietly(runs, tmp_path):
    exe = Path(sys.executable).with_name("img2dmp")
    cmd = [str(exe)] if exe.exists() else [sys.executable, "-m", "img2dmp"]
    cmd += ["serve", "--model", str(runs[2]), "--port", "0", "--data-dir", str(tmp_path / "r")]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        line = proc.stdout.readline()
        assert line.startswith("img2dmp serve: listening on http://127.0.0.1:"), line
        url = line.split("listening on ")[1].split()[0]
        with urllib.request.urlopen(url + "api/models", timeout=60) as r:
            assert json.load(r)["default"] == "net2"
        body = json.dumps({"strokes": SEVEN, "canvas": CANVAS}).encode()
        req = urllib.request.Request(
            url + "api/predict", body, {"content-type": "application/json"}
        )
        with urllib.request.urlopen(req, timeout=60) as r:
            assert len(json.load(r)["hypotheses"]) == 2
    finally:
        proc.send_signal(signal.SIGINT)  # Ctrl+C: a clean stop
        out, err = proc.communicate(timeout=30)
    assert proc.returncode == 0, err
    assert out.strip() == "img2dmp serve: stopped", out
    assert "GET /api/models" not in out + err  # no access log without --verbose
    assert not (tmp_path / "r").exists()  # no image source: no recording, no folder made


# --- issue 31: the server's names and origins, slow bodies, odd times, planted links -------

#: A page of another site whose name was made to resolve to 127.0.0.1 (DNS rebinding).
REBOUND = "rebind.example:8000"


def test_requests_for_another_name_are_refused_before_any_work(serve, mnist_dir, tmp_path):
    """DNS rebinding: the page read /api/models, ran predictions and replaced a recording
    (201). Now every request whose Host is not one of the server's names gets 400."""
    c = serve(mnist=mnist_dir)
    first = {"image": 2, "strokes": _strokes_of(2)}
    assert c.post("/api/recordings", json=first).status_code == 201
    recorded = tmp_path / "recordings" / "image_2.json"
    before = recorded.read_bytes()
    again = {"image": 2, "strokes": _strokes_of(5), "replace": True}
    for method, url, body in [("get", "/api/models", None), ("get", "/", None),
                              ("post", "/api/predict", {"strokes": SEVEN, "canvas": CANVAS}),
                              ("post", "/api/recordings", again),
                              ("post", "/api/write", {"dmp": _seven_dmp()})]:  # fmt: skip
        r = c.request(method, url, json=body, headers={"Host": REBOUND})
        detail = _one_line_error(r, 400)
        assert detail.startswith(f"Host: '{REBOUND}' is not a name of this server"), detail
        assert "--allowed-host" in detail
    assert recorded.read_bytes() == before and not any((tmp_path / "jobs").iterdir())
    for host in ("127.0.0.1:8000", "localhost", "LocalHost.:8000", "[::1]:8000", "127.0.0.1"):
        assert c.get("/api/models", headers={"Host": host}).status_code == 200, host
    for host in ("", "127.0.0.1.example", "localhost.example:8000", "[::2]:8000"):
        _one_line_error(c.get("/api/models", headers={"Host": host}), 400)


def test_an_allowed_host_is_answered(serve, mnist_dir):
    c = serve(mnist=mnist_dir, allowed_hosts=["lan.example"])
    lan = {"Host": "lan.example:8000", "Origin": "http://lan.example:8000"}
    assert c.get("/api/models", headers=lan).status_code == 200
    r = c.post("/api/recordings", json={"image": 1, "strokes": _strokes_of(1)}, headers=lan)
    assert r.status_code == 201, r.text
    _one_line_error(c.get("/api/models", headers={"Host": "other.example"}), 400)
    with pytest.raises(ValueError, match="--allowed-host must be a host name"):
        create_app([], allowed_hosts=["http://lan.example/"])


@pytest.mark.parametrize(
    "origin", ["http://evil.example", "null", "http://127.0.0.1:9999", "https://127.0.0.1:8000",
               "http://localhost:8000"],
)  # fmt: skip
def test_what_changes_something_comes_only_from_the_server_s_own_pages(
    serve, mnist_dir, tmp_path, origin
):
    """A request that writes (a recording, a robot run) whose Origin is not the server's
    own (its scheme and the Host it was sent to) gets 403; reading stays open (a browser
    lets no other site read the answer without CORS, which the server never grants)."""
    c = serve(mnist=mnist_dir)
    body = {"image": 3, "strokes": _strokes_of(3)}
    detail = _one_line_error(c.post("/api/recordings", json=body, headers={"Origin": origin}), 403)
    assert detail.startswith(f"Origin: {origin!r} is not this server's own"), detail
    _one_line_error(c.post("/api/write", json={"dmp": _seven_dmp()}, headers={"Origin": origin}),
                    403)  # fmt: skip
    assert not (tmp_path / "recordings" / "image_3.json").exists()
    assert c.get("/api/models", headers={"Origin": origin}).status_code == 200
    own = c.post("/api/recordings", json=body, headers={"Origin": "http://127.0.0.1:8000"})
    assert own.status_code == 201, own.text
    assert "access-control-allow-origin" not in own.headers


def _read_answer(conn) -> str:
    """One HTTP answer from a socket: its head, then the body its Content-Length says."""
    data = b""
    while b"\r\n\r\n" not in data:
        data += conn.recv(65536) or b"\r\n\r\n"
    head, body = data.split(b"\r\n\r\n", 1)
    length = re.search(rb"(?i)content-length: *(\d+)", head)
    while length and len(body) < int(length.group(1)):
        chunk = conn.recv(65536)
        if not chunk:
            break
        body += chunk
    return (head + b"\r\n\r\n" + body).decode("latin-1")


def test_a_body_that_stops_half_way_gets_408(runs, tmp_path):
    """Before, the server held such a request open without a time-out. A real server
    (uvicorn on a socket), since the test client sends whole bodies only."""
    import socket

    import uvicorn

    app = create_app(
        [runs[1]], data_dir=tmp_path / "r", jobs_dir=tmp_path / "j", body_timeout_s=0.5
    )
    sock = socket.socket()
    sock.bind(("127.0.0.1", 0))
    sock.listen(8)
    server = uvicorn.Server(uvicorn.Config(app, log_level="warning"))
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, daemon=True)
    thread.start()
    try:
        deadline = time.monotonic() + 30
        while not server.started and time.monotonic() < deadline:
            time.sleep(0.02)
        with socket.create_connection(sock.getsockname(), timeout=10) as conn:
            conn.sendall(b"POST /api/predict HTTP/1.1\r\nHost: 127.0.0.1\r\n"
                         b"Content-Type: application/json\r\nContent-Length: 100\r\n\r\n"
                         b'{"strokes": ')  # fmt: skip
            t0 = time.monotonic()
            answer = _read_answer(conn)
        assert answer.startswith("HTTP/1.1 408"), answer
        assert time.monotonic() - t0 < 5
        detail = json.loads(answer.split("\r\n\r\n", 1)[1])["detail"]
        assert detail == "body: 12 bytes, then nothing for 0.5 s; send it whole"
    finally:
        server.should_exit = True
        thread.join(10)
        sock.close()


@pytest.mark.parametrize("t_ms", [1e17, 1e300])
def test_recording_times_beyond_the_range_are_one_line(serve, mnist_dir, tmp_path, t_ms):
    """1e17 ms overflowed an int64 conversion before the range check: 500."""
    c = serve(mnist=mnist_dir)
    strokes = _strokes_of(4)
    strokes[1][-1][2] = t_ms
    detail = _one_line_error(c.post("/api/recordings", json={"image": 4, "strokes": strokes}), 422)
    assert detail.startswith("strokes: the recording lasts") and "more than 1 hour" in detail
    assert len(detail) < 120
    assert not (tmp_path / "recordings" / "image_4.json").exists()


def test_a_body_with_a_key_twice_is_refused(client):
    body = b'{"strokes": [[[1, 1, 0]]], "canvas": [280, 280], "canvas": [10, 10]}'
    r = client.post("/api/predict", content=body, headers={"content-type": "application/json"})
    assert (
        _one_line_error(r, 400)
        == "body: key 'canvas' appears twice in one object; give each key once"
    )


def test_a_lock_link_planted_in_the_data_directory_is_not_followed(serve, mnist_dir, tmp_path):
    """A dangling ``.lock`` link in the recordings folder created a file outside it."""
    c = serve(mnist=mnist_dir)
    outside = tmp_path / "outside.txt"
    (tmp_path / "recordings" / ".lock").unlink()
    (tmp_path / "recordings" / ".lock").symlink_to(outside)
    r = c.post("/api/recordings", json={"image": 5, "strokes": _strokes_of(5)})
    detail = _one_line_error(r, 503)
    assert "symbolic link" in detail and ".lock" in detail
    assert not outside.exists() and not (tmp_path / "recordings" / "image_5.json").exists()


def test_a_dmp_whose_movement_overflows_is_refused_by_the_api(client):
    if not available():
        pytest.skip("the robot extra is not installed: /api/write answers 503 first")
    doc = _seven_dmp()
    doc["params"]["w"][0][0] = 1e308
    detail = _one_line_error(client.post("/api/write", json={"dmp": doc}), 422)
    assert detail.startswith("dmp: field 'params.w' is invalid: w[0, 0] is 1e+308"), detail


def test_ctrl_c_while_a_robot_run_starts_is_quiet(runs, tmp_path):
    """The runs, still importing torch, printed their KeyboardInterrupt tracebacks."""
    if not available():
        pytest.skip("the robot extra is not installed")
    cmd = [sys.executable, "-m", "img2dmp", "serve", "--model", str(runs[1]), "--port", "0",
           "--data-dir", str(tmp_path / "r"), "--jobs-dir", str(tmp_path / "j")]  # fmt: skip
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            start_new_session=True)  # fmt: skip
    try:
        url = proc.stdout.readline().split("listening on ")[1].split()[0]
        body = json.dumps({"dmp": _seven_dmp(), "video": False}).encode()
        req = urllib.request.Request(url + "api/write", body, {"content-type": "application/json"})
        with urllib.request.urlopen(req, timeout=60) as r:
            assert r.status == 202
        time.sleep(0.4)  # the run's process is starting: importing torch and pybullet
        os.killpg(proc.pid, signal.SIGINT)  # the terminal's Ctrl-C: the whole group
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, out
    assert out.strip() == "img2dmp serve: stopped", out
