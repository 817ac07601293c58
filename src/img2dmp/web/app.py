"""The HTTP API of ``img2dmp serve`` (docs/WEB.md) as a FastAPI application.

:func:`create_app` builds it: the models loaded once (:mod:`.models`), the Record page's
images and recordings (:mod:`.recordings`), the pages read from photos (:mod:`.pages`),
robot runs in their own processes (:mod:`.jobs`) and the static pages. Every refusal is a
4xx answer ``{"detail": one line}`` naming the field or value: a ``Host`` that is not one
of the server's names or a state-changing request from another ``Origin``
(:class:`HostGuard`, before anything else), request bodies larger than ``max_upload_mb``
(``max_page_mb`` for a page's photo; from ``Content-Length`` and while reading, before
parsing) or that stop half-way, JSON that is not strict JSON (no ``NaN`` or ``Infinity``,
no number beyond a double, no key twice), FastAPI's validation errors, and the checks of
the modules below. The endpoints that work are plain functions, run in FastAPI's thread
pool.
"""

from __future__ import annotations

import asyncio
import json
import math
import re
import time
from contextlib import asynccontextmanager
from pathlib import Path
from typing import Annotated
from urllib.parse import urlsplit

from fastapi import FastAPI, HTTPException, Query, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles
from fastapi_offline import FastAPIOffline
from pydantic import BaseModel, ConfigDict, Field
from starlette.concurrency import run_in_threadpool
from starlette.exceptions import HTTPException as StarletteHTTPException

from .. import __version__
from .._files import parse_json
from .bending import BEND_FIELDS, bend_answer
from .errors import WebError, one_line, show
from .jobs import JobManager, check_image, plan_write
from .models import LoadedModel, load_models, predict_with, prediction_answer
from .page_jobs import DEFAULT_WIDTH_MM, submit_page, submit_strokes
from .pages import PAGE_TYPES, PAGE_UPLOAD_MB, PageStore, check_page_type, page_answer, read_photo
from .recordings import FolderImages, MnistImages, Recordings
from .strokes import (
    MAX_IMAGE_PIXELS,
    MAX_POINTS,
    MAX_STROKES,
    canvas_bounds,
    canvas_size,
    check_strokes,
    decode_data_url,
    render_strokes,
)

STATIC_DIR = Path(__file__).resolve().parent / "static"
#: Samples of each trajectory a prediction may ask for.
N_POINTS_RANGE = (2, 1000)
#: The names a browser may give this server in ``Host`` without --allowed-host.
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
#: Seconds a request body may take to arrive between two of its parts.
BODY_TIMEOUT_S = 30.0
#: Methods that change nothing; any other must come from the server's own pages.
SAFE_METHODS = ("GET", "HEAD", "OPTIONS")


# --- request bodies -------------------------------------------------------------------


class _Body(BaseModel):
    """Strict types (no ``"3"`` for 3, no ``true`` for 1), finite numbers; unknown keys
    are ignored."""

    model_config = ConfigDict(strict=True, allow_inf_nan=False, extra="ignore")


Point = Annotated[list[float], Field(min_length=3, max_length=3, description="[x, y, t_ms]")]
Strokes = Annotated[list[Annotated[list[Point], Field(max_length=MAX_POINTS)]],
                    Field(max_length=MAX_STROKES)]  # fmt: skip


class PredictRequest(_Body):
    """``POST /api/predict``: exactly one of ``strokes`` (with ``canvas``) and ``image``."""

    strokes: Strokes | None = None
    canvas: Annotated[list[float], Field(min_length=2, max_length=2)] | None = Field(
        None, description="[width, height] of the drawing area, pixels"
    )
    image: str | None = Field(None, description="data:image/png;base64,... (or JPEG)")
    model: str | None = Field(None, description="an id of GET /api/models")
    n_points: int = Field(100, ge=N_POINTS_RANGE[0], le=N_POINTS_RANGE[1])


