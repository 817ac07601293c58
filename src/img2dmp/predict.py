"""From images to DMPs with a trained network (the inference side of Pahič et al.).

- :class:`Predictor` - a loaded model: :meth:`Predictor.load` (run directory or
  checkpoint), :meth:`~Predictor.predict_images` (prepared ``[B, H, W]`` images to
  :class:`~img2dmp.dmp.DMPParams`), :meth:`~Predictor.predict_paths` (image files),
  :meth:`~Predictor.trajectories` (rollout at given or evenly spaced time stamps).
- :func:`prepare_image` - bring an arbitrary PNG/JPEG (any size, dark ink on light paper
  or light on dark) to the model's input the way the training images were made
  (defined in :mod:`img2dmp.data.images`, with :func:`ink_margin`, :func:`stroke_width`
  and :func:`typical_stroke_width`; still importable from here).
- :func:`write_prediction` - JSON + CSV (+ overlay PNG) for one image.

The network runs through :mod:`img2dmp.nn.inference`, the batched path that evaluation
and training's validation use too.
"""

from __future__ import annotations

import json
import numbers
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
from .data.images import (  # noqa: F401  (re-exported: their home was this module)
    DEFAULT_MARGIN,
    INK_THRESHOLD,
    _decode,
    _match_stroke_width,
    ink_margin,
    prepare_image,
    stroke_width,
    typical_stroke_width,
)
from .dmp import DMPConfig, DMPParams, rollout
from .nn import ModelConfig, ParamNormaliser, build_model
from .nn.inference import dmp_trajectories, network_outputs, rollout_outputs
from .nn.model import split_hypotheses
from .nn.refine import RefineOptions, refine

#: Instants over a DMP's duration at which refinement compares its path with the ink.
REFINE_POINTS = 100
#: Most refinement steps per prediction (``--refine``; 30 is the default of refine).
MAX_REFINE_STEPS = 10_000
#: Largest batch the network is run on at once.
MAX_BATCH_SIZE = 1 << 20
#: Most samples of one trajectory (``n_points``, ``img2dmp predict --points``): a record
#: holds them as JSON text, about 60 bytes a sample and hypothesis.
MAX_POINTS = 100_000


