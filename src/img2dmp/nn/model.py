"""The encoder-decoder network of Pahič et al. (ICRA 2018), Section V.

An image goes through an *encoder* to a small latent code and a *decoder* maps that code
to the normalised DMP parameter vector (eq. 8, scaled by
:class:`~img2dmp.nn.normalise.ParamNormaliser`). The paper's network is fully connected::

    1600 -> 1500 -> 1300 -> 1000 -> 600 -> 200 -> 20  (encoder)  -> 35 -> 55  (decoder)

Encoders are interchangeable: anything with ``in_shape`` ``(H, W)``, ``out_features`` and
``forward(images [B, H, W]) -> [B, out_features]`` can be plugged into
:class:`EncoderDecoder`. :class:`FullyConnectedEncoder` is the paper's;
:class:`ConvEncoder` is a small convolutional alternative (the paper's stated next step).
:func:`build_model` makes either from a :class:`ModelConfig`, which (with the constants
and :func:`check_weights`) lives in the torch-free :mod:`img2dmp.nn.architecture` and is
re-exported here.
"""

from __future__ import annotations

import torch
from torch import nn

from .architecture import (  # noqa: F401 (re-exported: the torch-free names of the network)
    CONV_NORMS,
    ENCODERS,
    INITS,
    INPUT_FILTERS,
    MAX_HYPOTHESES,
    MAX_LAYERS,
    MAX_WEIGHTS,
    PAPER_IMAGE_SIZE,
    ModelConfig,
    check_weights,
    hypotheses_output_size,
)

#: The torch module of each activation ``ModelConfig`` names
#: (:data:`img2dmp.nn.architecture.ACTIVATIONS`, in the same order).
ACTIVATIONS = {
    "relu": nn.ReLU,
    "tanh": nn.Tanh,
    "elu": nn.ELU,
    "gelu": nn.GELU,
    "leaky_relu": nn.LeakyReLU,
    "sigmoid": nn.Sigmoid,
}


def _activation(name: str) -> nn.Module:
    if name not in ACTIVATIONS:
        raise ValueError(f"model.activation must be one of {sorted(ACTIVATIONS)}, got {name!r}")
    return ACTIVATIONS[name]()