class WriteRequest(_Body):
    """``POST /api/write``: exactly one of a DMP document (img2dmp-dmp) and a stroke
    model's character (``strokes_page``) for the simulated arm."""

    dmp: dict | None = None
    strokes_page: dict | None = Field(
        None, description="a stroke model's character: strokes_page of POST /api/predict"
    )
    hypothesis: int = Field(1, ge=1)
    video: bool = True
    image: str | None = Field(
        None,
        description="with dmp: data:image/png;base64,... of the image its params are in "
        "(/api/predict's input_image), shown under the path in paper.png",
    )


XY = Annotated[list[float], Field(min_length=2, max_length=2, description="[x, y], pixels")]


class BendRequest(_Body):
    """``POST /api/bend``: one hypothesis of a DMP document bent (img2dmp.dmp.bend_dmp);
    positions in pixels of the document's ``params`` frame (a prediction's: the model's
    input)."""

    dmp: dict
    hypothesis: int = Field(1, ge=1)
    goal: XY | None = Field(None, description="a new goal (the weights kept)")
    start: XY | None = Field(None, description="a new start (the weights and goal kept)")
    shift: XY | None = Field(None, description="moves the whole movement")
    scale: float | None = Field(None, description="> 0, about the start")
    rotate_deg: float | None = Field(None, description="about the start, x toward y")
    tempo: float | None = Field(None, description="> 0: the movement tempo times as fast")
    n_points: int = Field(100, ge=N_POINTS_RANGE[0], le=N_POINTS_RANGE[1])


class PageWriteRequest(_Body):
    """``POST /api/pages/{id}/write``: how the arm writes a page read lately."""

    width_mm: float | None = Field(
        None,
        gt=0,
        description=f"the page's written width, mm (default {DEFAULT_WIDTH_MM:g}, "
        "or the widest that fits the sheet if narrower)",
    )
    skip_flagged: bool = Field(False, description="leave out the characters with flags")
    video: bool = True


class RecordingRequest(_Body):
    """``POST /api/recordings``: the pen path traced over image ``image``."""

    image: int = Field(ge=0)
    label: int | None = Field(None, ge=0, le=9)
    strokes: Strokes
    replace: bool = False


# --- strict JSON and the body limit ----------------------------------------------------


class _StrictJSONRequest(Request):
    """A request whose JSON body is read strictly: ``NaN``, ``Infinity`` and numbers
    beyond a double (``1e999``, read as infinity) refused (400)."""

    async def json(self):
        if not hasattr(self, "_json"):
            body = await self.body()
            try:
                self._json = parse_json(body, "body", allow_nan=False)
                _check_finite(self._json)
            except ValueError as e:
                raise HTTPException(400, str(e)) from None
        return self._json


def _check_finite(value) -> None:
    """``ValueError`` naming the first number of a parsed JSON body that is not finite
    (a literal such as ``1e999``, too large for a double, which JSON's grammar allows)."""
    try:
        json.dumps(value, allow_nan=False)  # in C: the body of any size at once
        return
    except (ValueError, RecursionError):  # then found and named below
        pass
    too_large = "is a number too large for a double (it reads as infinity); give a finite number"
    if not isinstance(value, (dict, list)):
        raise ValueError(f"body: {too_large}")
    stack = [((), value)]
    while stack:
        where, container = stack.pop()
        nested = []
        for k, v in container.items() if isinstance(container, dict) else enumerate(container):
            at = (*where, k)
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"body: {_field(at)} {too_large}")
            if isinstance(v, (dict, list)):
                nested.append((at, v))
        stack.extend(reversed(nested))


class _StrictJSONRoute(APIRoute):
    """A route whose JSON body is read strictly (:class:`_StrictJSONRequest`) and must be
    sent as JSON (:func:`check_json_type`)."""

    def get_route_handler(self):
        handler = super().get_route_handler()
        takes_json = self.body_field is not None

        async def strict(request: Request):
            if takes_json:
                check_json_type(request.url.path, request.headers.get("content-type"))
            return await handler(_StrictJSONRequest(request.scope, request.receive))

        return strict


