"""The forward pass of the encoder-decoder network in NumPy, for prediction without torch.

Importing torch takes 1.5-3 s, more than a whole one-image prediction without it.
:class:`NumpyNetwork` evaluates the network :func:`img2dmp.nn.model.build_model` makes
from a :class:`~img2dmp.nn.architecture.ModelConfig`, in evaluation mode (dropout off,
batch normalisation from its running statistics), from the weights of a checkpoint
(:func:`img2dmp.checkpoint.load_checkpoint` with ``framework="numpy"``), in float32; its
outputs agree with torch's to float32 rounding (tests/test_numpy_network.py).

Every architecture a ``ModelConfig`` describes is supported: the fully connected and the
convolutional encoder (3x3 convolutions, padding 1, any strides, with or without batch
normalisation), every activation, the impulse filter, K hypotheses. A convolution is one
matrix product over the image's 3x3 patches (im2col), with the feature maps kept
channels-last so that the patches are gathered by slicing.
"""

from __future__ import annotations

import math
import threading

import numpy as np

from .architecture import (
    ACTIVATIONS,
    ModelConfig,
    conv_out_size,
    conv_strides,
    input_size,
)

#: torch's default ``eps`` of ``nn.BatchNorm2d``, which the model does not change (it is
#: not stored with the weights).
BATCH_NORM_EPS = 1e-5
#: The slope of ``nn.LeakyReLU`` for negative inputs (torch's default, as the model uses).
LEAKY_SLOPE = 0.01
#: The prefixes of a checkpoint file's tensors: the network's and the optimiser's.
_MODEL_PREFIX, _OPTIM_PREFIX = "model.", "optim."
#: Bytes of the convolutions' buffers per thread: a batch whose buffers would be larger
#: goes through in parts of as many images as fit (as fast per image, measured from 4 to
#: 256 images of 28 x 28 and 40 x 40, and a few MB kept instead of hundreds).
WORK_BYTES = 8 << 20
#: The 8 neighbours of a pixel, as offsets into the image padded by one pixel.
_NEIGHBOURS = [(di, dj) for di in range(3) for dj in range(3) if (di, dj) != (1, 1)]


def _linear_indices(n_layers: int, last_activation: bool, dropout: float) -> list[int]:
    """Positions of the ``nn.Linear`` modules in the ``nn.Sequential`` that
    ``img2dmp.nn.model._mlp`` builds for ``n_layers`` linear layers: an activation after
    each hidden one (and the last with ``last_activation``), a dropout after each hidden
    activation with ``dropout`` > 0. They name the weights in the state dict."""
    out, i = [], 0
    for k in range(n_layers):
        hidden = k < n_layers - 1
        out.append(i)
        i += 1 + int(hidden or last_activation) + int(hidden and dropout > 0)
    return out


def state_shapes(config: ModelConfig) -> dict[str, tuple[int, ...]]:
    """The name and shape of every tensor of ``build_model(config).state_dict()``
    (parameters and batch normalisation's buffers), without the checkpoint's ``model.``
    prefix, in the state dict's order."""
    h, w = input_size(config)
    shapes: dict[str, tuple[int, ...]] = {}

    def dense(prefix: str, sizes: list[int], last_activation: bool, dropout: float = 0.0):
        at = _linear_indices(len(sizes) - 1, last_activation, dropout)
        for i, a, b in zip(at, sizes[:-1], sizes[1:], strict=True):
            shapes[f"{prefix}.{i}.weight"], shapes[f"{prefix}.{i}.bias"] = (b, a), (b,)

    latent = config.encoder_layers[-1]
    if config.encoder == "fc":
        dense("encoder.net", [h * w, *config.encoder_layers], True, config.dropout)
    else:
        c_in, j, batch = 1, 0, config.conv_norm == "batch"
        for c, st in zip(config.conv_channels, conv_strides(config), strict=True):
            shapes[f"encoder.conv.{j}.weight"] = (c, c_in, 3, 3)
            if batch:  # Conv2d (no bias), BatchNorm2d, activation
                for name in ("weight", "bias", "running_mean", "running_var"):
                    shapes[f"encoder.conv.{j + 1}.{name}"] = (c,)
                shapes[f"encoder.conv.{j + 1}.num_batches_tracked"] = ()
            else:  # Conv2d, activation
                shapes[f"encoder.conv.{j}.bias"] = (c,)
            j += 3 if batch else 2
            c_in, h, w = c, conv_out_size(h, st), conv_out_size(w, st)
        dense("encoder.head", [c_in * h * w, latent], True)
    dense("decoder", [latent, *config.decoder_layers, config.output_size], False)
    return shapes


