"""docs/RELIABILITY.md names, for each guarantee, the tests that prove it: every test it
names must exist, so that the table cannot drift from the suite."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _named_tests(text: str) -> list[tuple[str, str]]:
    """(file, test) pairs; ``::name`` without a file refers to the last file named."""
    pairs, current = [], None
    for m in re.finditer(r"`(?:(test_\w+\.py))?(?:::)?(test_\w+)?(?:\[[^\]]*\])?`", text):
        file, test = m.group(1), m.group(2)
        if file:
            current = file
        if test and current:
            pairs.append((current, test))
    return pairs


def test_every_test_the_reliability_table_names_exists():
    text = (ROOT / "docs" / "RELIABILITY.md").read_text()
    pairs = _named_tests(text)
    assert len(pairs) >= 40, "the table should name the tests that prove its guarantees"
    missing = []
    for file, test in pairs:
        source = (ROOT / "tests" / file).read_text() if (ROOT / "tests" / file).is_file() else ""
        if not re.search(rf"^def {test}\(", source, re.MULTILINE):
            missing.append(f"{file}::{test}")
    assert not missing, f"docs/RELIABILITY.md names tests that do not exist: {missing}"