def _mlp(
    sizes: list[int], activation: str, last_activation: bool, dropout: float = 0.0
) -> nn.Sequential:
    """Linear layers of ``sizes`` with ``activation`` after each (the last one only with
    ``last_activation``) and, with ``dropout`` > 0, dropout after each hidden layer's."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        hidden = i < len(sizes) - 2
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if hidden or last_activation:
            layers.append(_activation(activation))
        if hidden and dropout > 0:
            layers.append(nn.Dropout(dropout))
    return nn.Sequential(*layers)


class ImpulseFilter(nn.Module):
    """Switching median filter against salt-and-pepper (impulse) noise.

    A pixel at exactly 0 or 1, the two values that salt-and-pepper noise writes, takes the
    median of its 8 neighbours (the mean of the middle two; edges replicated); every other
    pixel is left as it is. A blurred synthetic image without noise has neither value on
    or near its strokes, so it passes unchanged (to 1e-4, where a background zero borders
    the blur's faint tail). A resampled (warped) image no longer holds the exact values,
    so the filter must come before any warp: training applies it to a batch before
    augmenting it, and applying it again is then close to a no-op.

    Only the pixels that can change are looked at: a zero whose neighbours are all zero
    keeps its value, which is also their median.
    """

    _NEIGHBOURS = [(di, dj) for di in range(3) for dj in range(3) if (di, dj) != (1, 1)]

    def forward(self, images: torch.Tensor) -> torch.Tensor:  # [B, H, W] -> [B, H, W]
        x = images[:, None]
        hit = ((x <= 0) | (x >= 1)) & (nn.functional.max_pool2d(x.abs(), 3, 1, 1) > 0)
        b, i, j = hit[:, 0].nonzero(as_tuple=True)
        out = images.clone()
        if b.numel():
            padded = nn.functional.pad(x, (1, 1, 1, 1), mode="replicate")[:, 0]
            around = [padded[b, i + di, j + dj] for di, dj in self._NEIGHBOURS]
            ordered = torch.stack(around, 1).sort(1).values  # [hits, 8]
            out[b, i, j] = ordered[:, 3:5].mean(1)
        return out


class FullyConnectedEncoder(nn.Module):
    """The paper's encoder: the flattened image through fully connected layers.

    ``H*W -> encoder_layers[0] -> ... -> encoder_layers[-1]``, activation after each, and
    with ``dropout`` > 0 dropout after each but the code's (training only).
    """

    def __init__(
        self,
        image_size: list[int],
        layers: list[int],
        activation: str = "relu",
        dropout: float = 0.0,
    ):
        super().__init__()
        self.in_shape = tuple(image_size)
        self.out_features = layers[-1]
        self.net = _mlp([image_size[0] * image_size[1], *layers], activation, True, dropout)

    def forward(self, images: torch.Tensor) -> torch.Tensor:  # [B, H, W] -> [B, latent]
        return self.net(images.flatten(1))


class ConvEncoder(nn.Module):
    """A small convolutional encoder: 3x3 convolutions, then one linear layer.

    With the default stride 2 each convolution halves the image (40 -> 20 -> 10 -> 5 for
    three layers); the feature map is flattened and mapped to ``latent`` features.
    """

    def __init__(
        self,
        image_size: list[int],
        channels: list[int],
        latent: int,
        activation: str = "relu",
        strides: list[int] | None = None,
        norm: str = "none",
        dropout: float = 0.0,
    ):
        super().__init__()
        self.in_shape = tuple(image_size)
        self.out_features = latent
        strides = strides if strides is not None else [2] * len(channels)
        layers: list[nn.Module] = []
        c_in, h, w = 1, image_size[0], image_size[1]
        for c, st in zip(channels, strides, strict=True):
            if norm == "batch":  # the norm's shift replaces the convolution's bias
                layers += [nn.Conv2d(c_in, c, 3, stride=st, padding=1, bias=False)]
                layers += [nn.BatchNorm2d(c)]
            else:
                layers += [nn.Conv2d(c_in, c, 3, stride=st, padding=1)]
            layers += [_activation(activation)]
            c_in, h, w = c, (h - 1) // st + 1, (w - 1) // st + 1
        self.conv = nn.Sequential(*layers)
        head: list[nn.Module] = [nn.Linear(c_in * h * w, latent), _activation(activation)]
        if dropout > 0:  # the code's units, in training only; no weights, the same keys
            head.append(nn.Dropout(dropout))
        self.head = nn.Sequential(*head)

    def forward(self, images: torch.Tensor) -> torch.Tensor:  # [B, H, W] -> [B, latent]
        return self.head(self.conv(images[:, None]).flatten(1))


class EncoderDecoder(nn.Module):
    """Image to normalised DMP vector: ``decoder(encoder(image))``.

    Parameters
    ----------
    encoder : nn.Module
        Has ``in_shape`` (H, W), ``out_features`` and maps ``[B, H, W] -> [B, out_features]``.
    decoder_layers : list of int
        Hidden widths between the code and the output.
    n_outputs : int
        Size P of one normalised DMP vector (eq. 8).
    hypotheses : int
        K DMPs per image: the output is ``[B, P]`` for K = 1 (the paper), else
        ``[B, K (P + 1)]``, K vectors and K scores (:func:`split_hypotheses`).
    """

    def __init__(
        self,
        encoder: nn.Module,
        decoder_layers: list[int],
        n_outputs: int,
        activation: str,
        input_filter: nn.Module | None = None,
        hypotheses: int = 1,
    ):
        super().__init__()
        self.input_filter = input_filter if input_filter is not None else nn.Identity()
        self.encoder = encoder
        self.n_params, self.n_hypotheses = int(n_outputs), int(hypotheses)
        width = hypotheses_output_size(self.n_params, self.n_hypotheses)
        self.decoder = _mlp([encoder.out_features, *decoder_layers, width], activation, False)

    @property
    def image_size(self) -> tuple[int, int]:
        return tuple(self.encoder.in_shape)

    def forward(self, images: torch.Tensor) -> torch.Tensor:  # [B, H, W] -> [B, P | K (P+1)]
        if images.shape[-2:] != self.encoder.in_shape:
            raise ValueError(
                f"images are {tuple(images.shape[-2:])} pixels, the model expects "
                f"{self.encoder.in_shape}"
            )
        return self.decoder(self.encoder(self.input_filter(images)))


def build_model(config: ModelConfig, seed: int | None = None) -> EncoderDecoder:
    """Make the network described by ``config`` (weights initialised as ``config.init``).

    ``seed`` makes the initial weights reproducible without touching the global RNG.
    ``ValueError`` (:func:`check_weights`) for a network of more than ``MAX_WEIGHTS``
    weights, before any is allocated.
    """
    check_weights(config)
    fork = torch.random.fork_rng(enabled=seed is not None)
    with fork:
        if seed is not None:
            torch.manual_seed(seed)
        model = _build(config)
        if config.init == "he":
            he_initialise(model)
    return model


def _build(config: ModelConfig) -> EncoderDecoder:
    """The network of ``config`` on the current default device, weights as torch makes them."""
    size = config.image_size if config.image_size is not None else list(PAPER_IMAGE_SIZE)
    if config.encoder == "fc":
        enc = FullyConnectedEncoder(size, config.encoder_layers, config.activation, config.dropout)
    else:
        enc = ConvEncoder(
            size,
            config.conv_channels,
            config.encoder_layers[-1],
            config.activation,
            config.conv_strides,
            config.conv_norm,
            config.dropout,
        )
    filt = ImpulseFilter() if config.input_filter == "impulse" else None
    return EncoderDecoder(
        enc, config.decoder_layers, config.n_outputs, config.activation, filt,
        hypotheses=config.hypotheses,
    )  # fmt: skip


# The gain of He et al.'s initialisation for each activation (torch.nn.init.calculate_gain).
_GAINS = {
    nn.ReLU: ("relu", None),
    nn.LeakyReLU: ("leaky_relu", 0.01),
    nn.Tanh: ("tanh", None),
    nn.Sigmoid: ("sigmoid", None),
    nn.ELU: ("relu", None),
    nn.GELU: ("relu", None),
}


def he_initialise(model: nn.Module) -> None:
    """He et al.'s normal initialisation of every linear and convolutional layer of
    ``model`` in place: weights ``N(0, gain**2 / fan_in)`` with the gain of the
    activation that follows the layer in its ``nn.Sequential`` (a batch normalisation in
    between is skipped; none follows: gain 1), biases 0."""
    for seq in model.modules():
        if not isinstance(seq, nn.Sequential):
            continue
        layers = list(seq)
        for i, layer in enumerate(layers):
            if not isinstance(layer, (nn.Linear, nn.Conv2d)):
                continue
            after = [type(m) for m in layers[i + 1 :] if not isinstance(m, nn.BatchNorm2d)]
            name, param = _GAINS.get(after[0] if after else None, ("linear", None))
            gain = nn.init.calculate_gain(name, param)  # linear: 1
            fan_in = layer.weight[0].numel()  # inputs (x kernel size) of one output
            with torch.no_grad():
                layer.weight.normal_(0.0, gain / fan_in**0.5)
                if layer.bias is not None:
                    layer.bias.zero_()


def split_hypotheses(out: torch.Tensor, hypotheses: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A network output ``[B, K (P + 1)]`` as normalised DMP vectors ``[B, K, P]`` and the
    hypotheses' scores (logits) ``[B, K]``; one hypothesis ``[B, P]`` as ``[B, 1, P]`` with
    score 0."""
    if hypotheses == 1:
        return out[:, None, :], out.new_zeros(out.shape[0], 1)
    k = hypotheses
    p = out.shape[-1] // k - 1
    return out[:, : k * p].reshape(-1, k, p), out[:, k * p :]


def top_hypothesis(out: torch.Tensor, hypotheses: int) -> torch.Tensor:
    """The normalised DMP vector ``[B, P]`` of the highest-scoring hypothesis."""
    if hypotheses == 1:
        return out
    z, logits = split_hypotheses(out, hypotheses)
    best = logits.argmax(dim=1)  # [B]
    return z[torch.arange(z.shape[0], device=z.device), best]
