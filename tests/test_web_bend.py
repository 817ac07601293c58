"""``POST /api/bend`` (docs/WEB.md): a hypothesis of a prediction's DMP document bent by
the library's :func:`img2dmp.dmp.bend_dmp`, as a document ``POST /api/write`` takes.

No network is needed: the document is made here as ``Predictor.predict`` makes one (two
hypotheses, a model frame of 40 x 40 inside a 320 x 320 drawing).
"""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import torch

pytest.importorskip("fastapi")
pytest.importorskip("httpx")
with warnings.catch_warnings():  # starlette's note that it prefers httpx2 to httpx
    warnings.simplefilter("ignore")
    from fastapi.testclient import TestClient

from img2dmp.data.dmpfile import check_dmp_document, dmp_document, trajectory_entry
from img2dmp.data.images import ImageFrame
from img2dmp.dmp import DMPConfig, affine_dmp, bend_dmp, fit_dmp, rollout
from img2dmp.web import create_app
from img2dmp.web.errors import WebError
from img2dmp.web.jobs import check_write, read_document

LOCAL = "http://127.0.0.1:8000"
CONFIG = DMPConfig(scaling="none")
FRAME = ImageFrame([[0.125, 0.0, -0.4375], [0.0, 0.125, -0.4375]], (320, 320), (40, 40))


def _params(k: int):
    t = np.linspace(0.0, 2.0, 150)
    y = np.stack([20 + 8 * np.cos(2 * t + k), 10 + 9 * t], -1)
    return fit_dmp(t, y, CONFIG).params


def _document() -> dict:
    """A prediction's document: two hypotheses (0.7, 0.3) with both frames."""
    hyps = []
    for k, p in enumerate((0.7, 0.3)):
        params = _params(k)
        t = float(params.tau) * np.linspace(0.0, 1.0, 50)
        y = rollout(params.to_torch(), torch.as_tensor(t), CONFIG).numpy()
        hyps.append({"rank": k + 1, "probability": p, "params": params.to_dict(),
                     "params_image": affine_dmp(params, CONFIG, FRAME.model_to_image).to_dict(),
                     "trajectory": trajectory_entry(t, y, FRAME.to_image(y))})  # fmt: skip
    doc = dmp_document(_params(0), CONFIG, (40, 40), frame="model", hypotheses=hyps,
                       image_frame={"image": None, **FRAME.to_dict()},
                       refinement={"steps": 0}, fit={"path_on_ink": 1.0, "ink_written": 1.0},
                       flags=[])  # fmt: skip
    return json.loads(json.dumps(doc))


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    app = create_app([], data_dir=tmp_path_factory.mktemp("bend") / "r")
    with TestClient(app, base_url=LOCAL) as c:
        yield c


def test_a_bent_hypothesis_is_the_librarys_bend_in_a_document_write_takes(client):
    doc = _document()
    body = {"dmp": doc, "hypothesis": 2, "goal": [30.0, 5.0], "tempo": 2, "n_points": 60}
    r = client.post("/api/bend", json=body)
    assert r.status_code == 200, r.text
    answer = r.json()
    want = bend_dmp(_params(1), CONFIG, goal=[30.0, 5.0], tempo=2.0)
    bent = check_dmp_document(answer["dmp"], "answer")
    np.testing.assert_allclose(bent.params.to_vector(), want.to_vector(), rtol=1e-12)
    assert bent.probabilities == [0.3] and bent.frame == "model"
    assert answer["dmp"]["bent"] == {"hypothesis": 2, "goal": [30.0, 5.0], "tempo": 2.0}
    assert "fit" not in answer["dmp"]  # the prediction's fit is not the bent DMP's
    h = answer["hypothesis"]
    assert h["rank"] == 1 and len(h["t"]) == 60 and h["tau_s"] == pytest.approx(want.tau)
    t = float(want.tau) * np.linspace(0.0, 1.0, 60)  # as sent, to 6 decimals
    np.testing.assert_allclose(h["t"], t, atol=1e-6)
    y = rollout(want.to_torch(), torch.as_tensor(t), CONFIG).numpy()
    np.testing.assert_allclose(h["model"], y, atol=1e-6)
    np.testing.assert_allclose(h["image"], FRAME.to_image(y), atol=1e-5)
    # the path's end moved with the goal (no scaling: by the goal's move, to 1e-9)
    before = rollout(_params(1).to_torch(), torch.as_tensor([float(_params(1).tau)]), CONFIG)
    moved = np.asarray(h["model"][-1]) - before.numpy()[0]
    np.testing.assert_allclose(moved, [30.0, 5.0] - _params(1).g, atol=1e-6)
    rows = answer["csv"].splitlines()
    assert rows[0].startswith("rank,probability,t_s,x_model_px") and len(rows) == 61
    # what the robot is given: the bent document, checked as POST /api/write checks it
    written = check_write(answer["dmp"], 1)
    np.testing.assert_array_equal(read_document(written, 1).params.to_vector(), want.to_vector())
    with pytest.raises(WebError, match="a rank in 1..1, got 2"):
        check_write(answer["dmp"], 2)  # one hypothesis: the bent one


