"""The architecture of the encoder-decoder network as data, without torch.

:class:`ModelConfig` describes an :class:`~img2dmp.nn.model.EncoderDecoder`: which
encoder, its widths and channels, the decoder, the hypotheses. It is read from every
checkpoint's record, so a prediction that never imports torch (the NumPy network of
:mod:`img2dmp.nn._numpy_net`) needs it too; :mod:`img2dmp.nn.model` builds the torch
network from it and re-exports every name here.

:func:`check_weights` counts the weights a configuration gives by arithmetic, before any
is allocated (tests/test_numpy_network.py checks the count against the built network).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from ..errors import show

#: Names of the activations after every hidden layer (:data:`img2dmp.nn.model.ACTIVATIONS`
#: maps them to torch modules).
ACTIVATIONS = ("relu", "tanh", "elu", "gelu", "leaky_relu", "sigmoid")
ENCODERS = ("fc", "conv")
CONV_NORMS = ("none", "batch")
#: Initialisations of the weights, see :class:`ModelConfig` ``init``.
INITS = ("torch", "he")
INPUT_FILTERS = ("none", "impulse")
#: The paper's input size (1600 inputs), used when a model is built without data.
PAPER_IMAGE_SIZE = (40, 40)
#: Most weights (parameters) of a network: the paper's has 6.5 million; 50 million take
#: 0.2 GB, and training holds four copies (weights, gradients, Adam's two moments).
MAX_WEIGHTS = 50_000_000
#: Most hypotheses K: each is a DMP rolled out and scored for every image of a batch.
MAX_HYPOTHESES = 64
#: Most entries of each list of layer widths or channels.
MAX_LAYERS = 64


@dataclass
class ModelConfig:
    """Architecture of an :class:`~img2dmp.nn.model.EncoderDecoder`.

    Parameters
    ----------
    encoder : {"fc", "conv"}
        ``"fc"``: the paper's fully connected encoder; ``"conv"``:
        :class:`~img2dmp.nn.model.ConvEncoder`.
    image_size : [H, W] or None
        Input image size in pixels (the paper: 40 x 40 = 1600 inputs). None (default):
        taken from the data by training; :func:`~img2dmp.nn.model.build_model` alone reads
        it as 40 x 40.
    encoder_layers : list of int
        Widths of the fully connected encoder's layers, the last being the latent code
        (paper: 1500, 1300, 1000, 600, 200, 20). For ``"conv"`` only the last entry
        (the latent size) is used.
    conv_channels : list of int
        Channels of the convolutional encoder's 3x3 convolutions.
    conv_strides : list of int, optional
        Stride of each of those convolutions (default ``None``: 2 for every one, each
        halving the image). A stride-1 first layer sees the image at full resolution,
        which can help to place the strokes to a fraction of a pixel, at about twice the
        cost.
    conv_norm : {"none", "batch"}
        Normalisation after each convolution (before its activation): none (default) or
        batch normalisation, which uses batch statistics in training and the running
        averages saved with the weights at evaluation.
    decoder_layers : list of int
        Hidden widths of the decoder between the latent code and the output (paper: 35).
    input_filter : {"none", "impulse"}
        Fixed filter on the image before the encoder: none (default) or
        :class:`~img2dmp.nn.model.ImpulseFilter`, which undoes most salt-and-pepper noise.
    activation : str
        One of :data:`ACTIVATIONS`, after every hidden layer.
    n_outputs : int
        Length P of the DMP vector (55 for N = 25, d = 2); set from the data.
    hypotheses : int
        K, the number of DMPs the network proposes for one image, each with a score
        (:func:`~img2dmp.nn.model.split_hypotheses`). 1 (default) is the paper's network:
        one DMP, no score.
    dropout : float
        Share of units dropped at random in training (Srivastava et al. 2014), in
        [0, 1); 0 (default, the paper's network as described): none. The fully
        connected encoder drops its hidden units (after each activation but the code's);
        the convolutional encoder its code's units (after its one fully connected
        layer). Prediction never drops units; no weights are added.
    init : {"torch", "he"}
        How the weights start. ``"torch"`` (default): PyTorch's default for each layer,
        under which the paper's deep ReLU stack shrinks the images' variation (its
        standard deviation across images) about 2.7-fold per layer, to 1/140 of the first
        layer's at the code, which first sees mostly the biases; ``"he"``:
        He et al.'s normal initialisation (variance ``gain**2 / fan_in``, the gain of
        the activation that follows the layer; 1 for the output layer) and zero biases,
        which keeps the variation through every layer. The paper does not say which.
    """

    encoder: str = "fc"
    image_size: list[int] | None = None
    encoder_layers: list[int] = field(default_factory=lambda: [1500, 1300, 1000, 600, 200, 20])
    conv_channels: list[int] = field(default_factory=lambda: [16, 32, 64])
    conv_strides: list[int] | None = None
    conv_norm: str = "none"
    decoder_layers: list[int] = field(default_factory=lambda: [35])
    input_filter: str = "none"
    activation: str = "relu"
    n_outputs: int = 55
    hypotheses: int = 1
    dropout: float = 0.0
    init: str = "torch"

    def __post_init__(self) -> None:
        if self.encoder not in ENCODERS:
            raise ValueError(f"model.encoder must be one of {ENCODERS}, got {self.encoder!r}")
        if self.image_size is not None:
            self.image_size = [int(s) for s in self.image_size]
            if len(self.image_size) != 2 or min(self.image_size) < 4:
                raise ValueError(f"model.image_size must be [H, W] >= 4, got {self.image_size!r}")
        for name in ("encoder_layers", "conv_channels", "decoder_layers"):
            vals = [int(v) for v in getattr(self, name)]
            if any(v < 1 for v in vals) or len(vals) > MAX_LAYERS:
                raise ValueError(
                    f"model.{name} must hold at most {MAX_LAYERS} positive widths, got {show(vals)}"
                )
            setattr(self, name, vals)
        if not self.encoder_layers:
            raise ValueError("model.encoder_layers must name at least the latent size")
        if self.encoder == "conv" and not self.conv_channels:
            raise ValueError("model.conv_channels must not be empty for a conv encoder")
        if self.conv_strides is not None:  # None: stride 2 everywhere
            self.conv_strides = [int(v) for v in self.conv_strides]
            if len(self.conv_strides) != len(self.conv_channels) or min(self.conv_strides) < 1:
                raise ValueError(
                    "model.conv_strides must hold one stride >= 1 per entry of "
                    f"conv_channels {self.conv_channels}, got {self.conv_strides!r}"
                )
        if self.input_filter not in INPUT_FILTERS:
            raise ValueError(
                f"model.input_filter must be one of {INPUT_FILTERS}, got {self.input_filter!r}"
            )
        if self.conv_norm not in CONV_NORMS:
            raise ValueError(f"model.conv_norm must be one of {CONV_NORMS}, got {self.conv_norm!r}")
        if self.activation not in ACTIVATIONS:
            raise ValueError(
                f"model.activation must be one of {sorted(ACTIVATIONS)}, got {self.activation!r}"
            )
        if int(self.n_outputs) < 1:
            raise ValueError(f"model.n_outputs must be >= 1, got {self.n_outputs!r}")
        self.n_outputs = int(self.n_outputs)
        if isinstance(self.hypotheses, bool) or not 1 <= int(self.hypotheses) <= MAX_HYPOTHESES:
            raise ValueError(
                f"model.hypotheses must be an integer from 1 to {MAX_HYPOTHESES}, got "
                f"{self.hypotheses!r}"
            )
        self.hypotheses = int(self.hypotheses)
        number = isinstance(self.dropout, (int, float)) and not isinstance(self.dropout, bool)
        if not number or not 0 <= self.dropout < 1:
            raise ValueError(f"model.dropout must be a number in [0, 1), got {self.dropout!r}")
        self.dropout = float(self.dropout)
        if self.init not in INITS:
            raise ValueError(f"model.init must be one of {INITS}, got {self.init!r}")
        check_weights(self)

    @property
    def output_size(self) -> int:
        """Width of the network's output: ``P`` for one hypothesis, ``K (P + 1)`` for K."""
        return hypotheses_output_size(self.n_outputs, self.hypotheses)

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> ModelConfig:
        unknown = set(d) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"unknown model config field(s): {sorted(unknown)}")
        return cls(**d)


