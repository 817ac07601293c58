"""Progress for people: live bars on a terminal, a few plain lines in a log file.

Every long step of img2dmp (generation, data preparation, training, robot runs) reports
through :func:`bar` and :func:`say`. On a terminal (standard error is a TTY) :func:`bar`
is a live ``tqdm`` bar. Otherwise, piped into a file or run by CI, it prints nothing
while it runs and one summary line when it closes, so ``make demo > log 2>&1`` stays a
short, readable log; the training loop adds one line per epoch with :func:`say`.
"""

from __future__ import annotations

import os
import sys
import time


def live() -> bool:
    """Whether progress may redraw itself: standard error is a terminal."""
    if os.environ.get("IMG2DMP_PROGRESS") == "lines":
        return False
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed stream
        return False


def say(message: str) -> None:
    """One line of progress on standard error, above any live bar."""
    if live():
        from tqdm.auto import tqdm

        tqdm.write(message, file=sys.stderr)
    else:
        print(message, file=sys.stderr, flush=True)


class _Lines:
    """The non-terminal stand-in of a ``tqdm`` bar: counts quietly, one line at the end."""

    def __init__(self, iterable, desc: str, total, unit: str, initial: int, report: bool):
        self.iterable, self.desc, self.total, self.unit = iterable, desc, total, unit
        self.n = initial
        self._start_n = initial
        self._report = report
        self._postfix = ""
        self._t0 = time.perf_counter()
        self._closed = False

    def __iter__(self):
        for item in self.iterable:
            yield item
            self.n += 1
        self.close()

    def __len__(self) -> int:
        return len(self.iterable) if self.iterable is not None else int(self.total or 0)

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, k: int = 1) -> None:
        self.n += k

    def set_postfix(self, ordered_dict=None, refresh: bool = True, **kwargs) -> None:
        items = dict(ordered_dict or {}, **kwargs)
        self._postfix = ", ".join(f"{k}={v}" for k, v in items.items())

    def set_description(self, desc: str, refresh: bool = True) -> None:
        self.desc = desc

    def refresh(self) -> None:
        pass

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        if self._report and self.n > self._start_n:
            done = self.n - self._start_n
            unit = self.unit if done == 1 or self.unit.endswith("s") else f"{self.unit}s"
            tail = f" ({self._postfix})" if self._postfix else ""
            say(f"{self.desc}: {done} {unit} in {time.perf_counter() - self._t0:.1f} s{tail}")


def bar(
    iterable=None,
    *,
    desc: str = "",
    total: int | None = None,
    unit: str = "it",
    enabled: bool = True,
    leave: bool = True,
    initial: int = 0,
):
    """A progress bar over ``iterable`` (or updated by hand with ``update``).

    ``enabled=False`` shows nothing at all. ``leave=False`` marks an inner bar (one
    epoch's batches): on a terminal it disappears when done, in a log it prints nothing.
    """
    if enabled and live():
        from tqdm.auto import tqdm

        return tqdm(
            iterable,
            desc=desc,
            total=total,
            unit=unit,
            leave=leave,
            initial=initial,
            file=sys.stderr,
            dynamic_ncols=True,
        )
    return _Lines(iterable, desc, total, unit, initial, report=enabled and leave)


__all__ = ["bar", "live", "say"]