def _named_weights(weights: dict, shapes: dict[str, tuple[int, ...]]) -> dict[str, np.ndarray]:
    """``weights`` by their state-dict names (a checkpoint file's ``model.`` prefix taken
    off, its ``optim.*`` tensors left out), each checked against ``shapes``."""
    named: dict[str, np.ndarray] = {}
    for key, value in weights.items():
        if not isinstance(key, str):
            raise ValueError(f"weights: a key must be a tensor's name, got {key!r}")
        if key.startswith(_OPTIM_PREFIX):  # a resumable checkpoint's optimiser state
            continue
        name = key.removeprefix(_MODEL_PREFIX)
        if name not in shapes:
            raise ValueError(f"weights: {key!r} is no tensor of this network")
        if name in named:
            raise ValueError(f"weights: {name!r} is given twice (with and without 'model.')")
        array = np.asarray(value)
        if array.shape != shapes[name]:
            raise ValueError(
                f"weights: {key!r} has shape {array.shape}, the network's is {shapes[name]}"
            )
        named[name] = array
    missing = [k for k in shapes if k not in named]
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise ValueError(f"weights: {missing[0]!r} of shape {shapes[missing[0]]} is missing{more}")
    return named


def _float32(a: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float32)


def _sigmoid(x: np.ndarray) -> np.ndarray:
    e = np.exp(-np.abs(x))  # never overflows, unlike exp(-x) for a large negative x
    return np.where(x >= 0, 1 / (1 + e), e / (1 + e)).astype(np.float32, copy=False)


def _gelu(x: np.ndarray) -> np.ndarray:
    from scipy.special import erf  # 0.3 s to import: only for networks that use it

    return (0.5 * x * (1 + erf(x * np.float32(0.5**0.5)))).astype(np.float32, copy=False)


def _activation(name: str):
    """The function ``x [any shape] float32 -> same`` of the activation ``name``, as
    torch's module with its default arguments (GELU: the exact erf form). It may work in
    place: it is only given a product just made."""
    if name == "relu":
        return lambda x: np.maximum(x, np.float32(0), out=x)
    if name == "tanh":
        return lambda x: np.tanh(x, out=x)
    if name == "elu":  # alpha 1
        return lambda x: np.expm1(x, out=x, where=x < 0)
    if name == "gelu":
        return _gelu
    if name == "leaky_relu":
        return lambda x: np.multiply(x, np.float32(LEAKY_SLOPE), out=x, where=x < 0)
    if name == "sigmoid":
        return _sigmoid
    raise ValueError(f"model.activation must be one of {sorted(ACTIVATIONS)}, got {name!r}")


def _dilate(mask: np.ndarray) -> np.ndarray:
    """``mask [B, H, W]`` bool, true wherever its 3x3 window (inside the image) holds a
    true pixel."""
    out = mask.copy()
    out[:, 1:] |= mask[:, :-1]
    out[:, :-1] |= mask[:, 1:]
    rows = out.copy()
    out[:, :, 1:] |= rows[:, :, :-1]
    out[:, :, :-1] |= rows[:, :, 1:]
    return out


def impulse_filter(images: np.ndarray) -> np.ndarray:
    """:class:`img2dmp.nn.model.ImpulseFilter` in NumPy: a pixel at exactly 0 or 1 with a
    nonzero pixel in its 3x3 window takes the median of its 8 neighbours (the mean of the
    middle two, edges replicated); ``images [B, H, W]`` -> ``[B, H, W]``."""
    x = images
    magnitude = np.abs(x)
    # torch's 3x3 max pool, whose maximum is NaN where the window holds a NaN
    near = _dilate(magnitude > 0) & ~_dilate(np.isnan(magnitude))
    b, i, j = np.nonzero(((x <= 0) | (x >= 1)) & near)
    out = x.copy()
    if b.size:
        padded = np.pad(x, ((0, 0), (1, 1), (1, 1)), mode="edge")  # [B, H + 2, W + 2]
        around = np.stack([padded[b, i + di, j + dj] for di, dj in _NEIGHBOURS], 1)  # [hits, 8]
        around.sort(axis=1)
        out[b, i, j] = (around[:, 3] + around[:, 4]) / np.float32(2)
    return out


class _Workspace(threading.local):
    """The convolutions' buffers, kept from one call to the next in each thread: arrays of
    a few MB made afresh come from the operating system zeroed, page by page, which took
    half the time of a batch of 64 images. Each is as large as the largest asked for."""

    arrays: dict

    def __init__(self):
        self.arrays: dict = {}

    def get(self, key, shape: tuple[int, ...]) -> np.ndarray:
        """The buffer ``key`` as a C-contiguous float32 array of ``shape``, its values
        left from earlier calls."""
        size = math.prod(shape)
        a = self.arrays.get(key)
        if a is None or a.size < size:
            a = self.arrays[key] = np.empty(size, np.float32)
        return a[:size].reshape(shape)


