"""The network on a device (``--device cuda``), the DMP maths on the CPU.

:func:`place_model` moves a network's weights to a device and makes it take and return
CPU tensors: its inputs are moved to the device before the forward pass and its output
back to the CPU after it (gradients flow through both moves). Everything around the
network - the output normalisation, the exact DMP rollout with its fused CPU kernels,
the costs, refinement, the data - stays where it was, on the CPU, unchanged; only the
network's own arithmetic, most of a training step's and a prediction's work, moves.
On the CPU (the default) the model is returned as it is.

:func:`resolve_device` turns ``"cpu"``, ``"cuda"`` or ``"cuda:N"`` into a
``torch.device`` and refuses, in one line, a device that this machine does not have.
"""

from __future__ import annotations

import torch

#: What ``--device`` accepts (``cuda:N`` picks one of several GPUs).
DEVICES = ("cpu", "cuda")


def resolve_device(name: str | torch.device) -> torch.device:
    """``name`` as a ``torch.device`` that exists here.

    Raises ``ValueError`` (one line) for a name that is not ``cpu``, ``cuda`` or
    ``cuda:N``, and for a CUDA device on a machine without one (or without that one).
    """
    text = str(name)
    kind, _, index = text.partition(":")
    if kind not in DEVICES or (index and (kind != "cuda" or not index.isdecimal())):
        raise ValueError(f"device must be cpu, cuda or cuda:N, got {text!r}")
    if kind == "cuda":
        count = torch.cuda.device_count() if torch.cuda.is_available() else 0
        if count == 0:
            raise ValueError(
                f"device {text!r} asked for, but this machine has no CUDA GPU that torch "
                f"can use (torch {torch.__version__}); use --device cpu"
            )
        if index and int(index) >= count:
            raise ValueError(f"device {text!r} asked for, but this machine has {count} GPU(s)")
    return torch.device(text)


def _inputs_to(device: torch.device):
    def hook(module, args):
        return tuple(a.to(device) if isinstance(a, torch.Tensor) else a for a in args)

    return hook


def _output_to_cpu(module, args, output):
    return output.cpu() if isinstance(output, torch.Tensor) else output


def place_model(model: torch.nn.Module, device: str | torch.device = "cpu") -> torch.nn.Module:
    """``model`` with its weights on ``device``, taking and returning CPU tensors.

    The same module object (its class, ``state_dict`` keys and attributes unchanged), so
    checkpoints, optimisers created afterwards and the code that calls it do not change;
    on the CPU nothing is done. See the module docstring.
    """
    device = resolve_device(device)
    if device.type == "cpu":
        return model
    model.to(device)
    model.register_forward_pre_hook(_inputs_to(device))
    model.register_forward_hook(_output_to_cpu)
    return model


__all__ = ["DEVICES", "place_model", "resolve_device"]
