"""Omniglot's drawings as an import source: now :mod:`img2dmp.data.sources.omniglot`
(the names it always had, for code that imports them from here)."""

from .sources.omniglot import (  # noqa: F401
    ALIGN_BELOW,
    ALIGN_BLUR_PX,
    DRAWER_SPLITS,
    FORMAT,
    MAX_CLOCK_STEP_BACK_MS,
    MAX_IMAGE_BYTES,
    MAX_OUTSIDE,
    MAX_SHIFT_PX,
    SHIFT_STEP_PX,
    SPLIT_BY,
    STROKE_SUFFIX,
    ArchiveMember,
    Entry,
    find_omniglot,
    fit_to_image,
    image_of,
    omniglot_trees,
    onto_ink,
    parse_strokes,
    read_strokes,
    tree_files,
    tree_name,
)
