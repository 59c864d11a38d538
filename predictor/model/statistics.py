"""The fitted statistics' common ground: the floor of every fitted standard deviation and the
per-axis RMS that the output scales are (predictor.model.head, encoders, highway_maps)."""

from __future__ import annotations

from torch import Tensor

MIN_STAT_STD = 1e-4  # floor of the fitted standard deviations (in metres)


def floored_rms(values: Tensor) -> Tensor:
    """Root mean square over the first axis of `values` (K, C), floored at MIN_STAT_STD: the
    scale of an output whose zero is meaningful (a deviation from a prior)."""
    return values.pow(2).mean(0).sqrt().clamp(min=MIN_STAT_STD)
