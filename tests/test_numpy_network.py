"""The network without torch: the torch-free architecture, the NumPy forward pass and the
checkpoint read as NumPy arrays (issue 33).

:class:`~img2dmp.nn._numpy_net.NumpyNetwork` is compared with the torch
:class:`~img2dmp.nn.model.EncoderDecoder` for every kind of layer a ``ModelConfig``
describes, on random weights and on the shipped model; :func:`check_weights` counts by
arithmetic what torch allocates; the NumPy checkpoint path gives the same digests and
the same refusals as torch's; and none of it imports torch.
"""

from __future__ import annotations

import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch

from img2dmp.checkpoint import (
    CheckpointError,
    load_checkpoint,
    load_weights_into,
    optimizer_to_tensors,
    save_checkpoint,
    weights_digest,
)
from img2dmp.nn import _numpy_net, architecture, model
from img2dmp.nn._numpy_net import NumpyNetwork, impulse_filter, state_shapes
from img2dmp.nn.architecture import MAX_WEIGHTS, ModelConfig, check_weights
from img2dmp.nn.model import ImpulseFilter, build_model

SHIPPED = "digits-real"
CONV = {"encoder": "conv"}
SMALL_CONV = {"encoder": "conv", "conv_channels": [4, 8], "encoder_layers": [16]}
#: Architectures, one per kind of layer and option, small enough to build in milliseconds.
CONFIGS = {
    "fc-paper-like": {"encoder_layers": [300, 200, 100, 20], "image_size": [40, 40]},
    "fc-dropout-28": {"encoder_layers": [64, 32, 20], "image_size": [28, 28], "dropout": 0.2},
    "fc-hypotheses-4": {"encoder_layers": [64, 20], "image_size": [28, 28], "hypotheses": 4},
    "conv-default": CONV,
    "conv-strides-122": {**CONV, "conv_strides": [1, 2, 2], "image_size": [28, 28]},
    "conv-batch-norm": {**CONV, "conv_norm": "batch", "hypotheses": 4},
    "conv-batch-strides": {**SMALL_CONV, "conv_norm": "batch", "conv_strides": [1, 3],
                           "image_size": [28, 28]},
    "conv-dropout": {**SMALL_CONV, "dropout": 0.3, "image_size": [28, 28]},
    "conv-odd-size": {**SMALL_CONV, "conv_strides": [2, 3], "image_size": [29, 41]},
    "conv-impulse-28": {**CONV, "input_filter": "impulse", "image_size": [28, 28]},
    "fc-impulse-40": {"encoder_layers": [64, 20], "input_filter": "impulse"},
    **{f"conv-{a}": {**SMALL_CONV, "activation": a, "image_size": [28, 28]}
       for a in architecture.ACTIVATIONS},
    **{f"fc-{a}": {"encoder_layers": [48, 20], "activation": a, "decoder_layers": [35, 17]}
       for a in ("gelu", "sigmoid", "elu")},
}  # fmt: skip


def _torch_net(cfg: ModelConfig, seed: int = 0) -> model.EncoderDecoder:
    """The network with He's weights (4 times larger before a sigmoid, whose slope is at
    most 1/4), random biases and (batch norm) random running statistics, scales and
    shifts: every output varies across images."""
    net = build_model(replace(cfg, init="he"), seed=seed).eval()
    gen = torch.Generator().manual_seed(seed)
    gain = 4.0 if cfg.activation == "sigmoid" else 1.0
    with torch.no_grad():
        for name, t in net.state_dict().items():
            if name.endswith(".bias"):
                t.copy_(0.1 * torch.randn(t.shape, generator=gen))
            elif name.endswith(".weight") and t.ndim > 1:
                t.mul_(gain)
            elif name.endswith("running_mean"):
                t.copy_(0.5 * torch.randn(t.shape, generator=gen))
            elif name.endswith("running_var") or (name.endswith(".weight") and t.ndim == 1):
                t.copy_(0.2 + torch.rand(t.shape, generator=gen) * 2)  # var and BN scale
    return net


