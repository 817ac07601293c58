"""Reading a page in the browser's API: ``POST /api/predict_page`` and ``GET /api/pages/{id}``
(docs/WEB.md), through FastAPI's TestClient.

- a generated page of five characters in two lines gives five characters, in reading
  order, each boxed around its own ink in the photo's pixels, the one touching the border
  flagged; the answer is the library's page document without the DMPs, and the whole
  document (every DMP, each a valid DMP document) downloads as ``<name>_page.json``;
- a photo stored on its side with an EXIF orientation tag gives the boxes of the upright
  photo, in its frame;
- a page without ink gives no characters and the ``no_ink`` flag;
- a body that is no image, sent as JSON, empty, too large (413 naming --max-page-mb, a
  limit of its own: the other endpoints keep --max-upload-mb) or of too many pixels is a
  one-line 4xx;
- a single image's prediction (``POST /api/predict``) carries its fit and flags;
- the arm writes a page read here (``POST /api/pages/{id}/write``, a robot job): its
  progress names the character being written, in order, and when done every character
  is inked (the commanded path's ink share > 0.9, in the job's answer and in its
  ``characters.csv``) and the figure, the video, the log and the table download; a width
  at which the page does not fit the sheet is a one-line 422 naming the widest that
  fits, an unknown page 404, nothing to write (every character flagged and skipped) 422.

The network is tiny (one epoch): the boxes come from the page's ink, not the network.
"""

from __future__ import annotations

import csv
import io
import time
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
from img2dmp.data.dmpfile import check_dmp_document
from img2dmp.robot import available
from img2dmp.web import create_app
from img2dmp.web.strokes import render_strokes

PNG = {"content-type": "image/png"}
#: The server answers to its own names only (HostGuard): the test client speaks as one.
LOCAL = "http://127.0.0.1:8000"


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    return tmp_path_factory.mktemp("web_page")


@pytest.fixture(scope="module")
def runs(work, train_tiny_runs):
    return train_tiny_runs(work, lambda k: work / f"net{k}" / "run")


@pytest.fixture(scope="module")
def client(runs, work):
    app = create_app([runs[2], runs[1]], data_dir=work / "recordings", jobs_dir=work / "jobs")
    with TestClient(app, base_url=LOCAL) as c:
        yield c


def _file(image: np.ndarray, fmt: str = "PNG", exif=None) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(image).save(buf, fmt, **({"exif": exif} if exif is not None else {}))
    return buf.getvalue()


def _one_line_error(r, status: int) -> str:
    assert r.status_code == status, (r.status_code, r.text)
    body = r.json()
    assert set(body) == {"detail"} and body["detail"] and "\n" not in body["detail"], body
    return body["detail"]


def _read(client, raw: bytes, **query):
    r = client.post("/api/predict_page", content=raw, headers=PNG, params=query)
    assert r.status_code == 200, r.text
    return r.json()


def test_every_character_of_a_page_is_boxed_around_its_ink_in_reading_order(
    client, runs, handwritten_page
):
    image, boxes = handwritten_page
    answer = _read(client, _file(image), name="my page.png", model="net1")
    page = answer["page"]
    assert answer["model"] == "net1" and page["format"] == "img2dmp-page"
    assert page["image_size_px"] == [360, 200] and page["image"] == "my page.png"
    assert "no_ink" not in page["flags"]
    assert [line["characters"] for line in page["lines"]] == [[0, 1, 2], [3, 4]]
    chars = page["characters"]
    assert [c["index"] for c in chars] == [0, 1, 2, 3, 4]
    for c, want in zip(chars, boxes, strict=True):
        assert np.abs(np.subtract(c["box_image_px"], want)).max() <= 1, (c["index"], want)
        assert "dmp" not in c and len(c["path_image_px"]) == 100 == len(c["pen"])
    assert "cut_by_border" in chars[4]["flags"]
    assert not any("cut_by_border" in c["flags"] for c in chars[:4])
    # the library's own reading of the same image
    ref = load_model(runs[1]).predict_page(image).to_document(dmps=False)
    assert page["flags"] == ref["flags"]  # the one-epoch network's are "mostly_unreadable"
    for c, r in zip(chars, ref["characters"], strict=True):
        assert c["box_image_px"] == r["box_image_px"] and c["flags"] == r["flags"]
        np.testing.assert_allclose(c["path_image_px"], r["path_image_px"], atol=1e-3)


def test_the_whole_page_document_downloads_with_every_dmp(client, handwritten_page):
    answer = _read(client, _file(handwritten_page[0]), name="photos/Page 1.png")
    assert answer["filename"] == "Page_1_page.json"
    r = client.get(answer["document"])
    assert r.status_code == 200
    assert r.headers["content-disposition"] == 'attachment; filename="Page_1_page.json"'
    doc = r.json()
    assert len(doc["characters"]) == 5
    for c, light in zip(doc["characters"], answer["page"]["characters"], strict=True):
        check_dmp_document(c.pop("dmp"), "dmp")
        assert c == light
    assert {k: v for k, v in doc.items() if k != "characters"} == {
        k: v for k, v in answer["page"].items() if k != "characters"
    }
    assert doc["image"] == "Page 1.png"  # the file's name, without its folder
    _one_line_error(client.get("/api/pages/0123456789abcdef"), 404)


