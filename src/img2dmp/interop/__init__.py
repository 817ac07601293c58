"""Bridges to the DMP libraries people already use (extra ``interop``; docs/INTEROP.md).

- :func:`to_movement_primitives`, :func:`from_movement_primitives` - DFKI's
  ``movement_primitives.dmp.DMP`` (one object per DMP; a batch is a list).
- :func:`to_mp_pytorch`, :func:`from_mp_pytorch` - MP_PyTorch's ``ProDMP`` or ``DMP``
  (one object per batch).

Exports map the parameters analytically where the two ODEs coincide (always, except a
ProDMP of a non-critically damped DMP, which is re-fitted); imports read them off a peer
configured as img2dmp's DMP and re-fit img2dmp's DMP to the peer's rollout otherwise.
Both can measure the largest distance between the peer's rollout and img2dmp's
(:class:`PeerExport`, :class:`PeerImport` ``error_px``). The peers are imported only
here, and only when installed: without them these functions raise ``ImportError``.
"""

from ._common import PeerExport, PeerImport
from ._movement_primitives import PhaseMatchedDMP, from_movement_primitives, to_movement_primitives
from ._mp_pytorch import from_mp_pytorch, to_mp_pytorch

__all__ = [
    "PeerExport",
    "PeerImport",
    "PhaseMatchedDMP",
    "from_movement_primitives",
    "from_mp_pytorch",
    "to_movement_primitives",
    "to_mp_pytorch",
]
