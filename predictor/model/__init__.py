"""The smooth-attention trajectory predictor `SmoothAttentionPredictor` (its module: predictor)."""

from predictor.model.predictor import SmoothAttentionPredictor, run_lstm

__all__ = ["SmoothAttentionPredictor", "run_lstm"]
