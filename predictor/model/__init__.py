"""The smooth-attention trajectory predictor `SmoothAttentionPredictor` (its module: predictor)."""

from predictor.model.predictor import SmoothAttentionPredictor

__all__ = ["SmoothAttentionPredictor"]