def check_json_type(path: str, content_type: str | None) -> None:
    """415 for a body sent to a JSON endpoint as something else (an image file, a form,
    text) or without ``Content-Type`` (which FastAPI would not read as JSON)."""
    kind = (content_type or "").split(";")[0].strip().lower()
    if kind == "application/json" or re.fullmatch(r"application/[\w.-]+\+json", kind):
        return
    hint = ""
    if kind.startswith("image/") and path == "/api/predict":
        hint = ' (an image goes in it as "image": a data:image/png;base64,... URL)'
    elif kind.startswith("image/"):
        hint = " (a page's photo goes to POST /api/predict_page as its own bytes)"
    got = show(kind) if kind else "none"
    raise WebError(415, f"Content-Type: {path} takes a JSON body, sent as application/json"
                   f"{hint}, got {got}")  # fmt: skip


class BodyLimit:
    """ASGI middleware: a body above ``max_bytes`` gets 413, refused from its
    ``Content-Length`` before anything is read, or while it is read (chunked bodies); a
    body whose next part does not arrive within ``timeout_s`` gets 408 (a client that
    stops half-way would otherwise hold a worker and a connection for ever). ``paths``
    gives some paths a limit of their own: ``{path: (max_bytes, option)}``."""

    def __init__(self, app, max_bytes: int, timeout_s: float = BODY_TIMEOUT_S,
                 paths: dict | None = None):  # fmt: skip
        self.app = app
        self.max_bytes = int(max_bytes)
        self.timeout_s = float(timeout_s)
        self.paths = {k: (int(n), option) for k, (n, option) in (paths or {}).items()}

    def _limit(self, path: str) -> tuple[int, str]:
        return self.paths.get(path, (self.max_bytes, "--max-upload-mb"))

    def _too_large(self, path: str, read: str) -> str:
        max_bytes, option = self._limit(path)
        return f"body: more than the {max_bytes / (1 << 20):.3g} MB allowed ({option}): {read}"

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        path, max_bytes = scope.get("path", ""), self._limit(scope.get("path", ""))[0]
        length = dict(scope.get("headers") or ()).get(b"content-length")
        if length is not None:
            text = length.decode("latin-1").strip()
            if not text.isdigit():
                answer = JSONResponse({"detail": f"Content-Length: {show(text)} is no size"}, 400)
                return await answer(scope, receive, send)
            if int(text) > max_bytes:
                too_large = self._too_large(path, f"Content-Length {int(text)} bytes")
                answer = JSONResponse({"detail": too_large}, 413)
                return await answer(scope, receive, send)
        total = 0

        async def limited():
            nonlocal total
            try:
                message = await asyncio.wait_for(receive(), self.timeout_s)
            except TimeoutError:
                raise HTTPException(
                    408,
                    f"body: {total} bytes, then nothing for {self.timeout_s:g} s; send it whole",
                ) from None
            if message["type"] == "http.request":
                total += len(message.get("body", b""))
                if total > max_bytes:
                    raise HTTPException(413, self._too_large(path, f"{total} bytes read"))
            return message

        await self.app(scope, limited, send)


def host_name(host: str) -> str:
    """The name in a ``Host`` header or an address (``[::1]:8000`` -> ``::1``,
    ``LocalHost.:80`` -> ``localhost``), as compared with the allowed hosts."""
    host = host.strip().lower()
    if host.startswith("["):
        return host[1 : host.find("]")] if "]" in host else host
    if host.count(":") == 1:  # name:port (an IPv6 address without brackets has several)
        host = host.split(":", 1)[0]
    return host[:-1] if host.endswith(".") else host