def _salt_and_pepper(b: int, h: int, w: int, seed: int = 0) -> np.ndarray:
    """Faint strokes in [0, 1) with a tenth of the pixels set to exactly 0 or 1."""
    rng = np.random.default_rng(seed)
    x = rng.random((b, h, w)) * (rng.random((b, h, w)) < 0.4)
    noise = rng.random((b, h, w))
    x[noise < 0.05], x[noise > 0.95] = 0.0, 1.0
    return x.astype(np.float32)


def _numpy(state: dict) -> dict[str, np.ndarray]:
    return {k: v.detach().numpy() for k, v in state.items()}


def _close(out: np.ndarray, ref: np.ndarray) -> float:
    """max |out - ref| in units of the tolerance 1e-5 (1 + max |ref|): <= 1 passes."""
    assert out.dtype == np.float32 and out.shape == ref.shape
    return float(np.abs(out - ref).max() / (1e-5 * (1 + np.abs(ref).max())))


# -- the architecture without torch ---------------------------------------------------------


@pytest.mark.parametrize(
    "kw",
    [
        {},  # the paper's 6.4 million
        *CONFIGS.values(),
        {**CONV, "conv_channels": [3, 5, 7, 9], "conv_strides": [3, 1, 2, 5],
         "image_size": [17, 90], "decoder_layers": [1, 2, 3]},
        {**CONV, "conv_norm": "batch", "conv_strides": [1, 1, 1], "hypotheses": 64},
    ],
)  # fmt: skip
def test_check_weights_counts_what_torch_allocates(kw):
    cfg = ModelConfig(**kw)
    net = build_model(cfg)
    assert check_weights(cfg) == sum(p.numel() for p in net.parameters())
    shapes = {k: tuple(v.shape) for k, v in net.state_dict().items()}
    assert list(state_shapes(cfg).items()) == list(shapes.items())  # in torch's order too


@pytest.mark.parametrize(
    ("kw", "message"),
    [
        ({"encoder_layers": [100_000_000]},
         "model.encoder_layers [100000000] give the encoder (40 x 40 pixels in) 160,100,000,000"),
        ({**CONV, "conv_channels": [3000, 3000], "image_size": [8, 8]},
         "model.conv_channels [3000, 3000] give the encoder (8 x 8 pixels in) 81,"),
        ({"encoder_layers": [20], "decoder_layers": [8000, 8000]},
         "model.decoder_layers [8000, 8000] give the decoder 64,"),
        ({"encoder_layers": [20], "decoder_layers": [400_000], "hypotheses": 64},
         "model.decoder_layers and model.hypotheses (64) [400000] give the decoder"),
    ],
)  # fmt: skip
def test_too_many_weights_are_refused_naming_the_field(kw, message):
    with pytest.raises(ValueError, match=f"at most {MAX_WEIGHTS:,} in all") as e:
        ModelConfig(**kw)
    assert str(e.value).startswith(message) and "\n" not in str(e.value)


def test_model_re_exports_the_architecture():
    for name in ("ModelConfig", "check_weights", "hypotheses_output_size", "ENCODERS",
                 "CONV_NORMS", "INITS", "INPUT_FILTERS", "PAPER_IMAGE_SIZE", "MAX_WEIGHTS",
                 "MAX_HYPOTHESES", "MAX_LAYERS"):  # fmt: skip
        assert getattr(model, name) is getattr(architecture, name), name
    assert tuple(model.ACTIVATIONS) == architecture.ACTIVATIONS  # the same names, in order
    assert model.ACTIVATIONS["gelu"] is torch.nn.GELU
    with pytest.raises(ValueError, match=r"model.activation must be one of \['elu', "):
        ModelConfig(activation="swish")


# -- the NumPy network against torch's -----------------------------------------------------


@pytest.mark.parametrize("batch", [1, 7])
@pytest.mark.parametrize("kw", CONFIGS.values(), ids=CONFIGS.keys())
def test_numpy_network_gives_torchs_outputs(kw, batch):
    cfg = ModelConfig(**kw)
    net = _torch_net(cfg)
    numpy_net = NumpyNetwork(cfg, _numpy(net.state_dict()))
    assert NumpyNetwork.supported(cfg) and numpy_net.output_size == cfg.output_size
    x = _salt_and_pepper(batch, *numpy_net.image_size)
    with torch.no_grad():
        ref = net(torch.from_numpy(x)).numpy()
    out = numpy_net(x)
    assert _close(out, ref) <= 1, (np.abs(out - ref).max(), np.abs(ref).max())
    if batch > 1:  # the outputs differ between images: the comparison is not of constants
        assert float(ref.std(0).min()) > 0.01


