"""Dynamic movement primitives: the pure maths of Sections III-IV of Pahič et al. (2018).

No I/O and no plotting here. The public surface:

- :class:`DMPConfig` - constants (alpha_z, beta_z, alpha_x, N, d, scaling)
- :class:`DMPParams` - w, tau, g, y0 and their flat 55-number vector
- :func:`phase`, :func:`kernel_centres`, :func:`kernel_widths`, :func:`basis_functions`,
  :func:`forcing_term` - eqs. (5)-(7)
- :func:`fit_dmp` - parameters from demonstrations
- :func:`affine_dmp` - the DMP of an affinely mapped movement, exactly
- :func:`bend_dmp` - a new goal or start, tempo, scale, rotation (which are exact: its module)
- :func:`rollout` - fast batched differentiable y(t) (cost 10)
- :func:`rollout_numpy` - the same rollout in NumPy alone (no torch, no gradient)
- :func:`rollout_sensitivity`, :func:`sensitivity_rollout` - the paper's gradient, eqs. (11)-(27)
- :class:`DMPIntegrator`, :func:`integrate` - step-by-step reference integrator
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import exports

_NAMES = {
    "affine_dmp": ".affine",
    "basis_functions": ".basis",
    "forcing_term": ".basis",
    "kernel_centres": ".basis",
    "kernel_widths": ".basis",
    "phase": ".basis",
    "bend_dmp": ".bend",
    "DMPConfig": ".config",
    "FitResult": ".fit",
    "fit_dmp": ".fit",
    "DMPIntegrator": ".integrate",
    "integrate": ".integrate",
    "DMPParams": ".params",
    "rollout": ".rollout",
    "rollout_numpy": "._numpy_rollout",
    "unit_responses": ".rollout",
    "rollout_sensitivity": ".sensitivity",
    "sensitivity_rollout": ".sensitivity",
}

if TYPE_CHECKING:  # the real imports, for type checkers and IDEs
    from ._numpy_rollout import rollout_numpy
    from .affine import affine_dmp
    from .basis import basis_functions, forcing_term, kernel_centres, kernel_widths, phase
    from .bend import bend_dmp
    from .config import DMPConfig
    from .fit import FitResult, fit_dmp
    from .integrate import DMPIntegrator, integrate
    from .params import DMPParams
    from .rollout import rollout, unit_responses
    from .sensitivity import rollout_sensitivity, sensitivity_rollout

__getattr__, __dir__ = exports(__name__, _NAMES, globals())

__all__ = [
    "DMPConfig",
    "DMPIntegrator",
    "DMPParams",
    "FitResult",
    "affine_dmp",
    "basis_functions",
    "bend_dmp",
    "fit_dmp",
    "forcing_term",
    "integrate",
    "kernel_centres",
    "kernel_widths",
    "phase",
    "rollout",
    "rollout_numpy",
    "rollout_sensitivity",
    "sensitivity_rollout",
    "unit_responses",
]