def check_count(name: str, value, lo: int, hi: int) -> int:
    """``value`` as an int if it is a whole number in ``[lo, hi]``, else ``ValueError``
    naming ``name``, the value and the range."""
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not lo <= value <= hi:
        raise ValueError(f"{name} must be a whole number in [{lo}, {hi}], got {value!r}")
    return int(value)


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
    refine_options : RefineOptions or None
        If set, every prediction is refined on its image (:func:`img2dmp.nn.refine.refine`:
        a few gradient steps that pull the DMP onto the ink near the network's output);
        None (default): the network's output as it is.
    """

    def __init__(
        self,
        model,
        normaliser: ParamNormaliser,
        dmp_config: DMPConfig,
        meta: dict,
        refine_options: RefineOptions | None = None,
    ):
        self.model = model.eval()
        self.normaliser = normaliser
        self.dmp_config = dmp_config
        self.meta = meta
        self.image_size = tuple(int(s) for s in model.image_size)
        self.refine_options = refine_options

    def _refined(self, z: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """``z [N, P]`` refined on images ``x [N, H, W]`` (unchanged without refinement),
        compared with the ink at 100 instants over each DMP's own duration."""
        o = self.refine_options
        if o is None or o.steps == 0:
            return z
        check_count("refine steps (--refine)", o.steps, 0, MAX_REFINE_STEPS)
        tau = self.normaliser.denormalise_vector(z.detach().double())[:, self.normaliser.tau_index]
        t = tau[:, None] * torch.linspace(0.0, 1.0, REFINE_POINTS, dtype=torch.float64)
        return refine(z, x, t, self.normaliser, self.dmp_config, o).to(z.dtype)

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

    @property
    def n_hypotheses(self) -> int:
        """K, the DMPs the network proposes per image (1: the paper's network)."""
        return int(getattr(self.model, "n_hypotheses", 1))

    def _outputs(self, images, batch_size: int):
        """Checked images ``x [B, H, W]``, the hypotheses ``z [B, K, P]`` and their scores."""
        check_count("batch_size", batch_size, 1, MAX_BATCH_SIZE)
        x = self._check_images(images)
        z, logits = split_hypotheses(network_outputs(self.model, x, batch_size), self.n_hypotheses)
        return x, z, logits

    def _refined_all(self, z: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Every hypothesis ``z [B, K, P]`` refined on its image (see :meth:`_refined`)."""
        b, k, p = z.shape
        return self._refined(z.reshape(b * k, p), x.repeat_interleave(k, 0)).reshape(b, k, p)

    def predict_normalised(self, images, batch_size: int = 4096) -> torch.Tensor:
        """Network output ``[B, P]`` (normalised units; the top hypothesis of a network
        with several) for prepared images ``[B, H, W]`` (:func:`img2dmp.nn.network_outputs`)."""
        x, z, logits = self._outputs(images, batch_size)
        top = z[torch.arange(z.shape[0]), logits.argmax(dim=1)]  # [B, P]
        return self._refined(top, x)

    def predict_hypotheses(self, images, batch_size: int = 4096) -> tuple[DMPParams, np.ndarray]:
        """All K hypotheses for prepared images, ranked by probability (highest first).

        Returns
        -------
        params : DMPParams
            NumPy float64, batch shape ``[B, K]``; ``params[b, 0]`` is the top hypothesis.
        probs : ndarray [B, K]
            Their probabilities (softmax of the scores), descending along K.
        """
        x, z, logits = self._outputs(images, batch_size)
        z = self._refined_all(z, x)  # [B, K, P]
        probs = torch.softmax(logits.double(), dim=1)
        order = torch.argsort(probs, dim=1, descending=True)  # [B, K]
        z = torch.gather(z, 1, order[..., None].expand_as(z))
        v = self.normaliser.denormalise_vector(z.double())
        n, d = self.dmp_config.n_kernels, self.dmp_config.n_dims
        return DMPParams.from_vector(v.numpy(), n, d), torch.gather(probs, 1, order).numpy()

    def hypothesis_trajectories(self, images, times, batch_size: int = 4096):
        """Every hypothesis rolled out at time stamps ``[B, T]``, in the network's order:
        ``y [B, K, T, d]`` and ``probs [B, K]`` (NumPy arrays), see
        :func:`img2dmp.nn.hypothesis_trajectories`."""
        t = torch.as_tensor(np.asarray(times), dtype=torch.float32)
        x, z, logits = self._outputs(images, batch_size)
        z = self._refined_all(z, x)  # unchanged without refinement
        y = rollout_outputs(z, t, self.normaliser, self.dmp_config, batch_size)
        return y.numpy(), torch.softmax(logits, dim=1).numpy()

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
        images = self.prepare_paths(paths, match_stroke_width)
        params = self.predict_images(images)
        return [(params[i], images[i]) for i in range(len(images))]

    def prepare_paths(self, paths, match_stroke_width: bool = True) -> np.ndarray:
        """Image files as the model's input ``[B, H, W]`` (:func:`prepare_image` with the
        training images' framing and, with ``match_stroke_width``, their pen width)."""
        width = self.stroke_width if match_stroke_width else None
        return np.stack(
            [
                prepare_image(p, self.image_size, margin=self.margin, stroke_width_px=width)
                for p in paths
            ]
        )

    def trajectories(self, params: DMPParams, times=None, n_points: int = 100):
        """Roll DMPs out (exact solution, eqs. 3-7).

        Parameters
        ----------
        params : DMPParams
            Batch shape ``[*batch]``.
        times : array [*batch, T] or [T], optional
            Seconds from the start; default ``n_points`` evenly spaced over ``[0, tau]``.
        n_points : int
            In ``[2, MAX_POINTS]`` (``ValueError`` naming the value otherwise).

        Returns
        -------
        times : ndarray [*batch, T]
        y : ndarray [*batch, T, d]
        """
        if not isinstance(params, DMPParams):
            raise ValueError(f"params must be a DMPParams, got {type(params).__name__}")
        p = params.to_torch(torch.float64)
        if times is None:
            n_points = check_count("n_points (--points)", n_points, 2, MAX_POINTS)
            u = torch.linspace(0.0, 1.0, n_points, dtype=torch.float64)
            t = p.tau[..., None] * u  # [*batch, T]
        else:
            t = torch.as_tensor(np.asarray(times), dtype=torch.float64)
        y = rollout(p, t, self.dmp_config)
        t = t.expand(*y.shape[:-1])
        return t.numpy(), y.numpy()

    def trajectories_for_images(self, images, times, batch_size: int = 4096) -> np.ndarray:
        """The network's DMP trajectories ``[B, T, d]`` at given time stamps ``[B, T]``
        (seconds, each row shifted to start at 0; :func:`img2dmp.nn.dmp_trajectories`,
        training's validation), the top hypothesis, refined on its image if asked."""
        check_count("batch_size", batch_size, 1, MAX_BATCH_SIZE)
        x = self._check_images(images)
        t = torch.as_tensor(np.asarray(times), dtype=torch.float32)  # [B, T], like training
        if self.refine_options is None:
            y = dmp_trajectories(self.model, self.normaliser, self.dmp_config, x, t, batch_size)
            return y.numpy()  # [B, T, d]
        z = self.predict_normalised(x, batch_size)  # [B, P], refined
        y = rollout_outputs(z[:, None], t, self.normaliser, self.dmp_config, batch_size)
        return y[:, 0].numpy()


def prediction_record(
    params: DMPParams,
    times: np.ndarray,
    y: np.ndarray,
    source: str,
    hypotheses: list[dict] | None = None,
) -> dict:
    """JSON-ready description of one predicted DMP and its sampled trajectory.

    ``hypotheses`` (a network with several): one :func:`hypothesis_record` per hypothesis,
    ranked; the top-level ``dmp`` and ``trajectory`` are then the top one's.
    """
    rec = {
        "image": source,
        "dmp": params.to_dict(),
        "vector": np.asarray(params.to_vector()).tolist(),
        "trajectory": {"t": times.tolist(), "y": y.tolist()},
    }
    if hypotheses is not None:
        rec["hypotheses"] = hypotheses
    return rec


def hypothesis_record(rank: int, probability: float, params: DMPParams, times, y) -> dict:
    """One ranked hypothesis (rank 1 = the most probable, the one a robot writes)."""
    return {
        "rank": int(rank),
        "probability": float(probability),
        "dmp": params.to_dict(),
        "trajectory": {"t": np.asarray(times).tolist(), "y": np.asarray(y).tolist()},
    }


def _trajectory_csv(record: dict) -> str:
    """``t_s,x_px,y_px[,y2...]``; with several hypotheses a ``rank,probability`` column
    pair first and one block of rows per hypothesis."""
    hyps = record.get("hypotheses")
    rows = hyps if hyps else [{"trajectory": record["trajectory"]}]
    d = np.asarray(rows[0]["trajectory"]["y"]).shape[1]
    cols = ["t_s", "x_px", "y_px"] + [f"y{k}" for k in range(2, d)]
    lines = [",".join((["rank", "probability"] if hyps else []) + cols)]
    for h in rows:
        t, y = np.asarray(h["trajectory"]["t"]), np.asarray(h["trajectory"]["y"])
        head = [str(h["rank"]), f"{h['probability']:.6g}"] if hyps else []
        lines += [",".join(head + [f"{v:.6g}" for v in (t[i], *y[i])]) for i in range(len(t))]
    return "\n".join(lines) + "\n"


def write_prediction(
    out_dir: str | os.PathLike,
    stem: str,
    record: dict,
    image: np.ndarray | None = None,
) -> list[Path]:
    """Write ``<stem>_dmp.json``, ``<stem>_trajectory.csv`` and, with ``image``, an overlay
    ``<stem>_overlay.png`` (the image with the DMP path in red; with several hypotheses
    all of them, ranked, the top one bold). Atomic writes."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = [out / f"{stem}_dmp.json", out / f"{stem}_trajectory.csv"]
    atomic_write_text(written[0], json.dumps(record, indent=1) + "\n")
    atomic_write_text(written[1], _trajectory_csv(record))
    if image is not None:
        # Imported here: matplotlib starts only when an overlay is asked for.
        from .data.plotting import hypotheses_figure, overlay_figure

        p = out / f"{stem}_overlay.png"
        hyps = record.get("hypotheses")
        if hyps:
            ys = np.stack([np.asarray(h["trajectory"]["y"]) for h in hyps])  # [K, T, d]
            probs = np.array([h["probability"] for h in hyps])
            hypotheses_figure(p, image, ys, probs, title=stem)
        else:
            y = np.asarray(record["trajectory"]["y"])
            overlay_figure(p, image[None], None, y[None], titles=[stem], cell_inches=3.0,
                           labels=("demonstration", "prediction"))  # fmt: skip
        written.append(p)
    return written


__all__ = [
    "DEFAULT_MARGIN",
    "INK_THRESHOLD",
    "MAX_BATCH_SIZE",
    "MAX_POINTS",
    "MAX_REFINE_STEPS",
    "Predictor",
    "check_count",
    "hypothesis_record",
    "ink_margin",
    "prediction_record",
    "prepare_image",
    "stroke_width",
    "typical_stroke_width",
    "write_prediction",
]