def test_calls_of_other_sizes_in_parts_and_in_threads_agree(monkeypatch):
    """The convolutions' buffers are kept between calls (per thread): a call of another
    batch size, or one in another thread at the same time, leaves the results as they are;
    a batch larger than the buffers goes through in parts."""
    cfg = ModelConfig(**CONFIGS["conv-batch-norm"])
    state = _numpy(_torch_net(cfg).state_dict())
    net = NumpyNetwork(cfg, state)
    x = _salt_and_pepper(32, 40, 40)
    first = net(x)
    assert _close(net(x[:1]), first[:1]) <= 1
    again = net(x)
    np.testing.assert_array_equal(again, first)
    assert not np.shares_memory(again, first)
    batches = [x[i % 4 :: 4] for i in range(24)]  # the same size: the same buffers' shapes
    with ThreadPoolExecutor(4) as pool:
        outs = list(pool.map(net, batches))
    for i, out in enumerate(outs):
        assert _close(out, first[i % 4 :: 4]) <= 1, i
    monkeypatch.setattr(_numpy_net, "WORK_BYTES", 3 * 210_000)  # 3 images of 40 x 40
    in_parts = NumpyNetwork(cfg, state)
    assert in_parts._part == 3 and net._part > 32
    assert _close(in_parts(x), first) <= 1


def test_batch_norm_uses_the_running_statistics():
    # The test can fail: the same weights with the running statistics left out differ.
    cfg = ModelConfig(**CONFIGS["conv-batch-norm"])
    state = _numpy(_torch_net(cfg).state_dict())
    x = _salt_and_pepper(3, 40, 40)
    plain = dict(state)
    for k in plain:
        if k.endswith("running_mean"):
            plain[k] = np.zeros_like(plain[k])
    assert np.abs(NumpyNetwork(cfg, state)(x) - NumpyNetwork(cfg, plain)(x)).max() > 1e-2


def test_impulse_filter_gives_torchs_pixels():
    x = _salt_and_pepper(5, 28, 28, seed=3)
    x[0, 0, :3] = np.nan  # NaN spreads through torch's max pool: its neighbours keep theirs
    x[1] = 0.0  # an empty image stays empty
    x[2, 0, 0], x[2, 5, 5] = 1.0, 0.0  # at a corner (edges replicated)
    ref = ImpulseFilter()(torch.from_numpy(x)).numpy()
    out = impulse_filter(x)
    np.testing.assert_array_equal(out, ref)
    changed = ~np.isclose(out, x, equal_nan=True)
    assert changed.sum() > 100 and not changed[1].any()


def test_shipped_model_through_numpy_gives_torchs_outputs():
    numpy_ckpt = load_checkpoint(SHIPPED, framework="numpy")
    torch_ckpt = load_checkpoint(SHIPPED)
    assert all(isinstance(v, np.ndarray) for v in numpy_ckpt.model_state.values())
    assert numpy_ckpt.meta == torch_ckpt.meta
    cfg = ModelConfig.from_dict(torch_ckpt.meta["model"])
    net = build_model(cfg).eval()
    load_weights_into(net, torch_ckpt)
    images = np.zeros((4, 28, 28), np.float32)
    images[1, 6:22, 13:15] = 1.0  # a "1"
    images[2, 6:8, 8:20], images[2, 6:22, 18:20] = 1.0, 1.0  # a "7"
    images[3] = _salt_and_pepper(1, 28, 28)[0]
    with torch.no_grad():
        ref = net(torch.from_numpy(images)).numpy()
    out = NumpyNetwork.from_checkpoint(numpy_ckpt)(images)
    assert _close(out, ref) <= 1 and np.abs(ref).max() > 1
    back = build_model(cfg).eval()
    load_weights_into(back, numpy_ckpt)  # torch takes the NumPy arrays too
    with torch.no_grad():
        assert torch.equal(back(torch.from_numpy(images)), net(torch.from_numpy(images)))


def _state(cfg: ModelConfig) -> dict[str, np.ndarray]:
    return _numpy(build_model(cfg, seed=0).state_dict())


