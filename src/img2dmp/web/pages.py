"""Pages read in the browser: a photo's bytes in, the page document out (docs/WEB.md).

:func:`read_photo` decodes an upload and reads it with
:meth:`img2dmp.predict.Predictor.predict_page`, one page at a time per server (a 24-MP
photo decodes to 72 MB) and one prediction at a time per model; :func:`page_answer` is
the JSON body of ``POST /api/predict_page``: the page document without the characters'
DMPs (a tenth of its size). :class:`PageStore` keeps the latest pages read, so that
``GET /api/pages/{id}`` gives the whole document, DMPs and all, as
``img2dmp predict --page`` writes it (``<stem>_page.json``).
"""

from __future__ import annotations

import collections
import json
import re
import secrets
import threading
from pathlib import PurePath

from .errors import WebError, show
from .models import LoadedModel
from .strokes import decode_image_bytes

#: Largest photo of a page, MB (``--max-page-mb``): a 24-MP phone photo is 5-15 MB as
#: JPEG and up to about 50 MB as PNG. Every other request keeps ``--max-upload-mb``.
PAGE_UPLOAD_MB = 64.0
#: Pages kept for ``GET /api/pages/{id}``; the oldest is dropped first.
MAX_KEPT_PAGES = 16
#: What ``Content-Type`` a photo may be sent as (none at all is taken as the file too).
PAGE_TYPES = ("image/jpeg", "image/jpg", "image/png", "application/octet-stream")


class PageStore:
    """The latest pages read (at most ``max_pages``), by id, for their full documents.

    A page is kept as its :class:`~img2dmp.page.PagePrediction` (without the page
    picture's copy of the photo) and written out as JSON only when it is asked for.
    ``reading`` is held while a photo is decoded and read: one page at a time.
    """

    def __init__(self, max_pages: int = MAX_KEPT_PAGES):
        self.max_pages = int(max_pages)
        self.reading = threading.Lock()
        self._pages: collections.OrderedDict = collections.OrderedDict()
        self._lock = threading.Lock()

    def add(self, page) -> str:
        """Keep ``page``; its id."""
        page_id = secrets.token_hex(8)
        page.preview = None  # only the page picture draws on it
        with self._lock:
            self._pages[page_id] = page
            while len(self._pages) > self.max_pages:
                self._pages.popitem(last=False)
        return page_id

    def document(self, page_id: str) -> tuple[str, str]:
        """The page document's text (``PagePrediction.to_json``) and its file name; 404
        for a page not (or no longer) kept."""
        with self._lock:
            page = self._pages.get(page_id)
        if page is None:
            raise WebError(
                404,
                f"page {show(page_id)}: not kept (the server keeps the last {self.max_pages} "
                "pages read); read the photo again",
            )
        return page.to_json(), document_name(page.source)


def clean_name(name: str | None) -> str | None:
    """A photo's file name as the page keeps it: its last part (no folders, whatever the
    slashes), letters and digits of any script, spaces and ``._-()`` kept, anything else
    ``_``, no leading dots or spaces; None for none left (``../../../tmp/evil.png`` ->
    ``evil.png``)."""
    last = PurePath((name or "").replace("\\", "/")).name
    safe = re.sub(r"[^\w .()-]+", "_", last).lstrip(". ")[:255].rstrip()
    return safe or None


def document_name(name: str | None) -> str:
    """``<stem>_page.json`` for a photo's file name (its stem in safe characters)."""
    stem = re.sub(r"[^A-Za-z0-9._-]+", "_", PurePath(name or "").stem).strip("._")[:100]
    return f"{stem or 'page'}_page.json"


def check_page_type(content_type: str | None) -> None:
    """415 for a body that is not sent as the photo's own bytes (e.g. JSON or a form)."""
    kind = (content_type or "").split(";")[0].strip().lower()
    if kind and kind not in PAGE_TYPES:
        raise WebError(
            415,
            f"Content-Type: send the photo's own bytes as image/jpeg or image/png, "
            f"got {show(kind)}",
        )


def read_photo(model: LoadedModel, raw: bytes, n_points: int, name: str | None, reading):
    """The :class:`~img2dmp.page.PagePrediction` of the photo whose file is ``raw``.

    ``name`` (the file's name, or None) becomes the document's ``"image"``, cleaned
    (:func:`clean_name`); ``reading`` is held throughout.

    Raises
    ------
    WebError
        422 for an empty body, bytes that are no PNG or JPEG of at most
        ``MAX_IMAGE_PIXELS`` pixels, or a photo the library refuses (naming it).
    """
    name = clean_name(name)
    label = name or "photo"
    if not raw:
        raise WebError(422, "body: is empty; send the photo's bytes (a PNG or JPEG file)")
    with reading:
        image = decode_image_bytes(raw, label)
        try:
            with model.lock:
                page = model.predictor.predict_page(image, n_points=n_points, name=label)
        except ValueError as e:
            raise WebError(422, str(e) if str(e).startswith(label) else f"{label}: {e}") from None
    page.source = name
    return page


def page_answer(model: LoadedModel, page, page_id: str, elapsed_ms: float) -> bytes:
    """The JSON body of ``POST /api/predict_page`` (docs/WEB.md)."""
    answer = {
        "model": model.id,
        "elapsed_ms": round(float(elapsed_ms), 3),
        "id": page_id,
        "document": f"/api/pages/{page_id}",
        "filename": document_name(page.source),
        "page": page.to_document(dmps=False),
    }
    return json.dumps(answer, allow_nan=False, separators=(",", ":")).encode("utf-8")


__all__ = [
    "MAX_KEPT_PAGES",
    "PAGE_UPLOAD_MB",
    "PageStore",
    "check_page_type",
    "clean_name",
    "document_name",
    "page_answer",
    "read_photo",
]
