"""The one kind of refusal the web API gives: a status code and one line naming the
field or value (``{"detail": "..."}``, docs/WEB.md). No FastAPI here, so the modules
below the app (and the robot's job processes) can raise it."""

from __future__ import annotations

from ..errors import show


class WebError(Exception):
    """A request refused with ``status`` (4xx, or 503) and a one-line ``detail``."""

    def __init__(self, status: int, detail: str):
        super().__init__(detail)
        self.status = int(status)
        self.detail = one_line(detail)


def one_line(text: str, limit: int = 500) -> str:
    """``text`` as one line of at most ``limit`` characters."""
    line = " ".join(part.strip() for part in str(text).splitlines() if part.strip())
    return line if len(line) <= limit else line[: limit - 3] + "..."


__all__ = ["WebError", "one_line", "show"]