@pytest.mark.parametrize(
    ("edit", "key", "what"),
    [
        (lambda s: s.pop("encoder.conv.3.weight"), "encoder.conv.3.weight", "is missing"),
        (lambda s: s.pop("encoder.conv.1.num_batches_tracked"), "num_batches_tracked",
         "is missing"),
        (lambda s: s.update({"decoder.2.bias": np.zeros(54, np.float32)}), "decoder.2.bias",
         "has shape (54,), the network's is (55,)"),
        (lambda s: s.update({"encoder.head.0.weight": np.zeros((16, 7), np.float32)}),
         "encoder.head.0.weight", "has shape (16, 7)"),
        (lambda s: s.update({"encoder.conv.9.weight": np.zeros(1)}), "encoder.conv.9.weight",
         "is no tensor of this network"),
        (lambda s: s.update({"model.decoder.0.bias": s["decoder.0.bias"]}), "decoder.0.bias",
         "is given twice"),
    ],
    ids=["missing", "missing-buffer", "mis-shaped", "head-mis-shaped", "unknown", "twice"],
)  # fmt: skip
def test_missing_or_mis_shaped_weights_are_named(edit, key, what):
    cfg = ModelConfig(**SMALL_CONV, conv_norm="batch")
    state = _state(cfg)
    edit(state)
    with pytest.raises(ValueError, match="weights: ") as e:
        NumpyNetwork(cfg, state)
    msg = str(e.value)
    assert key in msg and what in msg and "\n" not in msg


def test_checkpoint_names_with_prefix_and_optimiser_state_are_taken():
    cfg = ModelConfig(**SMALL_CONV)
    state = _state(cfg)
    x = _salt_and_pepper(2, 40, 40)
    prefixed = {f"model.{k}": v for k, v in state.items()} | {"optim.state.0.step": np.ones(())}
    np.testing.assert_array_equal(NumpyNetwork(cfg, prefixed)(x), NumpyNetwork(cfg, state)(x))
    net = NumpyNetwork(cfg, state)
    assert net(np.zeros((0, 40, 40))).shape == (0, cfg.output_size)
    with pytest.raises(ValueError, match=r"images are \(28, 28\) pixels, the model expects"):
        net(np.zeros((1, 28, 28)))
    with pytest.raises(ValueError, match=r"images must be \[B, H, W\], got shape \(40, 40\)"):
        net(np.zeros((40, 40)))


# -- the checkpoint as NumPy arrays --------------------------------------------------------


@pytest.fixture
def resumable(tmp_path) -> Path:
    """A checkpoint of a batch-normalised network after two Adam steps, with the
    optimiser's state (0-dim step counts, int64 ``num_batches_tracked``)."""
    cfg = ModelConfig(**SMALL_CONV, conv_norm="batch", hypotheses=2, image_size=[28, 28])
    net = build_model(cfg, seed=0)
    opt = torch.optim.Adam(net.parameters(), lr=1e-2)
    for _ in range(2):
        loss = net(torch.rand(8, 28, 28)).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    tensors, record = optimizer_to_tensors(opt)
    meta = {"model": cfg.to_dict(), "optim": record}
    return save_checkpoint(tmp_path / "last.safetensors", net.state_dict(), meta, tensors)


def test_numpy_and_torch_give_the_same_digests(resumable):
    a, b = load_checkpoint(resumable, framework="numpy"), load_checkpoint(resumable)
    assert a.extra and a.model_state["encoder.conv.1.num_batches_tracked"].dtype == np.int64
    assert a.extra["state.0.step"].shape == ()  # 0-dim tensors hash as torch's do
    for x, y in ((a.model_state, b.model_state), (a.extra, b.extra)):
        assert weights_digest(x) == weights_digest(y)
    assert weights_digest(a.model_state) == a.meta["weights_sha256"]
    assert weights_digest(a.extra) == a.meta["optim_sha256"]
    shipped = load_checkpoint(SHIPPED, framework="numpy")
    state = shipped.model_state
    torch_digest = weights_digest(load_checkpoint(SHIPPED).model_state)
    assert weights_digest(state) == torch_digest == shipped.meta["weights_sha256"]
    big_endian = {k: v.astype(v.dtype.newbyteorder(">")) for k, v in state.items()}
    assert weights_digest(big_endian) == torch_digest
    # The test can fail: one changed value changes the digest.
    state["decoder.0.bias"] = state["decoder.0.bias"] + np.float32(1)
    assert weights_digest(state) != torch_digest
    with pytest.raises(ValueError, match="'w' has dtype object"):
        weights_digest({"w": np.array([None])})


