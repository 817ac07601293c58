"""How much of a DMP can the paper's 20-unit code hold under cost (9) (issue 21)?

Cost (9) is the squared error of the 55 normalised DMP parameters, and the paper's network
passes every image through one layer of 20 units (1600-1500-1300-1000-600-200-20-35-55).
Two measurements say what that layer allows:

1. **The code's floor.** The evaluation set's true normalised parameter vectors, projected
   on the first k principal components of the training set's (k = 10, 20, 35, 55), are
   rolled out and compared with the true trajectories. A linear code of k units trained
   with a squared parameter error ends at that projection (Eckart-Young), whatever the
   encoder: it is the trajectory error a perfect encoder of the parameters themselves
   could not beat with k linear units.
2. **The paper's decoder with a perfect encoder** (``--decoder-epochs N``): the true
   normalised parameters through an encoder (55-512-512-20) and the paper's decoder
   (20-35-55, the same activations), trained with cost (9) on the training set and
   rolled out on the evaluation set: what the paper's code and decoder can hold when
   the encoder has nothing to infer from an image.
3. **Live units** of trained runs (``--run DIR``, repeatable): how many of the code's
   units are non-zero on at least one training image, and how many per image on
   average. A ReLU unit that is zero on every image gets no gradient and stays so: the
   code is then narrower than its 20 units, and its floor that of fewer components.

Usage::

    python experiments/bottleneck_floor.py --data OUT/data [--digits 2] \\
        [--units weights|amplitudes] [--decoder-epochs 100] [--run OUT/cost9 ...]

``OUT/data`` holds ``train.safetensors`` and ``eval.safetensors`` of
``reproduce_table1.py``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

from img2dmp.data.store import load_dataset
from img2dmp.dmp import rollout
from img2dmp.nn.model import ACTIVATIONS
from img2dmp.nn.normalise import ParamNormaliser

# isort: split
# From this script's directory, which Python puts on sys.path when it runs a script.
from _provenance import format_record, run_record

COMPONENTS = (10, 20, 35, 55)


def principal_floor(train, evalset, units: str = "weights", ks=COMPONENTS, limit: int = 4000):
    """``{k: (errors [M] px, normalised squared error)}``: the evaluation set's parameters
    (at most ``limit`` samples, a fixed random choice) through their projection on the
    training set's first k principal components (normalised units of ``units``),
    rolled out at their own time stamps against the unprojected ones."""
    cfg = train.dmp_config
    norm = ParamNormaliser.fit(train.params, cfg, units=units)
    z_train = norm.normalise(torch.as_tensor(train.params, dtype=torch.float64)).numpy()
    rows = np.random.default_rng(0).permutation(len(evalset))[:limit]
    z_eval = norm.normalise(torch.as_tensor(evalset.params[rows], dtype=torch.float64)).numpy()
    centre = z_train.mean(0)
    basis = np.linalg.svd(z_train - centre, full_matrices=False)[2]  # [P, P], rows by variance
    t = torch.as_tensor(evalset.times[rows], dtype=torch.float64)
    truth = rollout(norm.denormalise(torch.as_tensor(z_eval)), t, cfg)
    out = {}
    for k in ks:
        v = basis[: min(k, len(basis))]
        z = (z_eval - centre) @ v.T @ v + centre
        y = rollout(norm.denormalise(torch.as_tensor(z)), t, cfg)
        out[k] = ((y - truth).norm(dim=-1).mean(-1).numpy(), float(((z - z_eval) ** 2).mean()))
    return out


def perfect_encoder_floor(
    train, evalset, units="weights", activation="relu", epochs=100, code=20, hidden=35, seed=0
) -> np.ndarray:
    """Trajectory errors ``[M]`` (px) on ``evalset`` of the true normalised parameters
    through ``55-512-512-code`` (activation after each layer, the code's too, as in the
    paper's encoder) and the paper's decoder ``code-hidden-55``, trained ``epochs``
    epochs with cost (9) (mean squared normalised error; Adam 1e-3, cosine, batch 128)."""
    from torch import nn

    cfg = train.dmp_config
    norm = ParamNormaliser.fit(train.params, cfg, units=units)
    z = norm.normalise(torch.as_tensor(train.params, dtype=torch.float64)).float()
    z_eval = norm.normalise(torch.as_tensor(evalset.params, dtype=torch.float64))
    torch.manual_seed(seed)
    act, n = ACTIVATIONS[activation], z.shape[1]
    net = nn.Sequential(
        *(nn.Linear(n, 512), act(), nn.Linear(512, 512), act(), nn.Linear(512, code), act()),
        *(nn.Linear(code, hidden), act(), nn.Linear(hidden, n)),
    )
    batch = min(128, len(z))
    steps = max(1, epochs * (len(z) // batch))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # a small network: one thread is fastest, and never waits
    try:
        _fit(net, z, batch, epochs, steps)
    finally:
        torch.set_num_threads(threads)
    with torch.no_grad():
        z_hat = net(z_eval.float()).double()
    t = torch.as_tensor(evalset.times, dtype=torch.float64)
    truth = rollout(norm.denormalise(z_eval), t, cfg)
    y = rollout(norm.denormalise(z_hat), t, cfg)
    return (y - truth).norm(dim=-1).mean(-1).numpy()


def _fit(net, z, batch: int, epochs: int, steps: int) -> None:
    """``epochs`` of Adam (1e-3, cosine to 0 over ``steps``) on the mean squared error
    of ``net(z)`` against ``z``, batches of ``batch``."""
    opt = torch.optim.Adam(net.parameters(), 1e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, steps)
    for _ in range(epochs):
        perm = torch.randperm(len(z))
        for s in range(0, len(z) - batch + 1, batch):
            b = z[perm[s : s + batch]]
            loss = ((net(b) - b) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            sched.step()


def live_units(model, images, batch: int = 512) -> tuple[int, int, float]:
    """``(live, width, per image)``: units of ``model``'s code (its encoder's output)
    that are non-zero on at least one of ``images [M, H, W]``, the code's width, and
    the mean number non-zero per image."""
    ever, count, n = None, 0.0, 0
    with torch.no_grad():
        for s in range(0, len(images), batch):
            x = torch.as_tensor(np.asarray(images[s : s + batch]), dtype=torch.float32)
            code = model.encoder(model.input_filter(x)) != 0  # [b, width]
            ever = code.any(0) if ever is None else ever | code.any(0)
            count += float(code.sum())
            n += len(code)
    return int(ever.sum()), int(ever.numel()), count / max(n, 1)


def select(data, digits):
    """The samples of ``digits`` (all without), named as the data set names its classes."""
    if not digits:
        return data
    return data.subset(np.flatnonzero(np.isin(data.labels, data.labels_of_digits(digits))))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--data", required=True, help="folder with train.safetensors, eval.safetensors")
    p.add_argument("--digits", type=lambda s: [int(x) for x in s.split(",")], default=None)
    p.add_argument("--units", default="weights", choices=("weights", "amplitudes"))
    p.add_argument("--run", action="append", default=[], help="a trained run (repeatable)")
    p.add_argument(
        "--decoder-epochs", type=int, default=0, help="train the perfect-encoder network (0: no)"
    )
    p.add_argument(
        "--activation",
        default="relu",
        choices=sorted(ACTIVATIONS),
        help="its activation (the paper's: relu)",
    )
    args = p.parse_args(argv)
    print(format_record(run_record(__file__, sys.argv[1:] if argv is None else list(argv))))
    folder = Path(args.data)
    train = select(load_dataset(folder / "train.safetensors").select_split("train"), args.digits)
    evalset = select(load_dataset(folder / "eval.safetensors"), args.digits)
    print(f"{len(train)} training, {len(evalset)} evaluation samples; units {args.units}")
    print(f"{'components':>10} {'trajectory error (px)':>22} {'normalised sq. error':>21}")
    for k, (err, sq) in principal_floor(train, evalset, args.units).items():
        print(f"{k:>10} {err.mean():>13.3f} +- {err.std():.3f} {sq:>21.4f}")
    if args.decoder_epochs:
        err = perfect_encoder_floor(
            train, evalset, args.units, args.activation, args.decoder_epochs
        )
        print(
            f"the paper's code and decoder ({args.activation}) on the true parameters, "
            f"{args.decoder_epochs} epochs: {err.mean():.3f} +- {err.std():.3f} px"
        )
    for run in args.run:
        from img2dmp.predict import Predictor

        live, width, per = live_units(Predictor.load(run).model, train.images)
        print(f"{run}: {live} of {width} code units live on the training images, {per:.1f} each")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