def _origin(url: str) -> tuple[str, str, int | None] | None:
    """(scheme, host, port) of an ``Origin`` or URL, ports spelled out; None if it is none."""
    try:
        parts = urlsplit(url.strip().lower())
        port = parts.port or {"http": 80, "https": 443}.get(parts.scheme)
    except ValueError:
        return None
    return (parts.scheme, host_name(parts.hostname or ""), port) if parts.hostname else None


class HostGuard:
    """ASGI middleware against DNS rebinding and cross-site requests, before any work.

    A page of another site that makes its own name resolve to 127.0.0.1 (DNS rebinding)
    reaches this server from the user's browser as a page of its own origin; only the
    ``Host`` header shows the name it used. A request whose ``Host`` is none of
    ``allowed`` (the loopback names, the address bound, ``--allowed-host``) gets 400. A
    request that may change something (any method but GET, HEAD and OPTIONS) whose
    ``Origin`` is not this server's own (the scheme and the ``Host`` it was sent to) gets
    403; a request without ``Origin`` is not from a browser's page of another site.
    """

    def __init__(self, app, allowed: tuple[str, ...]):
        self.app = app
        self.allowed = tuple(dict.fromkeys(host_name(h) for h in allowed))

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = dict(scope.get("headers") or ())
        host = headers.get(b"host", b"").decode("latin-1")
        refusal = None
        if host_name(host) not in self.allowed:
            names = ", ".join(self.allowed)
            refusal = (400, f"Host: {show(host)} is not a name of this server (it answers to "
                       f"{names}; img2dmp serve --allowed-host NAME adds one)")  # fmt: skip
        elif scope.get("method", "GET") not in SAFE_METHODS and b"origin" in headers:
            origin = headers[b"origin"].decode("latin-1")
            own = _origin(f"{scope.get('scheme', 'http')}://{host}")
            if _origin(origin) != own:
                refusal = (403, f"Origin: {show(origin)} is not this server's own; what "
                           "changes something is taken only from its own pages")  # fmt: skip
        if refusal is not None:
            answer = JSONResponse({"detail": refusal[1]}, refusal[0])
            return await answer(scope, receive, send)
        return await self.app(scope, receive, send)


# --- errors ---------------------------------------------------------------------------


def _field(loc) -> str:
    parts = [p for p in loc if p not in ("body", "path", "query")] or list(loc[:1])
    text = ""
    for p in parts:
        text += f"[{p}]" if isinstance(p, int) else (f".{p}" if text else str(p))
    return text or "body"


def validation_detail(errors) -> tuple[int, str]:
    """Status and one line for FastAPI's validation errors: the first error's field,
    message and value (400 for a body that is not JSON, else 422)."""
    if not errors:
        return 422, "the request is not valid"
    e = errors[0]
    if e.get("type") == "json_invalid":
        return 400, f"body: not valid JSON ({(e.get('ctx') or {}).get('error', e.get('msg'))})"
    where = _field(e.get("loc", ()))
    if e.get("type") == "missing":
        return 422, f"{where}: is required"
    return 422, f"{where}: {e.get('msg', 'is not valid')}, got {show(e.get('input'))}"


def _install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(WebError)
    async def web_error(request, exc: WebError):
        return JSONResponse({"detail": exc.detail}, exc.status)

    @app.exception_handler(RequestValidationError)
    async def invalid(request, exc: RequestValidationError):
        status, detail = validation_detail(exc.errors())
        return JSONResponse({"detail": one_line(detail)}, status)

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request, exc: StarletteHTTPException):
        detail = exc.detail if isinstance(exc.detail, str) else json.dumps(exc.detail)
        return JSONResponse({"detail": one_line(detail)}, exc.status_code, headers=exc.headers)


# --- the application ------------------------------------------------------------------


