"""The one place that imports pybullet, with a clear message when it is missing."""

from __future__ import annotations

INSTALL_HINT = (
    "img2dmp.robot needs pybullet, an optional dependency: install it with "
    "`pip install img2dmp[robot]` (or `pip install pybullet==3.2.7`)"
)


def available() -> bool:
    """True if pybullet and pybullet_data can be imported."""
    try:
        require()
    except ImportError:
        return False
    return True


def require():
    """Return the modules ``(pybullet, pybullet_data)``; raise ``ImportError`` if missing."""
    try:
        import pybullet
        import pybullet_data
    except ImportError as e:
        raise ImportError(f"{INSTALL_HINT} ({e})") from e
    return pybullet, pybullet_data