def test_a_file_name_with_folders_is_kept_as_its_last_part(client):
    """The download's name was cleaned, the document kept "../../../tmp/evil.png"."""
    blank = np.full((60, 80), 255, np.uint8)
    for name, kept in (("../../../tmp/evil.png", "evil.png"), ("..\\a\\b.png", "b.png"),
                       ("..", None), ("Übung\n(2).jpg", "Übung_(2).jpg")):  # fmt: skip
        answer = _read(client, _file(blank), name=name)
        assert answer["page"]["image"] == kept, (name, answer["page"]["image"])
        assert client.get(answer["document"]).json()["image"] == kept
    assert answer["filename"] == "bung__2_page.json"  # the download's: ASCII


def test_a_photo_stored_on_its_side_is_read_upright(client, handwritten_page):
    image, boxes = handwritten_page
    exif = Image.Exif()
    exif[0x0112] = 6  # the viewer turns the raster 90 degrees clockwise to show it
    raw = _file(np.ascontiguousarray(np.rot90(image, 1)), "JPEG", exif)
    answer = _read(client, raw)
    page = answer["page"]
    assert page["image_size_px"] == [360, 200] and len(page["characters"]) == 5
    for c, want in zip(page["characters"], boxes, strict=True):
        assert np.abs(np.subtract(c["box_image_px"], want)).max() <= 2, (c["index"], want)


def test_a_page_without_ink_has_no_characters_and_says_so(client):
    paper = np.full((240, 320, 3), (236, 232, 220), np.uint8)
    page = _read(client, _file(paper))["page"]
    assert page["characters"] == [] and page["lines"] == [] and page["flags"] == ["no_ink"]


def test_bad_photos_get_one_line_4xx(client, runs, work, handwritten_page):
    post = client.post
    assert "cannot be decoded" in _one_line_error(post("/api/predict_page", content=b"hello"), 422)
    detail = _one_line_error(post("/api/predict_page", json={"image": "data:..."}), 415)
    assert "image/jpeg or image/png" in detail
    assert "empty" in _one_line_error(post("/api/predict_page", content=b"", headers=PNG), 422)
    gif = io.BytesIO()
    Image.fromarray(handwritten_page[0]).save(gif, "GIF")
    detail = _one_line_error(post("/api/predict_page", content=gif.getvalue(), headers=PNG), 422)
    assert "PNG or JPEG" in detail and "GIF" in detail
    raw = _file(handwritten_page[0])
    for query, field in (({"n_points": 1}, "n_points"), ({"model": "nope"}, "model")):
        r = post("/api/predict_page", content=raw, headers=PNG, params=query)
        assert _one_line_error(r, 422).startswith(field)
    bomb = _file(np.zeros((5100, 5100), np.uint8))  # 26 million pixels, 26 kB of PNG
    assert "pixels" in _one_line_error(post("/api/predict_page", content=bomb, headers=PNG), 422)


def test_the_page_upload_has_a_limit_of_its_own(runs, work, handwritten_page):
    raw = _file(np.ascontiguousarray(handwritten_page[0][::-1]))  # a page of about 20 kB
    app = create_app([runs[1]], data_dir=work / "r2", max_upload_mb=0.001, max_page_mb=0.5)
    with TestClient(app, base_url=LOCAL) as c:
        assert c.post("/api/predict_page", content=raw, headers=PNG).status_code == 200
        big = raw + bytes(600_000)
        detail = _one_line_error(c.post("/api/predict_page", content=big, headers=PNG), 413)
        assert "0.5 MB" in detail and "--max-page-mb" in detail
        strokes = {"strokes": [[[5.0, 5.0, float(i)] for i in range(200)]], "canvas": [64, 64]}
        assert "--max-upload-mb" in _one_line_error(c.post("/api/predict", json=strokes), 413)
        spec = c.get("/openapi.json").json()["paths"]["/api/predict_page"]["post"]
        assert {"image/jpeg", "image/png"} <= set(spec["requestBody"]["content"])
        assert "0.5 MB" in spec["requestBody"]["description"]


def test_a_single_prediction_carries_its_fit_and_flags(client, runs):
    seven = [[[70.0, 60.0, 0.0], [215.0, 62.0, 80.0], [130.0, 235.0, 200.0]]]
    r = client.post("/api/predict", json={"strokes": seven, "canvas": [280, 280]})
    assert r.status_code == 200, r.text
    a = r.json()
    pred = load_model(runs[2]).predict(render_strokes([np.array(s) for s in seven], (280, 280)))
    assert a["fit"] == pred.fit == a["dmp"]["fit"]
    assert a["flags"] == pred.flags == a["dmp"]["flags"]
    assert set(a["fit"]) == {"path_on_ink", "ink_written"}