def _header(path: Path) -> tuple[int, dict]:
    data = path.read_bytes()
    n = int.from_bytes(data[:8], "little")
    return n, json.loads(data[8 : 8 + n])


def _flip(path: Path, name: str) -> None:
    """Flip a bit of the first byte of tensor ``name``."""
    n, header = _header(path)
    data = bytearray(path.read_bytes())
    data[8 + n + header[name]["data_offsets"][0]] ^= 0x10
    path.write_bytes(bytes(data))


def _edit_record(path: Path) -> None:
    """Rewrite the checkpoint with its epoch changed (its record_sha256 left stale)."""
    from safetensors.numpy import save_file

    old = load_checkpoint(path, framework="numpy")
    tensors = {f"model.{k}": v for k, v in old.model_state.items()}
    tensors |= {f"optim.{k}": v for k, v in old.extra.items()}
    save_file(tensors, str(path), metadata={"img2dmp": json.dumps(dict(old.meta, epoch=99))})


def _foreign(path: Path) -> None:
    from safetensors.numpy import save_file

    save_file({"w": np.zeros(3, np.float32)}, str(path))


DAMAGES = {
    "weight-bit": (lambda p: _flip(p, "model.decoder.0.weight"), "SHA-256 of its weights"),
    "optimiser-bit": (lambda p: _flip(p, next(k for k in _header(p)[1] if k.startswith("optim."))),
                      "SHA-256 of its optimiser state"),
    "record": (_edit_record, "does not match its record_sha256"),
    "truncated-to-8": (lambda p: p.write_bytes(p.read_bytes()[:8]), "corrupt or truncated"),
    "truncated-by-1": (lambda p: p.write_bytes(p.read_bytes()[:-1]), "corrupt or truncated"),
    "foreign": (_foreign, "not an img2dmp checkpoint"),
    "pickle": (lambda p: p.write_bytes(b"\x80\x02pickled torch file"), "corrupt or truncated"),
}  # fmt: skip


@pytest.mark.parametrize("damage", DAMAGES)
def test_numpy_path_refuses_what_torch_refuses_with_the_same_message(resumable, damage):
    # Undamaged, the file loads through both paths: the refusals below are the damage's.
    assert load_checkpoint(resumable, framework="numpy").meta == load_checkpoint(resumable).meta
    make, expected = DAMAGES[damage]
    make(resumable)
    messages = []
    for framework in ("numpy", "pt"):
        with pytest.raises(CheckpointError) as e:
            load_checkpoint(resumable, framework=framework)
        messages.append(str(e.value))
    assert messages[0] == messages[1]
    assert expected in messages[0] and str(resumable) in messages[0] and "\n" not in messages[0]


def test_an_unknown_framework_is_refused():
    with pytest.raises(ValueError, match=r"framework must be one of \('pt', 'numpy'\), got 'tf'"):
        load_checkpoint(SHIPPED, framework="tf")


# -- none of it imports torch --------------------------------------------------------------

TORCH_FREE = """
import sys
import numpy as np
import img2dmp.nn._numpy_net, img2dmp.nn.architecture, img2dmp.checkpoint
from img2dmp.checkpoint import load_checkpoint, read_checkpoint_meta, weights_digest
from img2dmp.nn._numpy_net import NumpyNetwork
assert "torch" not in sys.modules
ckpt = load_checkpoint("digits-real", framework="numpy")
assert read_checkpoint_meta("digits-real") == ckpt.meta
assert weights_digest(ckpt.model_state) == ckpt.meta["weights_sha256"]
out = NumpyNetwork.from_checkpoint(ckpt)(np.zeros((2, 28, 28), np.float32))
assert "torch" not in sys.modules, "torch imported"
print(out.shape)
"""


def test_numpy_prediction_path_never_imports_torch():
    proc = subprocess.run(
        [sys.executable, "-c", TORCH_FREE], capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "(2, 224)"