class ServerState:
    """What the endpoints share: the models, the recordings, the robot's jobs, the pages
    read."""

    def __init__(self, models: dict[str, LoadedModel], recordings: Recordings, jobs: JobManager,
                 pages: PageStore | None = None):  # fmt: skip
        self.models, self.recordings, self.jobs = models, recordings, jobs
        self.pages = pages if pages is not None else PageStore()

    def model(self, model_id: str | None) -> LoadedModel:
        """The model of ``model_id`` (None: the first); 409 without models, 422 for an
        unknown id."""
        if not self.models:
            raise WebError(409, "model: no model is loaded; start img2dmp serve with --model RUN")
        if model_id is None:
            return next(iter(self.models.values()))
        if model_id not in self.models:
            raise WebError(
                422, f"model: no model {show(model_id)}; the models are {', '.join(self.models)}"
            )
        return self.models[model_id]


def create_app(
    models=(),
    *,
    mnist=None,
    images=None,
    data_dir="recordings",
    max_jobs: int = 1,
    max_upload_mb: float = 4.0,
    jobs_dir=None,
    static_dir=None,
    max_page_mb: float = PAGE_UPLOAD_MB,
    refine: int | None = None,
    allowed_hosts=(),
    body_timeout_s: float = BODY_TIMEOUT_S,
    refine_unfamiliar: int | None = None,
) -> FastAPI:
    """The application of ``img2dmp serve`` (docs/WEB.md).

    Parameters
    ----------
    models : sequence
        Names of shipped models, run directories or checkpoints (or ``(id, Predictor)``
        pairs); the first is the default. None loaded: predictions answer 409.
    mnist, images : path-like, optional
        The Record page's images: MNIST's training IDX files, or a folder of PNG/JPEG
        files (not both).
    data_dir : path-like
        Where recordings are written (created if missing).
    max_jobs : int
        Robot runs at the same time; more wait.
    max_upload_mb : float
        Largest request body, MB (but for ``POST /api/predict_page``).
    jobs_dir : path-like, optional
        Where robot runs write (default: a temporary folder).
    static_dir : path-like, optional
        The pages (default: the package's ``web/static``).
    max_page_mb : float
        Largest photo of a page (``POST /api/predict_page``), MB.
    refine : int or None
        Gradient steps every prediction of a model loaded from a path is refined with on
        its ink (``img2dmp serve --refine``; 0: the network's output); None: each model's
        recommendation (a card's, a run's ``reading``: ``Predictor.reading``).
    refine_unfamiliar : int or None
        The steps of images a model finds unfamiliar instead (``--refine-unfamiliar``;
        :func:`img2dmp.predict.load_model`); None: as the model recommends when
        ``refine`` is None too, else ``refine``'s.
    allowed_hosts : sequence of str
        Names the server answers to besides :data:`LOOPBACK_HOSTS` (``Host`` header;
        ``img2dmp serve`` gives its ``--host`` and ``--allowed-host``), see
        :class:`HostGuard`.
    body_timeout_s : float
        Seconds a request body may pause before it is refused (408).

    Raises
    ------
    ValueError, OSError
        For a model, image source or directory that cannot be used (naming it).
    """
    if mnist is not None and images is not None:
        raise ValueError("give --mnist DIR or --images DIR, not both")
    if not (isinstance(max_jobs, int) and max_jobs >= 1):
        raise ValueError(f"--max-jobs must be an integer >= 1, got {max_jobs!r}")
    allowed = _check_requests(max_upload_mb, body_timeout_s, allowed_hosts, max_page_mb)
    source = MnistImages(mnist) if mnist is not None else None
    source = FolderImages(images) if images is not None else source
    state = ServerState(
        load_models(models, refine, refine_unfamiliar),
        Recordings(data_dir, source),
        JobManager(jobs_dir, max_jobs),
    )
    _load_rollout_kernels(state.models.values())
    app = _new_app(state)
    _install_guards(app, max_upload_mb, max_page_mb, body_timeout_s, allowed)
    _install_error_handlers(app)
    _predict_routes(app, state)
    _page_routes(app, state, max_page_mb)
    _image_routes(app, state)
    _job_routes(app, state)
    _static_routes(app, Path(static_dir) if static_dir is not None else STATIC_DIR)
    return app


