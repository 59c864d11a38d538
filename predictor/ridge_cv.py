"""Standardised ridge regression with its penalty chosen by grouped k-fold cross-validation
(scikit-learn): the closed-form fitter behind the ridge baselines (`predictor.baselines`) and
the highway's maps (`predictor.highway_fit`). Folds never split a group (a scene), so the
penalty is chosen on scenes the fit has not seen. An optional block of columns gets a factor of
its own from the same search (banded ridge, Nunez-Elizalde et al., NeuroImage 2019).
"""

from __future__ import annotations

from typing import Any

import numpy as np


def scale_columns_from(x: np.ndarray, start: int, scale: float) -> np.ndarray:
    """x with its columns from `start` on multiplied by `scale` (a banded ridge's block)."""
    x = np.array(x, dtype=np.float64)
    x[:, start:] *= scale
    return x


def fit_ridge_cv(
    features: np.ndarray,
    target: np.ndarray,
    groups: np.ndarray,
    alphas: tuple[float, ...],
    folds: int,
    block: tuple[int, tuple[float, ...]] | None = None,
) -> tuple[Any, float]:
    """Standardised ridge regression with alpha chosen by grouped k-fold cross-validation
    (folds never split a group, e.g. a scene); returns the refitted scikit-learn pipeline
    (StandardScaler, Ridge) and the chosen alpha. Needs at least two groups.

    `block` (start, scales): the standardised features from column `start` on are multiplied
    by one of `scales`, chosen by the same cross-validation (the pipeline then has a
    FunctionTransformer between scaler and ridge); ignored where there are no such columns or
    the only scale is 1."""
    from sklearn.linear_model import Ridge
    from sklearn.model_selection import GridSearchCV, GroupKFold
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import FunctionTransformer, StandardScaler
    from threadpoolctl import threadpool_limits

    num_groups = len(np.unique(groups))
    if num_groups < 2:
        raise ValueError(f"ridge cross-validation needs at least two groups, got {num_groups}")
    steps, grid = [StandardScaler(), Ridge()], {"ridge__alpha": list(alphas)}
    if block is not None and block[0] < features.shape[1] and tuple(block[1]) != (1.0,):
        start, scales = block
        steps.insert(1, FunctionTransformer(scale_columns_from))
        grid["functiontransformer__kw_args"] = [{"start": start, "scale": s} for s in scales]
    search = GridSearchCV(
        make_pipeline(*steps),
        grid,
        cv=GroupKFold(n_splits=min(folds, num_groups)),
        scoring="neg_mean_squared_error",
    )
    # one BLAS thread: the problems are small, and on 2 cores measured as fast or faster
    # (0.9-1.8 s against 1.75-1.9 s for Double Merge's 52 training scenes)
    with threadpool_limits(limits=1):
        search.fit(features, target, groups=groups)
    return search.best_estimator_, float(search.best_params_["ridge__alpha"])