def test_the_page_view_is_served_and_its_limit_is_an_option(client, capsys):
    from img2dmp import cli

    r = client.get("/page")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    assert "/static/page.js" in r.text
    assert client.get("/static/page.js").status_code == 200
    assert cli.main(["serve", "--help"]) == 0
    assert "--max-page-mb" in capsys.readouterr().out
    assert cli.main(["serve", "--max-page-mb", "0"]) == 2


# --- the arm writes the page ----------------------------------------------------------------

needs_robot = pytest.mark.skipif(not available(), reason="needs pybullet (img2dmp[robot])")


def _poll(client, job_id: str, timeout_s: float = 180.0) -> tuple[dict, list]:
    """The job's last state and every ``character`` it reported while running."""
    seen, end = [], time.monotonic() + timeout_s
    while time.monotonic() < end:
        state = client.get(f"/api/jobs/{job_id}").json()
        if state["character"] is not None:
            seen.append(state["character"])
        if state["status"] in ("done", "failed"):
            return state, seen
        time.sleep(0.05)
    raise AssertionError(f"job {job_id} did not end within {timeout_s} s: {state}")


@needs_robot
def test_the_arm_writes_a_page_read_here_and_inks_every_character(client, handwritten_page):
    answer = _read(client, _file(handwritten_page[0]), name="note.png", model="net1")
    r = client.post(f"/api/pages/{answer['id']}/write", json={"width_mm": 100, "video": True})
    assert r.status_code == 202, r.text
    job = r.json()
    assert job["kind"] == "page" and job["status"] == "queued" and job["page"] is None
    assert set(job["files"]) == {"paper", "animation", "log", "characters"}
    state, seen = _poll(client, job["id"])
    assert state["status"] == "done", state["error"]
    # the progress named each character as the arm began it, in reading order
    assert seen and {c["of"] for c in seen} == {5}
    assert [c["number"] for c in seen] == sorted(c["number"] for c in seen)
    assert all(c["index"] == c["number"] - 1 for c in seen)
    page = state["page"]
    assert page["totals"]["characters_written"] == 5 == len(page["characters"])
    assert page["totals"]["width_mm"] == pytest.approx(100.0)
    for c in page["characters"]:
        assert c["written"] and c["ink_share"] > 0.9, c
    assert page["video_speed"] >= 1.0
    assert state["summary"][0].startswith("note_page: 5 of 5 characters written on 100.0 x ")
    kinds = {"paper": "image/png", "animation": "image/gif", "log": "text/csv",
             "characters": "text/csv"}  # fmt: skip
    files = {}
    for key, mime in kinds.items():
        r = client.get(state["files"][key])
        assert r.status_code == 200 and r.headers["content-type"].startswith(mime), key
        files[key] = r.content
    rows = list(csv.DictReader(io.StringIO(files["characters"].decode())))
    assert [row["index"] for row in rows] == ["0", "1", "2", "3", "4", "page"]
    for row, c in zip(rows, page["characters"], strict=False):
        assert float(row["ink_share"]) == pytest.approx(c["ink_share"], abs=1e-4)
    assert Image.open(io.BytesIO(files["paper"])).size[0] > 1000  # full size for a new tab
    for name in ("page.json", "result.json", "dmp.json", "job.log"):
        _one_line_error(client.get(f"/api/jobs/{job['id']}/files/{name}"), 404)


@needs_robot
def test_a_page_the_arm_cannot_write_is_refused_with_one_line(client, handwritten_page):
    answer = _read(client, _file(handwritten_page[0]), name="note.png", model="net1")
    url = f"/api/pages/{answer['id']}/write"
    detail = _one_line_error(client.post(url, json={"width_mm": 2000}), 422)
    assert detail.startswith("note_page.json: the page does not fit the sheet at a width of 2000")
    assert "the page fits at a width of at most" in detail
    # the tiny network's characters are all flagged: skipping them leaves nothing
    detail = _one_line_error(client.post(url, json={"skip_flagged": True}), 422)
    assert "no characters to write" in detail
    for body, field in (({"width_mm": 0}, "width_mm"), ({"width_mm": "100"}, "width_mm"),
                        ({"skip_flagged": 1}, "skip_flagged")):  # fmt: skip
        assert _one_line_error(client.post(url, json=body), 422).startswith(field)
    assert "not kept" in _one_line_error(
        client.post("/api/pages/0123456789abcdef/write", json={}), 404
    )


def test_writing_a_page_without_the_robot_answers_503(client, handwritten_page, monkeypatch):
    import img2dmp.robot

    answer = _read(client, _file(handwritten_page[0]))
    monkeypatch.setattr(img2dmp.robot, "available", lambda: False)
    r = client.post(f"/api/pages/{answer['id']}/write", json={})
    assert "img2dmp[robot]" in _one_line_error(r, 503)