def _load_rollout_kernels(models) -> None:
    """The rollout's fused kernels loaded at the start, for every model's DMP constants
    and the default ones: every request's numbers then come from them, whatever the
    requests before it (:func:`img2dmp.dmp.rollout`'s ``"auto"`` would take torch's
    operations for a server's small calls until it had made enough of them, so the same
    request could differ in its last bits before and after). Without numba, nothing."""
    from ..dmp import DMPConfig
    from ..dmp.rollout import load_fused_kernels

    for config in {DMPConfig(), *(m.predictor.dmp_config for m in models)}:
        if not load_fused_kernels(config):
            return


def _new_app(state: ServerState) -> FastAPI:
    """The application holding ``state``, whose robot runs end with it."""

    @asynccontextmanager
    async def lifespan(app):
        yield
        state.jobs.close()

    # FastAPIOffline: FastAPI with /docs and /redoc served from the package's own copy of
    # Swagger UI and ReDoc instead of a CDN, so the API's pages work offline too.
    app = FastAPIOffline(title="img2dmp", version=__version__, lifespan=lifespan,
                         description="Draw a digit, predict its DMP, write it with a "
                         "simulated KUKA iiwa, record demonstrations (docs/WEB.md).")  # fmt: skip
    app.router.route_class = _StrictJSONRoute
    app.state.img2dmp = state
    return app


def _install_guards(app, max_upload_mb, max_page_mb, body_timeout_s, allowed) -> None:
    """The middleware that refuses before any work: bodies too large or too slow
    (:class:`BodyLimit`, a page's photo its own limit) and foreign hosts and origins
    (:class:`HostGuard`, added last so that it runs first)."""
    page_limit = (int(max_page_mb * (1 << 20)), "--max-page-mb")
    app.add_middleware(BodyLimit, max_bytes=int(max_upload_mb * (1 << 20)),
                       timeout_s=body_timeout_s,
                       paths={"/api/predict_page": page_limit})  # fmt: skip
    app.add_middleware(HostGuard, allowed=allowed)


def _check_requests(max_upload_mb, body_timeout_s, allowed_hosts,
                    max_page_mb: float = PAGE_UPLOAD_MB) -> tuple[str, ...]:  # fmt: skip
    """The bounds of a request checked (``ValueError`` naming the option); the names the
    server answers to."""
    if not 0 < max_upload_mb < float("inf"):
        raise ValueError(f"--max-upload-mb must be a number > 0, got {max_upload_mb!r}")
    if not 0 < max_page_mb < float("inf"):
        raise ValueError(f"--max-page-mb must be a number > 0, got {max_page_mb!r}")
    if not 0 < body_timeout_s < float("inf"):
        raise ValueError(f"body_timeout_s must be a number > 0, got {body_timeout_s!r}")
    allowed = (*LOOPBACK_HOSTS, *allowed_hosts)
    for name in allowed:
        if not isinstance(name, str) or not host_name(name) or "/" in name:
            raise ValueError(f"--allowed-host must be a host name or address, got {show(name)}")
    return allowed


def _json(payload: dict, status: int = 200) -> Response:
    text = json.dumps(payload, allow_nan=False, separators=(",", ":"))
    return Response(text, status, media_type="application/json")


