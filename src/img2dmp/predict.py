"""From images to DMPs with a trained network (the inference side of Pahič et al.).

- :class:`Predictor` - a loaded model: :meth:`Predictor.load` (run directory or
  checkpoint), :meth:`~Predictor.predict_images` (prepared ``[B, H, W]`` images to
  :class:`~img2dmp.dmp.DMPParams`), :meth:`~Predictor.predict_paths` (image files),
  :meth:`~Predictor.trajectories` (rollout at given or evenly spaced time stamps).
- :func:`prepare_image` - bring an arbitrary PNG/JPEG (any size, dark ink on light paper
  or light on dark) to the model's input the way the training images were made.
- :func:`write_prediction` - JSON + CSV (+ overlay PNG) for one image.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import torch

from .checkpoint import (
    CheckpointError,
    atomic_write_text,
    load_checkpoint,
    load_weights_into,
)
from .dmp import DMPConfig, DMPParams, rollout
from .nn import ModelConfig, ParamNormaliser, build_model
from .nn.costs import dmp_trajectory

# How a prepared image frames the ink: the ink's bounding box, padded to a square, fills
# the image except for this share of the side on each border (see prepare_image). A model
# stores the median framing of its training images (ink_margin); this is the fallback,
# that of the synthetic digits at their default size.
DEFAULT_MARGIN = 0.175
# A pixel counts as ink for the bounding box when it is above this share of the range.
INK_THRESHOLD = 0.2


def ink_margin(images: np.ndarray) -> float:
    """Median share of the side left empty around the ink (its bounding box's longer side)
    in prepared images ``[M, H, W]``; what :func:`prepare_image` reproduces."""
    margins = []
    for a in np.asarray(images):
        rows, cols = np.nonzero(a > INK_THRESHOLD)
        if rows.size == 0:
            continue
        side = max(
            (rows.max() - rows.min() + 1) / a.shape[0], (cols.max() - cols.min() + 1) / a.shape[1]
        )
        margins.append((1.0 - side) / 2.0)
    return float(np.clip(np.median(margins), 0.0, 0.45)) if margins else DEFAULT_MARGIN


def stroke_width(image: np.ndarray, upsample: int = 4) -> float:
    """Estimated pen width in pixels of the ink in a grey image ``[H, W]`` (ink high).

    The image is scaled to [0, 1], enlarged ``upsample`` times (bilinear) so that thin
    strokes span several pixels, and thresholded at half ink; for a stroke of width W the
    distance of its pixels to the background runs evenly from 0 to W / 2, so W is about
    four times their mean. Returns 0 for an image without ink.
    """
    from PIL import Image
    from scipy.ndimage import distance_transform_edt

    a = np.asarray(image, dtype=np.float32)
    top = float(a.max()) if a.size else 0.0
    if top <= 0:
        return 0.0
    big = Image.fromarray(a / top, mode="F").resize(
        (a.shape[1] * upsample, a.shape[0] * upsample), Image.Resampling.BILINEAR
    )
    mask = np.asarray(big) > 0.5
    if not mask.any():
        return 0.0
    return float(4.0 * distance_transform_edt(mask)[mask].mean() / upsample)


def typical_stroke_width(images: np.ndarray, limit: int = 500) -> float:
    """Median :func:`stroke_width` over (up to ``limit`` of) prepared images ``[M, H, W]``."""
    widths = [w for w in (stroke_width(a) for a in np.asarray(images)[:limit]) if w > 0]
    return float(np.median(widths)) if widths else 0.0


def _match_stroke_width(crop: np.ndarray, scale: float, target_px: float) -> np.ndarray:
    """Thicken or thin the ink of ``crop`` so that it is ``target_px`` wide after resizing.

    ``scale`` is output pixels per crop pixel. Grey-level dilation (erosion) with a disc
    widens (narrows) every stroke by twice the disc's radius and keeps its ink profile.
    """
    from scipy.ndimage import grey_dilation, grey_erosion

    width_out = stroke_width(crop, upsample=1 if scale < 0.5 else 4) * scale
    if width_out <= 0 or abs(width_out - target_px) < 0.25:
        return crop
    radius = abs(target_px - width_out) / 2.0 / scale  # in crop pixels
    if width_out > target_px:  # never erode a stroke away: keep at least half its width
        radius = min(radius, width_out / scale / 4.0)
    r = int(np.ceil(radius))
    if r < 1:
        return crop
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    disc = (xx**2 + yy**2) <= radius**2 + 1e-9
    op = grey_dilation if width_out < target_px else grey_erosion
    return op(np.pad(crop, r), footprint=disc)


def _decode(path: Path) -> np.ndarray:
    """Grey levels in [0, 1] of an image file; transparency is composited on white."""
    from PIL import Image, UnidentifiedImageError

    if not path.is_file():
        raise FileNotFoundError(f"image file {path} does not exist")
    try:
        with Image.open(path) as im:
            im.load()
            if im.mode in ("RGBA", "LA", "PA") or (im.mode == "P" and "transparency" in im.info):
                rgba = im.convert("RGBA")
                bg = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
                im = Image.alpha_composite(bg, rgba)
            grey = np.asarray(im.convert("F"), dtype=np.float64)
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as e:
        raise ValueError(f"cannot decode image file {path}: {e}") from e
    if grey.ndim != 2 or min(grey.shape) < 2:
        raise ValueError(f"image file {path} has unusable size {grey.shape}")
    top = grey.max()
    return grey / (255.0 if top > 1.0 else 1.0)


def prepare_image(
    source,
    image_size=(40, 40),
    *,
    margin: float = DEFAULT_MARGIN,
    stroke_width_px: float | None = None,
    name: str | None = None,
) -> np.ndarray:
    """Bring an image of one handwritten digit to the network's input.

    Steps: grey levels in [0, 1]; polarity from the border (if the median of the outer
    ring of pixels is brighter than the median of the whole image, the ink is dark on
    light paper and the image is inverted); the background level (border median) is
    subtracted and the ink scaled to 1; crop to the bounding box of pixels above
    ``INK_THRESHOLD``; pad to a square around the box's centre; add ``margin`` of the
    side on every border; optionally thicken or thin the strokes to the training images'
    pen width (a thin pen photographed at high resolution would otherwise shrink to faint
    hairlines); resize with area averaging (anti-aliased, as the training strokes are);
    scale so the darkest ink is 1.

    Parameters
    ----------
    source : path or array [H, W]
        PNG/JPEG file (any size, RGB, grey or with transparency) or a grey-level array.
    image_size : (H, W)
        The model's input size.
    margin : float
        Share of the side left empty on each border, in [0, 0.45].
    stroke_width_px : float, optional
        Pen width, in output pixels, to bring the strokes to (a model's
        ``stroke_width_px``, see :func:`typical_stroke_width`); None keeps the width.
    name : str, optional
        Used in error messages for arrays.

    Returns
    -------
    ndarray float32 [H, W]
        Ink = 1, background = 0.
    """
    from PIL import Image

    if isinstance(source, (str, os.PathLike)):
        label = str(source)
        grey = _decode(Path(source))
    else:
        label = name or "image array"
        grey = np.asarray(source, dtype=np.float64)
        if grey.ndim != 2:
            raise ValueError(f"{label} must be a 2-D grey-level array, got shape {grey.shape}")
        if not np.isfinite(grey).all():
            raise ValueError(f"{label} contains NaN or inf")
        if grey.max() > 1.0:
            grey = grey / 255.0
    if not 0 <= margin <= 0.45:
        raise ValueError(f"margin must be in [0, 0.45], got {margin!r}")
    if stroke_width_px is not None and not (np.isfinite(stroke_width_px) and stroke_width_px > 0):
        raise ValueError(f"stroke_width_px must be a positive number, got {stroke_width_px!r}")
    h_out, w_out = (int(s) for s in image_size)
    ring = max(1, round(0.05 * min(grey.shape)))
    border = np.concatenate(
        [grey[:ring].ravel(), grey[-ring:].ravel(), grey[:, :ring].ravel(), grey[:, -ring:].ravel()]
    )
    if np.median(border) > np.median(grey) or np.median(border) > 0.5:
        grey = 1.0 - grey  # dark ink on light paper
        border = 1.0 - border
    ink = grey - np.median(border)
    top = ink.max()
    if top < 0.05:
        raise ValueError(f"{label} shows no ink (contrast {top:.3f} against the background)")
    ink = np.clip(ink / top, 0.0, 1.0)
    rows, cols = np.nonzero(ink > INK_THRESHOLD)
    r0, r1, c0, c1 = rows.min(), rows.max() + 1, cols.min(), cols.max() + 1
    crop = ink[r0:r1, c0:c1]
    if stroke_width_px is not None:
        side = max(crop.shape) / (1.0 - 2.0 * margin)
        crop = _match_stroke_width(crop, max(h_out, w_out) / side, float(stroke_width_px))
        rows, cols = np.nonzero(crop > INK_THRESHOLD)  # re-frame the widened ink
        crop = crop[rows.min() : rows.max() + 1, cols.min() : cols.max() + 1]
    side = max(crop.shape)
    inner = side / (1.0 - 2.0 * margin)
    total = int(np.ceil(inner))
    canvas = np.zeros((total, total))
    top_off = (total - crop.shape[0]) // 2
    left_off = (total - crop.shape[1]) // 2
    canvas[top_off : top_off + crop.shape[0], left_off : left_off + crop.shape[1]] = crop
    im = Image.fromarray(canvas.astype(np.float32), mode="F")
    out = np.asarray(
        im.resize(
            (w_out, h_out),
            Image.Resampling.BOX if total >= max(h_out, w_out) else Image.Resampling.BILINEAR,
        ),
        dtype=np.float64,
    )
    out = np.clip(out / max(out.max(), 1e-12), 0.0, 1.0)
    return out.astype(np.float32)


class Predictor:
    """A trained network with its output normalisation and DMP constants.

    Attributes
    ----------
    model : EncoderDecoder
    normaliser : ParamNormaliser
    dmp_config : DMPConfig
    image_size : (H, W)
    meta : dict
        The checkpoint's JSON record.
    """

    def __init__(self, model, normaliser: ParamNormaliser, dmp_config: DMPConfig, meta: dict):
        self.model = model.eval()
        self.normaliser = normaliser
        self.dmp_config = dmp_config
        self.meta = meta
        self.image_size = tuple(int(s) for s in model.image_size)

    @classmethod
    def load(cls, path: str | os.PathLike, name: str = "best") -> Predictor:
        """Load from a run directory (its ``checkpoints/<name>``) or a checkpoint file.

        Raises ``FileNotFoundError`` if nothing is there and :class:`CheckpointError`
        (a ``ValueError``) if the file is corrupt, truncated or of another architecture.
        """
        ckpt = load_checkpoint(path, name)
        try:
            mcfg = ModelConfig.from_dict(ckpt.meta["model"])
            normaliser = ParamNormaliser.from_dict(ckpt.meta["normaliser"])
            dmp_config = DMPConfig.from_dict(ckpt.meta["dmp_config"])
        except (KeyError, TypeError, ValueError) as e:
            raise CheckpointError(f"checkpoint {ckpt.path}: invalid record ({e})") from e
        if mcfg.n_outputs != dmp_config.n_params:
            raise CheckpointError(
                f"checkpoint {ckpt.path}: model has {mcfg.n_outputs} outputs but the DMP "
                f"config needs {dmp_config.n_params}"
            )
        model = build_model(mcfg)
        load_weights_into(model, ckpt)
        return cls(model, normaliser, dmp_config, ckpt.meta)

    @property
    def margin(self) -> float:
        """Framing of the training images, used by :func:`prepare_image`."""
        return float(self.meta.get("ink_margin", DEFAULT_MARGIN))

    @property
    def stroke_width(self) -> float | None:
        """Typical pen width of the training images in pixels (None: not recorded)."""
        w = self.meta.get("stroke_width_px")
        return float(w) if w else None

    def _check_images(self, images) -> torch.Tensor:
        x = torch.as_tensor(np.asarray(images, dtype=np.float32))
        if x.ndim == 2:
            x = x[None]
        if x.ndim != 3 or tuple(x.shape[1:]) != self.image_size:
            raise ValueError(
                f"images must have shape [B, {self.image_size[0]}, {self.image_size[1]}], "
                f"got {tuple(x.shape)} (use prepare_image for other sizes)"
            )
        if not bool(torch.isfinite(x).all()):
            raise ValueError("images contain NaN or inf")
        return x

    @torch.inference_mode()
    def predict_normalised(self, images, batch_size: int = 4096) -> torch.Tensor:
        """Network output ``[B, P]`` (normalised units) for prepared images ``[B, H, W]``."""
        x = self._check_images(images)
        outs = [self.model(x[lo : lo + batch_size]) for lo in range(0, x.shape[0], batch_size)]
        return torch.cat(outs) if outs else torch.zeros(0, self.dmp_config.n_params)

    def predict_images(self, images, batch_size: int = 4096) -> DMPParams:
        """DMPs for prepared images.

        Parameters
        ----------
        images : array float32 [B, H, W] (or [H, W])
            In [0, 1], ink = 1, at the model's ``image_size``.

        Returns
        -------
        DMPParams
            NumPy float64, batch shape ``[B]``.
        """
        z = self.predict_normalised(images, batch_size)
        v = self.normaliser.denormalise_vector(z.double())
        n, d = self.dmp_config.n_kernels, self.dmp_config.n_dims
        return DMPParams.from_vector(v.numpy(), n, d)

    def predict_paths(
        self, paths, match_stroke_width: bool = True
    ) -> list[tuple[DMPParams, np.ndarray]]:
        """One DMP (batch shape ``[]``) and the prepared image for every image file.

        With ``match_stroke_width`` (and a model that recorded it) the strokes are brought
        to the training images' pen width, see :func:`prepare_image`.
        """
        width = self.stroke_width if match_stroke_width else None
        images = np.stack(
            [
                prepare_image(p, self.image_size, margin=self.margin, stroke_width_px=width)
                for p in paths
            ]
        )
        params = self.predict_images(images)
        return [(params[i], images[i]) for i in range(len(images))]

    def trajectories(self, params: DMPParams, times=None, n_points: int = 100):
        """Roll DMPs out (exact solution, eqs. 3-7).

        Parameters
        ----------
        params : DMPParams
            Batch shape ``[*batch]``.
        times : array [*batch, T] or [T], optional
            Seconds from the start; default ``n_points`` evenly spaced over ``[0, tau]``.

        Returns
        -------
        times : ndarray [*batch, T]
        y : ndarray [*batch, T, d]
        """
        p = params.to_torch(torch.float64)
        if times is None:
            u = torch.linspace(0.0, 1.0, n_points, dtype=torch.float64)
            t = p.tau[..., None] * u  # [*batch, T]
        else:
            t = torch.as_tensor(np.asarray(times), dtype=torch.float64)
        y = rollout(p, t, self.dmp_config)
        t = t.expand(*y.shape[:-1])
        return t.numpy(), y.numpy()

    @torch.inference_mode()
    def trajectories_for_images(self, images, times, batch_size: int = 4096) -> np.ndarray:
        """The network's DMP trajectories ``[B, T, d]`` at given time stamps ``[B, T]``."""
        x = self._check_images(images)
        t = torch.as_tensor(np.asarray(times), dtype=torch.float32)
        out = []
        for lo in range(0, x.shape[0], batch_size):
            z = self.model(x[lo : lo + batch_size])
            out.append(dmp_trajectory(z, t[lo : lo + batch_size], self.normaliser, self.dmp_config))
        return torch.cat(out).numpy()


def prediction_record(params: DMPParams, times: np.ndarray, y: np.ndarray, source: str) -> dict:
    """JSON-ready description of one predicted DMP and its sampled trajectory."""
    return {
        "image": source,
        "dmp": params.to_dict(),
        "vector": np.asarray(params.to_vector()).tolist(),
        "trajectory": {"t": times.tolist(), "y": y.tolist()},
    }


def write_prediction(
    out_dir: str | os.PathLike,
    stem: str,
    record: dict,
    image: np.ndarray | None = None,
) -> list[Path]:
    """Write ``<stem>_dmp.json``, ``<stem>_trajectory.csv`` and, with ``image``, an overlay
    ``<stem>_overlay.png`` (the image with the DMP path in red). Atomic writes."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    p = out / f"{stem}_dmp.json"
    atomic_write_text(p, json.dumps(record, indent=1) + "\n")
    written.append(p)
    t = np.asarray(record["trajectory"]["t"])
    y = np.asarray(record["trajectory"]["y"])
    cols = ["t_s", "x_px", "y_px"] + [f"y{k}" for k in range(2, y.shape[1])]
    lines = [",".join(cols)] + [",".join(f"{v:.6g}" for v in (t[i], *y[i])) for i in range(len(t))]
    p = out / f"{stem}_trajectory.csv"
    atomic_write_text(p, "\n".join(lines) + "\n")
    written.append(p)
    if image is not None:
        from .evaluate import overlay_figure

        p = out / f"{stem}_overlay.png"
        overlay_figure(p, image[None], None, y[None], titles=[stem], cell_inches=3.0)
        written.append(p)
    return written


__all__ = [
    "DEFAULT_MARGIN",
    "Predictor",
    "prediction_record",
    "prepare_image",
    "write_prediction",
]