def hypotheses_output_size(n_params: int, hypotheses: int) -> int:
    """``P`` for one hypothesis; ``K P`` DMP units and K scores for ``K > 1``."""
    return n_params if hypotheses == 1 else hypotheses * (n_params + 1)


def input_size(config: ModelConfig) -> tuple[int, int]:
    """``(H, W)`` of the images the network of ``config`` takes: ``config.image_size``,
    else the paper's 40 x 40 (a network built before the data is seen)."""
    size = config.image_size if config.image_size is not None else PAPER_IMAGE_SIZE
    return int(size[0]), int(size[1])


def conv_strides(config: ModelConfig) -> list[int]:
    """The stride of each convolution of a conv encoder (2 where none is given)."""
    if config.conv_strides is not None:
        return list(config.conv_strides)
    return [2] * len(config.conv_channels)


def conv_out_size(size: int, stride: int) -> int:
    """Rows (or columns) after a 3x3 convolution with padding 1 at ``stride``."""
    return (size - 1) // stride + 1


def _dense_weights(sizes: list[int]) -> int:
    """Weights and biases of linear layers ``sizes[0] -> sizes[1] -> ...``."""
    return sum(a * b + b for a, b in zip(sizes[:-1], sizes[1:], strict=True))


def _encoder_weights(config: ModelConfig) -> int:
    h, w = input_size(config)
    if config.encoder == "fc":
        return _dense_weights([h * w, *config.encoder_layers])
    n, c_in = 0, 1
    for c, st in zip(config.conv_channels, conv_strides(config), strict=True):
        # with batch norm its shift replaces the convolution's bias, and adds a scale
        n += 9 * c_in * c + (2 * c if config.conv_norm == "batch" else c)
        c_in, h, w = c, conv_out_size(h, st), conv_out_size(w, st)
    return n + _dense_weights([c_in * h * w, config.encoder_layers[-1]])


