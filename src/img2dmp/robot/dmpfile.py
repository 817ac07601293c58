"""The DMP file ``img2dmp write --dmp`` executes: the one DMP file of img2dmp.

Its home is :mod:`img2dmp.data.dmpfile` (format ``"img2dmp-dmp"``, version 2: what
``img2dmp predict --out`` writes, with the hypotheses, trajectories and the user's image
frame as optional fields; older files are converted as they are read). The names are
re-exported here, where the robot's users have found them; docs/ROBOT.md describes the
format.

The robot executes the top hypothesis (``params``) unless another rank is asked for
(``load_dmp_json(path, hypothesis=k)``, ``img2dmp write --dmp FILE --hypothesis k``),
in the frame of ``image_size``: the model's input for a prediction, so that
``--writing-height-mm`` is the height of that image.
"""

from __future__ import annotations

from ..data.dmpfile import (
    FORMAT,
    MAX_FILE_BYTES,
    MAX_KERNELS,
    VERSION,
    DMPFile,
    load_dmp_json,
    read_dmp_file,
    save_dmp_json,
)

__all__ = [
    "FORMAT",
    "MAX_FILE_BYTES",
    "MAX_KERNELS",
    "VERSION",
    "DMPFile",
    "load_dmp_json",
    "read_dmp_file",
    "save_dmp_json",
]