def _predict_routes(app: FastAPI, state: ServerState) -> None:
    @app.get("/api/models")
    def models() -> dict:
        """The models served; the first is the default."""
        default = next(iter(state.models), None)
        return {"default": default, "models": [m.describe() for m in state.models.values()]}

    @app.post("/api/predict")
    def predict(body: PredictRequest) -> Response:
        """The DMP(s) of a drawn or uploaded digit, ranked, in both frames; a stroke
        model's character as its strokes, each a DMP."""
        model = state.model(body.model)
        if (body.strokes is None) == (body.image is None):
            raise WebError(422, "body: give exactly one of strokes (with canvas) and image")
        t0 = time.perf_counter()
        if body.strokes is not None:
            size = canvas_size(body.canvas)
            strokes = check_strokes(body.strokes, canvas_bounds(size), "the canvas")
            image, name = render_strokes(strokes, size), "strokes"
        else:
            image, name = decode_data_url(body.image), "image"
        try:
            pred = predict_with(model, image, body.n_points, name, clean=name == "image")
        except ValueError as e:
            raise WebError(422, str(e) if str(e).startswith(name) else f"{name}: {e}") from None
        elapsed_ms = 1e3 * (time.perf_counter() - t0)
        return Response(prediction_answer(model, pred, elapsed_ms), media_type="application/json")

    @app.post("/api/bend")
    def bend(body: BendRequest) -> Response:
        """One hypothesis of a DMP document bent: a new goal or start, shifted, scaled or
        rotated about its start, another tempo; the bent DMP as a document of its own."""
        options = {k: getattr(body, k) for k in BEND_FIELDS if getattr(body, k) is not None}
        answer = bend_answer(body.dmp, body.hypothesis, options, body.n_points)
        return Response(answer, media_type="application/json")


PAGE_NAME = "the photo's file name, for the page document's image and file name"


def _page_body(max_page_mb: float) -> dict:
    """The OpenAPI description of ``POST /api/predict_page``'s body: a file's bytes."""
    binary = {"schema": {"type": "string", "format": "binary"}}
    return {
        "requestBody": {
            "required": True,
            "description": f"The photo's PNG or JPEG file, at most {max_page_mb:g} MB "
            f"(--max-page-mb) and {MAX_IMAGE_PIXELS:,} pixels",
            "content": {kind: binary for kind in PAGE_TYPES if kind != "image/jpg"},
        }
    }


def _page_routes(app: FastAPI, state: ServerState, max_page_mb: float) -> None:
    def read(loaded: LoadedModel, raw: bytes, n_points: int, name: str | None) -> bytes:
        t0 = time.perf_counter()
        page = read_photo(loaded, raw, n_points, name, state.pages.reading)
        page_id = state.pages.add(page)
        return page_answer(loaded, page, page_id, 1e3 * (time.perf_counter() - t0))

    @app.post("/api/predict_page", openapi_extra=_page_body(max_page_mb))
    async def predict_page(
        request: Request,
        model: Annotated[str | None, Query(description="an id of GET /api/models")] = None,
        n_points: Annotated[int, Query(ge=N_POINTS_RANGE[0], le=N_POINTS_RANGE[1])] = 100,
        name: Annotated[str | None, Query(max_length=255, description=PAGE_NAME)] = None,
    ) -> Response:
        """Every handwritten character of a photo of a page, in reading order: the page
        document without the characters' DMPs; ``document`` is the whole one's URL."""
        loaded = state.model(model)
        check_page_type(request.headers.get("content-type"))
        raw = await request.body()
        answer = await run_in_threadpool(read, loaded, raw, n_points, name)
        return Response(answer, media_type="application/json")

    @app.get("/api/pages/{page_id}")
    def page_document(page_id: str) -> Response:
        """The whole page document (img2dmp-page, every character's DMP) of a page read
        lately, as a file ``<stem>_page.json``."""
        text, filename = state.pages.document(page_id)
        disposition = f'attachment; filename="{filename}"'
        return Response(text, media_type="application/json",
                        headers={"Content-Disposition": disposition})  # fmt: skip