def check_weights(config: ModelConfig) -> int:
    """The number of weights of ``build_model(config)`` (at ``config.image_size``, else
    the paper's 40 x 40), counted from the layers' sizes, nothing allocated;
    ``ValueError`` naming the fields that decide it when it is above :data:`MAX_WEIGHTS`
    (a network of 100 million units per layer would otherwise end in an allocation
    failure, or the machine's memory)."""
    encoder = _encoder_weights(config)
    latent = config.encoder_layers[-1]
    decoder = _dense_weights([latent, *config.decoder_layers, config.output_size])
    if encoder + decoder <= MAX_WEIGHTS:
        return encoder + decoder
    h, w = input_size(config)
    if encoder >= decoder:
        field = "model.conv_channels" if config.encoder == "conv" else "model.encoder_layers"
        value = config.conv_channels if config.encoder == "conv" else config.encoder_layers
        part = f"the encoder ({h} x {w} pixels in)"
    else:
        field, value, part = "model.decoder_layers", config.decoder_layers, "the decoder"
        if config.hypotheses > 1:
            field += f" and model.hypotheses ({config.hypotheses})"
    raise ValueError(
        f"{field} {show(value)} give {part} {max(encoder, decoder):,} weights; a network "
        f"may have at most {MAX_WEIGHTS:,} in all ({encoder + decoder:,} here)"
    )