class _Conv:
    """One 3x3 convolution (padding 1) with its bias (batch normalisation folded in) and
    activation, on channels-last feature maps ``[B, H, W, C_in] -> [B, H', W', C_out]``."""

    def __init__(self, weight: np.ndarray, bias: np.ndarray, stride: int, activation):
        c_out, c_in = weight.shape[:2]
        self.c_in = c_in
        # rows ordered (kernel row, kernel column, input channel), as the patches below
        self.matrix = _float32(weight.transpose(2, 3, 1, 0).reshape(9 * c_in, c_out))
        self.bias, self.stride, self.activation = _float32(bias), stride, activation

    def __call__(self, x: np.ndarray, work: _Workspace) -> np.ndarray:
        """The feature map ``x`` convolved; the result is ``work``'s until its next use."""
        n, h, w, c = x.shape
        s, c_out = self.stride, self.matrix.shape[1]
        ho, wo = conv_out_size(h, s), conv_out_size(w, s)
        padded = work.get((id(self), "in"), (n, h + 2, w + 2, c))
        padded[:, [0, -1]], padded[:, :, [0, -1]] = 0, 0  # the border: the padding
        padded[:, 1:-1, 1:-1] = x
        patches = work.get((id(self), "patches"), (n, ho, wo, 9, c))  # im2col
        for k in range(9):
            di, dj = divmod(k, 3)
            patches[:, :, :, k] = padded[
                :, di : di + s * (ho - 1) + 1 : s, dj : dj + s * (wo - 1) + 1 : s
            ]
        y = work.get((id(self), "out"), (n * ho * wo, c_out))  # [B H' W', C_out]
        np.matmul(patches.reshape(n * ho * wo, 9 * c), self.matrix, out=y)
        y += self.bias
        return self.activation(y).reshape(n, ho, wo, c_out)

    def work_bytes(self, h: int, w: int) -> int:
        """Bytes of the buffers for one image of ``h`` x ``w`` pixels in."""
        ho, wo = conv_out_size(h, self.stride), conv_out_size(w, self.stride)
        floats = (h + 2) * (w + 2) * self.c_in + ho * wo * (9 * self.c_in + self.matrix.shape[1])
        return 4 * floats


def _conv_layers(config: ModelConfig, w: dict, act) -> tuple[list[_Conv], list[tuple]]:
    """The convolutions of a conv encoder (batch normalisation folded into them) and its
    head as a dense layer ``(weight [latent, h w C], bias, activation)`` that reads the
    channels-last feature map."""
    convs, j, batch = [], 0, config.conv_norm == "batch"
    h, wd = input_size(config)
    for st in conv_strides(config):
        weight = w[f"encoder.conv.{j}.weight"].astype(np.float64)  # [C_out, C_in, 3, 3]
        if batch:  # eval: y = (conv - mean) * gamma / sqrt(var + eps) + beta
            p = f"encoder.conv.{j + 1}."
            var = w[p + "running_var"].astype(np.float64)
            scale = w[p + "weight"] / np.sqrt(var + BATCH_NORM_EPS)  # [C_out]
            bias = w[p + "bias"] - w[p + "running_mean"] * scale
            weight = weight * scale[:, None, None, None]
        else:
            bias = w[f"encoder.conv.{j}.bias"]
        convs.append(_Conv(weight, bias, st, act))
        j += 3 if batch else 2
        h, wd = conv_out_size(h, st), conv_out_size(wd, st)
    head = w["encoder.head.0.weight"]  # [latent, C h w], torch's (C, h, w) order
    c = config.conv_channels[-1]
    head = head.reshape(-1, c, h, wd).transpose(0, 2, 3, 1).reshape(head.shape[0], -1)
    return convs, [(head, w["encoder.head.0.bias"], act)]


