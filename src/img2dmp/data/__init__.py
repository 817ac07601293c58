"""Where examples come from: synthetic digits, rendering, affine transforms, the file format.

Public surface:

- :mod:`.store` - :class:`DigitData`, :func:`save_dataset`, :func:`load_dataset`
  (the data-set file of ``docs/CONTRACTS.md``)

Further modules are imported on demand (``from img2dmp.data.render import ...``) so
that reading a data set does not pay for torch-heavy imports it does not need.
"""

from .store import SPLITS, DigitData, load_dataset, save_dataset

__all__ = ["SPLITS", "DigitData", "load_dataset", "save_dataset"]
