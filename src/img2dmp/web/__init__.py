"""The browser front end's back end: ``img2dmp serve`` (docs/WEB.md).

- :func:`create_app` - the FastAPI application (:mod:`.app`): predictions of drawn or
  uploaded digits, pages read from photos (:mod:`.pages`), robot runs in their own
  processes (:mod:`.jobs`), the Record page's images and recordings (:mod:`.recordings`),
  the static pages in ``web/static/``.

Needs the optional extra ``pip install -e '/path/to/img2dmp[web]'`` (FastAPI, uvicorn); importing
this package does not import them, :func:`create_app` does.
"""

from __future__ import annotations

__all__ = ["create_app"]


def __getattr__(name: str):
    if name == "create_app":
        from .app import create_app

        return create_app
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
