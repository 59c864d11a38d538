"""The grouped cross-validated ridge fitter against the closed-form ridge solution."""

from __future__ import annotations

import numpy as np
import pytest

from predictor.ridge_cv import fit_ridge_cv


def problem(seed: int = 0, n: int = 60, features: int = 4):
    rng = np.random.default_rng(seed)
    x = rng.normal(size=(n, features)) * [1.0, 3.0, 0.5, 2.0][:features] + 1.0
    y = x @ rng.normal(size=(features, 2)) + rng.normal(scale=0.1, size=(n, 2))
    return x, y, np.arange(n) // 6  # 10 groups of 6 samples


def closed_form(x: np.ndarray, y: np.ndarray, alpha: float, query: np.ndarray) -> np.ndarray:
    """Ridge on standardised x (population std) with an unpenalised intercept."""
    mean, std = x.mean(0), x.std(0)
    z = (x - mean) / std
    weights = np.linalg.solve(z.T @ z + alpha * np.eye(x.shape[1]), z.T @ (y - y.mean(0)))
    return ((query - mean) / std) @ weights + y.mean(0)


def test_one_alpha_is_the_closed_form_ridge():
    x, y, groups = problem()
    model, alpha = fit_ridge_cv(x, y, groups, alphas=(2.5,), folds=5)
    assert alpha == 2.5
    np.testing.assert_allclose(model.predict(x[:7]), closed_form(x, y, 2.5, x[:7]), rtol=1e-9)


def test_cross_validation_picks_the_best_held_out_alpha():
    x, y, groups = problem(seed=1)
    alphas = (1e-3, 1e3)  # nearly unpenalised against far too strong on a low-noise problem
    _, alpha = fit_ridge_cv(x, y, groups, alphas=alphas, folds=5)
    assert alpha == 1e-3


def test_a_block_scaled_by_zero_is_dropped():
    x, y, groups = problem(seed=2)
    model, _ = fit_ridge_cv(x, y, groups, alphas=(1.0,), folds=5, block=(2, (0.0,)))
    np.testing.assert_allclose(
        model.predict(x[:5]), closed_form(x[:, :2], y, 1.0, x[:5, :2]), rtol=1e-9
    )


def test_one_group_is_refused():
    x, y, _ = problem()
    with pytest.raises(ValueError, match="at least two groups"):
        fit_ridge_cv(x, y, np.zeros(len(x)), alphas=(1.0,), folds=5)