class NumpyNetwork:
    """The network of ``config`` with ``weights``, evaluated in NumPy (float32).

    Parameters
    ----------
    config : ModelConfig
        The architecture (a checkpoint's ``meta["model"]``).
    weights : dict[str, ndarray]
        The network's state dict: the names of ``model.state_dict()``, with or without
        the ``model.`` prefix of a checkpoint file (``optim.*`` tensors are ignored).
        Every tensor must be there at its shape: ``ValueError`` naming the first that is
        missing, mis-shaped or unknown.

    Notes
    -----
    Calls may come from several threads at once. Each thread keeps the convolutions'
    buffers (at most :data:`WORK_BYTES`; a larger batch goes through in parts) until its
    next call or the network's end: making them afresh each time cost half the time of a
    batch of 64.

    Examples
    --------
    >>> ckpt = load_checkpoint("digits-real", framework="numpy")  # doctest: +SKIP
    >>> net = NumpyNetwork.from_checkpoint(ckpt)  # doctest: +SKIP
    >>> net(np.zeros((1, 28, 28), np.float32)).shape  # doctest: +SKIP
    (1, 224)
    """

    def __init__(self, config: ModelConfig, weights: dict):
        if not isinstance(config, ModelConfig):
            raise ValueError(f"config must be a ModelConfig, got {type(config).__name__}")
        self.config = config
        self.image_size = input_size(config)
        self.n_params, self.n_hypotheses = config.n_outputs, config.hypotheses
        self.output_size = config.output_size
        w = _named_weights(weights, state_shapes(config))
        act = _activation(config.activation)
        self._impulse = config.input_filter == "impulse"
        self._convs: list[_Conv] = []
        self._work = _Workspace()
        if config.encoder == "conv":
            self._convs, encoder_dense = _conv_layers(config, w, act)
        else:
            at = _linear_indices(len(config.encoder_layers), True, config.dropout)
            encoder_dense = [
                (w[f"encoder.net.{i}.weight"], w[f"encoder.net.{i}.bias"], act) for i in at
            ]
        at = _linear_indices(len(config.decoder_layers) + 1, False, 0.0)
        decoder = [(w[f"decoder.{i}.weight"], w[f"decoder.{i}.bias"], act) for i in at]
        decoder[-1] = (*decoder[-1][:2], None)  # the output layer: no activation
        # x @ W.T as a product with a contiguous [in, out] matrix
        self._dense = [(_float32(m.T), _float32(b), f) for m, b, f in encoder_dense + decoder]
        self._n_encoder = len(encoder_dense)
        self.feature_size = int(self._dense[self._n_encoder - 1][0].shape[1])
        per_image, (h, wd) = 0, self.image_size
        for conv, st in zip(self._convs, conv_strides(config), strict=False):
            per_image += conv.work_bytes(h, wd)
            h, wd = conv_out_size(h, st), conv_out_size(wd, st)
        self._part = max(1, WORK_BYTES // per_image) if per_image else None

    @staticmethod
    def supported(config: ModelConfig) -> bool:
        """Whether the network of ``config`` can be evaluated here: every architecture a
        :class:`ModelConfig` describes can (kept for callers that choose between this and
        torch)."""
        return isinstance(config, ModelConfig)

    @classmethod
    def from_checkpoint(cls, ckpt) -> NumpyNetwork:
        """The network of a :class:`~img2dmp.checkpoint.Checkpoint` (its record's
        ``"model"`` and its ``model_state``)."""
        return cls(ModelConfig.from_dict(ckpt.meta["model"]), ckpt.model_state)

    def __call__(self, images: np.ndarray) -> np.ndarray:  # [B, H, W] -> [B, P | K (P + 1)]
        """The network's output for ``images [B, H, W]``: ``[B, output_size]`` float32,
        the normalised DMP vector (K = 1) or K vectors and K scores."""
        return self._run(images, len(self._dense), self.output_size)

    def features(self, images: np.ndarray) -> np.ndarray:  # [B, H, W] -> [B, F]
        """The encoder's output for ``images [B, H, W]``: ``[B, feature_size]`` float32,
        what the decoder reads (torch: ``model.encoder(model.input_filter(x))``)."""
        return self._run(images, self._n_encoder, self.feature_size)

    def with_features(self, images: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The output and the encoder's features of ``images``, in one pass."""
        feats = self.features(images)
        return self._dense_layers(feats, self._n_encoder, len(self._dense)), feats

    def _run(self, images, layers: int, size: int) -> np.ndarray:
        x = np.asarray(images, dtype=np.float32)
        if x.ndim != 3:
            raise ValueError(f"images must be [B, H, W], got shape {x.shape}")
        if x.shape[1:] != self.image_size:
            raise ValueError(
                f"images are {x.shape[1:]} pixels, the model expects {self.image_size}"
            )
        if self._impulse:
            x = impulse_filter(x)
        n, part = x.shape[0], self._part
        if part is None or n <= part:
            return self._forward(x, layers)
        out = np.empty((n, size), np.float32)
        for i in range(0, n, part):
            out[i : i + part] = self._forward(x[i : i + part], layers)
        return out

    def _forward(self, x: np.ndarray, layers: int) -> np.ndarray:  # [B, H, W] -> [B, *]
        """The convolutions, then the first ``layers`` dense layers."""
        n = x.shape[0]
        if self._convs:
            x = x[..., None]  # [B, H, W, 1]
            for conv in self._convs:
                x = conv(x, self._work)
        x = x.reshape(n, self._dense[0][0].shape[0])  # [B, inputs of the first dense layer]
        return self._dense_layers(x, 0, layers)

    def _dense_layers(self, x: np.ndarray, first: int, stop: int) -> np.ndarray:
        """Dense layers ``first`` to ``stop - 1`` applied to ``x [B, *]``."""
        for matrix, bias, activation in self._dense[first:stop]:
            x = x @ matrix
            x += bias
            if activation is not None:
                x = activation(x)
        return x
