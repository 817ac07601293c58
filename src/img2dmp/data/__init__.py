"""Where examples come from: synthetic digits, rendering, affine transforms, the file format.

- :mod:`.store` - :class:`DigitData`, :func:`save_dataset`, :func:`load_dataset`
  (the data-set file of ``docs/CONTRACTS.md``, described in ``docs/DATASET.md``)
- :mod:`.synthetic` - digits from lines and elliptic arcs with minimum-jerk timing:
  ``SyntheticConfig``, ``generate``, ``generate_dataset`` (the paper's first experiments)
- :mod:`.render` - ``render_paths`` (the one rendering function), ``gaussian_filter``,
  ``salt_and_pepper``
- :mod:`.affine` - joint image/path affine transforms: ``AffineRanges``, ``sample_affine``,
  ``warp_images``, ``warp_points``
- :mod:`.torch_data` - ``StoredDigits`` (map-style) and ``SyntheticDigitStream``
  (fresh samples on the fly)
- :mod:`.plotting` - ``plot_grid`` / ``save_grid``: images with paths drawn over them

Only :mod:`.store` is imported here, so that reading a data set does not pay for the
others; import the rest from their modules (``from img2dmp.data.render import ...``).
"""

from .store import SPLITS, DigitData, load_dataset, save_dataset

__all__ = ["SPLITS", "DigitData", "load_dataset", "save_dataset"]