def test_the_server_s_rollouts_take_one_path_from_its_start(tmp_path, monkeypatch):
    """rollout's ``"auto"`` takes torch's operations for small calls until the fused
    kernels are loaded, which a process of many small calls does after a while: a
    server's first bends and its later ones came from two paths (equal to rounding).
    The server loads the kernels at its start."""
    import importlib

    from img2dmp.dmp import _kernels

    if not _kernels.available():
        pytest.skip("numba missing: every rollout takes the torch operations")
    rollout_module = importlib.import_module("img2dmp.dmp.rollout")
    monkeypatch.setattr(rollout_module, "_fused_loaded", False)  # as in a fresh process
    monkeypatch.setitem(rollout_module._unfused, "seconds", 0.0)
    create_app([], data_dir=tmp_path / "r")
    assert rollout_module._fused_loaded


def test_each_bend_is_the_librarys(client):
    doc = _document()
    for options in ({"start": [15.0, 12.0]}, {"shift": [-3.0, 4.5]}, {"scale": 0.5},
                    {"rotate_deg": 30}, {}):  # fmt: skip
        r = client.post("/api/bend", json={"dmp": doc, **options})
        assert r.status_code == 200, r.text
        want = bend_dmp(_params(0), CONFIG, **options)
        got = check_dmp_document(r.json()["dmp"], "answer").params
        np.testing.assert_allclose(got.to_vector(), want.to_vector(), rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize(
    "change, status, detail",
    [
        ({"tempo": 0}, 422, "tempo must be a finite number > 0, got 0.0"),
        ({"scale": -1.5}, 422, "scale must be a finite number > 0, got -1.5"),
        ({"rotate_deg": 1e308}, 422, "rotate_deg must be from -1e+06 to 1e+06 degrees, got 1e+308"),
        ({"goal": [1.0]}, 422, "goal: List should have at least 2 items"),
        ({"goal": ["1", 2]}, 422, "goal[0]: Input should be a valid number"),
        ({"hypothesis": 3}, 422, "a rank in 1..2, got 3"),
        ({"dmp": {"params": 1}}, 422, "dmp: field"),
        ({"n_points": 1}, 422, "n_points: Input should be greater than or equal to 2"),
    ],
)
def test_a_bad_bend_is_a_one_line_4xx_naming_the_value(client, change, status, detail):
    r = client.post("/api/bend", json={"dmp": _document(), **change})
    assert r.status_code == status, r.text
    assert detail in r.json()["detail"] and "\n" not in r.json()["detail"]


def test_a_non_finite_goal_is_refused_as_strict_json(client):
    text = json.dumps({"dmp": _document()})[:-1] + ', "goal": [NaN, 1]}'
    r = client.post("/api/bend", content=text, headers={"Content-Type": "application/json"})
    assert r.status_code == 400 and "NaN" in r.json()["detail"]


def test_bending_is_refused_to_other_origins_and_names(client):
    body = {"dmp": _document(), "tempo": 2}
    r = client.post("/api/bend", json=body, headers={"Origin": "http://evil.test"})
    assert r.status_code == 403 and "Origin" in r.json()["detail"]
    r = client.post("/api/bend", json=body, headers={"Host": "rebind.test:8000"})
    assert r.status_code == 400 and "Host" in r.json()["detail"]
    r = client.post("/api/bend", json=body, headers={"Origin": LOCAL})
    assert r.status_code == 200


def test_a_dmp_slowed_beyond_what_the_arm_writes_is_refused_before_it_is_queued(client):
    """A DMP bent to tempo 0.0001 (tau ~ 20,000 s) was queued (202), then its job failed."""
    from img2dmp.robot import available

    if not available():
        pytest.skip("the robot extra is not installed: /api/write answers 503 first")
    bent = client.post("/api/bend", json={"dmp": _document(), "tempo": 0.0001}).json()["dmp"]
    for video in (True, False):
        r = client.post("/api/write", json={"dmp": bent, "video": video})
        assert r.status_code == 422, r.text
        detail = r.json()["detail"]
        assert detail.startswith("dmp: params.tau is 2") and "\n" not in detail, detail
        assert "more than the 250000 the arm writes" in detail, detail


def test_a_long_dmp_is_filmed_as_a_time_lapse_instead_of_failing(client):
    """tau = 400 s filmed every 0.1 s is 4,000 frames (1.7 GiB): its job failed. Its
    video keeps a frame every 3.35 s (120 frames), as a page's does."""
    pytest.importorskip("pybullet")
    from img2dmp.robot import WritingOptions
    from img2dmp.web.jobs import FRAME_INTERVAL_S, plan_write

    bent = client.post("/api/bend", json={"dmp": _document(), "tempo": 0.005}).json()["dmp"]
    tau = read_document(bent, 1).params.tau
    assert tau == pytest.approx(400.0, rel=1e-3)
    with pytest.raises(ValueError, match="keeps up to 4"):  # what the job was given
        WritingOptions(frame_interval_s=FRAME_INTERVAL_S).check_video(float(tau))
    doc, interval_s = plan_write(bent, 1, True)
    assert interval_s == pytest.approx(np.ceil(100 * (float(tau) + 2) / 120) / 100)
    WritingOptions(frame_interval_s=interval_s).check_video(float(tau))
    assert read_document(doc, 1).params.tau == tau
    assert plan_write(bent, 1, False)[1] is None
    assert plan_write(_document(), 1, True)[1] == FRAME_INTERVAL_S  # a digit: every 0.1 s
