"""The encoder-decoder network and its two cost functions (Section V of Pahič et al.).

- :class:`ModelConfig`, :func:`build_model`, :class:`EncoderDecoder`,
  :class:`FullyConnectedEncoder`, :class:`ConvEncoder` - the network
- :class:`ParamNormaliser` - per-unit scaling of the DMP vector (eq. 8)
- :func:`parameter_cost` (eq. 9), :func:`trajectory_cost` (eq. 10), :class:`Cost`
- :func:`trajectory_error_px` - Table I's metric
- :func:`split_hypotheses`, :func:`top_hypothesis` - K DMPs per image and their scores
- :mod:`.ink` - image-consistency terms: the path on the ink, the ink covered
- :func:`network_outputs`, :func:`dmp_trajectories`, :func:`hypothesis_trajectories` - the
  one batched inference path
  (images -> network -> DMP rollout) of prediction, evaluation and validation
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from .._lazy import exports

_NAMES = {
    "COST_NAMES": ".costs",
    "Cost": ".costs",
    "dmp_trajectory": ".costs",
    "parameter_cost": ".costs",
    "trajectory_cost": ".costs",
    "trajectory_error_px": ".costs",
    "dmp_trajectories": ".inference",
    "hypothesis_trajectories": ".inference",
    "network_outputs": ".inference",
    "ConvEncoder": ".model",
    "EncoderDecoder": ".model",
    "FullyConnectedEncoder": ".model",
    "ModelConfig": ".model",
    "build_model": ".model",
    "split_hypotheses": ".model",
    "top_hypothesis": ".model",
    "ParamNormaliser": ".normalise",
}

if TYPE_CHECKING:  # the real imports, for type checkers and IDEs
    from .costs import (
        COST_NAMES,
        Cost,
        dmp_trajectory,
        parameter_cost,
        trajectory_cost,
        trajectory_error_px,
    )
    from .inference import dmp_trajectories, hypothesis_trajectories, network_outputs
    from .model import (
        ConvEncoder,
        EncoderDecoder,
        FullyConnectedEncoder,
        ModelConfig,
        build_model,
        split_hypotheses,
        top_hypothesis,
    )
    from .normalise import ParamNormaliser

__getattr__, __dir__ = exports(__name__, _NAMES, globals())

__all__ = [
    "COST_NAMES",
    "ConvEncoder",
    "Cost",
    "EncoderDecoder",
    "FullyConnectedEncoder",
    "ModelConfig",
    "ParamNormaliser",
    "build_model",
    "dmp_trajectories",
    "dmp_trajectory",
    "hypothesis_trajectories",
    "network_outputs",
    "parameter_cost",
    "split_hypotheses",
    "trajectory_cost",
    "top_hypothesis",
    "trajectory_error_px",
]