def _image_routes(app: FastAPI, state: ServerState) -> None:
    rec = state.recordings

    @app.get("/api/images")
    def images() -> dict:
        """The Record page's image source, its size and how much of it is recorded."""
        return rec.summary()

    @app.get("/api/images/{n}", response_class=Response)
    def image(n: int) -> Response:
        """Image ``n`` as PNG, dark ink on white."""
        return Response(rec.png(n), media_type="image/png")

    @app.get("/api/images/{n}/meta")
    def meta(n: int) -> dict:
        """Index, label, size, name and whether image ``n`` is recorded."""
        return rec.meta(n)

    @app.post("/api/recordings", status_code=201)
    def record(body: RecordingRequest) -> Response:
        """Write the recording of one image (409 if it exists and ``replace`` is false)."""
        answer = rec.write(body.image, body.label, body.strokes, body.replace)
        return _json(answer, 201)


def _job_routes(app: FastAPI, state: ServerState) -> None:
    @app.post("/api/write", status_code=202)
    def write(body: WriteRequest) -> Response:
        """Queue a run of the simulated KUKA iiwa writing one hypothesis of a DMP, or a
        stroke model's character stroke by stroke."""
        from ..robot import available

        if (body.dmp is None) == (body.strokes_page is None):
            raise WebError(422, "body: give exactly one of dmp and strokes_page")
        if not available():
            raise WebError(
                503, "the robot needs pybullet: pip install -e '/path/to/img2dmp[robot]'"
            )
        if body.strokes_page is not None:
            if body.hypothesis != 1:
                raise WebError(422, "hypothesis: a stroke model's character has one (1), "
                               f"got {body.hypothesis}")  # fmt: skip
            if body.image is not None:
                raise WebError(422, "image: goes with dmp, not with strokes_page")
            return _json(submit_strokes(state.jobs, body.strokes_page, body.video), 202)
        doc, interval_s = plan_write(body.dmp, body.hypothesis, body.video)
        image = None if body.image is None else check_image(body.image)
        answer = state.jobs.submit(doc, body.hypothesis, body.video, interval_s, image)
        return _json(answer, 202)

    @app.post("/api/pages/{page_id}/write", status_code=202)
    def write_page(page_id: str, body: PageWriteRequest) -> Response:
        """Queue a run of the simulated KUKA iiwa writing every character of a page read
        lately (its whole document), ``width_mm`` wide; 422 if it does not fit."""
        from ..robot import available

        if not available():
            raise WebError(
                503, "the robot needs pybullet: pip install -e '/path/to/img2dmp[robot]'"
            )
        answer = submit_page(state.jobs, state.pages, page_id, body.width_mm,
                             body.skip_flagged, body.video)  # fmt: skip
        return _json(answer, 202)

    @app.get("/api/jobs/{job_id}")
    def job(job_id: str) -> dict:
        """A robot run's state, progress, outcome and files."""
        return state.jobs.state(job_id)

    @app.get("/api/jobs/{job_id}/files/{name}", response_class=FileResponse)
    def job_file(job_id: str, name: str) -> FileResponse:
        """One output of a finished run: paper.png, animation.gif, log.csv (and a page's
        characters.csv)."""
        return FileResponse(state.jobs.file(job_id, name))


def _static_routes(app: FastAPI, static: Path) -> None:
    def page(name: str) -> FileResponse:
        path = static / name
        if not path.is_file():
            raise WebError(404, f"page {name} is not installed")
        return FileResponse(path, media_type="text/html")

    @app.get("/", include_in_schema=False)
    def index() -> FileResponse:
        return page("index.html")

    @app.get("/record", include_in_schema=False)
    def record_page() -> FileResponse:
        return page("record.html")

    @app.get("/page", include_in_schema=False)
    def page_page() -> FileResponse:
        return page("page.html")

    app.mount("/static", StaticFiles(directory=static, check_dir=False), name="static")


__all__ = [
    "BendRequest",
    "BodyLimit",
    "HostGuard",
    "PredictRequest",
    "RecordingRequest",
    "WriteRequest",
    "create_app",
    "host_name",
]
