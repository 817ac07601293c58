"""How far each peer's own rollout of an exported img2dmp DMP lies from img2dmp's.

The ten synthetic digits in the 28-px frame (1 s each, ``scaling="none"``, the
recommended model's DMP), exported with :mod:`img2dmp.interop` at several time steps per
movement, rolled out by the peer (movement_primitives ``open_loop()``, MP_PyTorch
``get_traj_pos()``) and compared with img2dmp's exact rollout at the peer's time stamps.
The parameters map exactly, so what remains is each peer's integration; the last line
shows it for movement_primitives: its own RK4 step given the step's own times instead of
the step's end (where 0.9.1 evaluates the forcing term) is within 1e-6 px.

Run: ``.venv/bin/python experiments/interop_errors.py``
"""

from __future__ import annotations

import sys

import numpy as np
import torch

from _provenance import format_record, run_record
from img2dmp import interop
from img2dmp.data.synthetic import SyntheticConfig, generate
from img2dmp.dmp import DMPConfig, DMPParams, rollout

STEPS = (100, 500, 1000, 2000, 4000)


def digits(cfg: DMPConfig) -> DMPParams:
    syn = SyntheticConfig(image_size=(28, 28), duration_s=1.0)
    data = generate(np.arange(10), syn, np.random.default_rng(0), cfg)
    return DMPParams.from_vector(data.params.astype(np.float64), 25, 2)


def late_forcing_free(p: DMPParams, cfg: DMPConfig, steps: int) -> float:
    """movement_primitives' RK4 step, given each step's own times: largest error, px."""
    from movement_primitives.dmp._dmp import dmp_step_rk4

    worst = 0.0
    for i in range(p.tau.shape[0]):
        dmp = interop.to_movement_primitives(p[i], cfg, dt=float(p.tau[i]) / steps, check=False).dmp
        t = np.linspace(0.0, float(p.tau[i]), steps + 1)
        y, yd, zero, ys = dmp.start_y.copy(), np.zeros(2), np.zeros(2), [dmp.start_y.copy()]
        for k in range(1, len(t)):
            dt = t[k] - t[k - 1]
            dmp_step_rk4(
                *(t[k - 1] - dt, t[k] - dt, y, yd, dmp.goal_y, zero, zero, dmp.start_y),
                *(zero, zero, dmp.execution_time_, 0.0, dmp.alpha_y, dmp.beta_y),
                dmp.forcing_term,
            )
            ys.append(y.copy())
        ref = rollout(p[i].to_torch(), torch.as_tensor(t), cfg).numpy()
        worst = max(worst, float(np.linalg.norm(np.array(ys) - ref, axis=-1).max()))
    return worst


def main(argv=None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    print(format_record(run_record(__file__, argv)))
    cfg = DMPConfig(scaling="none")
    p = digits(cfg)
    print("largest distance (px, 28-px frame) of the peer's rollout from img2dmp's, over the")
    print("ten digits; steps = time steps per movement (tau)")
    print(f"{'peer':32s}" + "".join(f"{s:>10d}" for s in STEPS))
    rows = {
        "movement_primitives (RK4)": lambda s: interop.to_movement_primitives(
            p, cfg, dt=float(p.tau[0]) / s
        ),
        "MP_PyTorch DMP (Euler)": lambda s: interop.to_mp_pytorch(p, cfg, kind="dmp", steps=s),
        "MP_PyTorch ProDMP": lambda s: interop.to_mp_pytorch(p, cfg, kind="prodmp", steps=s),
    }
    for name, export in rows.items():
        cells = []
        for s in STEPS:
            if name.endswith("ProDMP") and s > 1000:  # its table costs O(steps^2)
                cells.append(f"{'-':>10s}")
                continue
            cells.append(f"{float(export(s).error_px.max()):10.4f}")
        print(f"{name:32s}" + "".join(cells))
    print(
        "movement_primitives' RK4 with each step's own times: "
        f"{late_forcing_free(p, cfg, 100):.1e} px at 100 steps, "
        f"{late_forcing_free(p, cfg, 1000):.1e} px at 1000"
    )
    print("defaults of img2dmp.interop: movement_primitives 4000, MP_PyTorch DMP 2000, ProDMP 500")


if __name__ == "__main__":
    main()
