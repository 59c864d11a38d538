"""Ridge from per-sample moments (predictor.moment_ridge) against scikit-learn's ridge on the
rows themselves."""

from __future__ import annotations

import numpy as np
import pytest
from sklearn.linear_model import Ridge
from sklearn.model_selection import GridSearchCV, GroupKFold
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from predictor.moment_ridge import RidgeForm, alpha_scores, fit_moment_ridge, group_statistics

ALPHAS = (1e-3, 1e-1, 1.0, 10.0, 1e3)


def noisy_linear(samples: int, features: int, outputs: int, seed: int):
    gen = np.random.default_rng(seed)
    x = gen.normal(size=(samples, features)) * gen.uniform(0.01, 10.0, size=features)
    y = x @ gen.normal(size=(features, outputs)) + gen.normal(size=(samples, outputs))
    groups = gen.integers(0, 12, size=samples)
    return x, y, groups


def grid_search(x, y, groups, alphas, folds: int, centred: bool = True) -> GridSearchCV:
    """scikit-learn's cross-validated standardised ridge, fitted (the reference); uncentred:
    no centring and no intercept."""
    return GridSearchCV(
        make_pipeline(StandardScaler(with_mean=centred), Ridge(fit_intercept=centred)),
        {"ridge__alpha": list(alphas)},
        cv=GroupKFold(n_splits=folds),
        scoring="neg_mean_squared_error",
    ).fit(x, y, groups=groups)


def test_one_row_per_sample_is_scikit_learns_cross_validated_standardised_ridge():
    x, y, groups = noisy_linear(90, 5, 3, seed=0)
    moment = x[:, :, None] * x[:, None, :]
    coef, intercept, alpha = fit_moment_ridge(x, moment, y, groups, ALPHAS, folds=5)
    search = grid_search(x, y, groups, ALPHAS, folds=5)
    assert alpha == search.best_params_["ridge__alpha"]
    expected = search.best_estimator_.predict(x)
    np.testing.assert_allclose(x @ coef + intercept, expected, rtol=1e-8, atol=1e-8)


def scores_of(x, moment, y, groups, alphas, folds, weights=None):
    """alpha_scores on one-sample-per-row inputs, through the per-group sums as the fit uses."""
    weights = np.ones(len(x)) if weights is None else weights
    names, inverse = np.unique(groups, return_inverse=True)
    stats = group_statistics(x, moment, y, weights, inverse, len(names))
    return alpha_scores(x, y, weights, inverse, stats, alphas, folds)


def test_every_alphas_score_is_grid_search_cvs_mean_test_score():
    # the scores come from one eigendecomposition per fold, not a solve per alpha: each must
    # still be scikit-learn's held-out mean squared error, averaged over the folds
    alphas = tuple(np.logspace(-3, 4, 15))
    x, y, groups = noisy_linear(120, 8, 4, seed=5)
    scores = scores_of(x, x[:, :, None] * x[:, None, :], y, groups, alphas, folds=5)
    search = grid_search(x, y, groups, alphas, folds=5)
    np.testing.assert_allclose(scores, -search.cv_results_["mean_test_score"], rtol=1e-9)


def test_identical_training_samples_make_features_constant_and_alphas_tied():
    # each fold trains on one sample whose weight is not one: E[x^2] - E[x]^2 is then rounding
    # (~1e-17), not zero. As constant features every alpha predicts the training target, so
    # the scores are the squared differences of the two targets, tied, and the first alpha wins
    gen = np.random.default_rng(6)
    x = gen.normal(size=(2, 5)) * 40.0
    y = gen.normal(size=(2, 3))
    weights = np.array([0.49416956178705473, 0.4679919906271712])
    moment = x[:, :, None] * x[:, None, :]
    groups = np.array([0, 1])
    scores = scores_of(x, moment, y, groups, ALPHAS, folds=2, weights=weights)
    expected = np.mean((y[0] - y[1]) ** 2)
    np.testing.assert_allclose(scores, expected, rtol=1e-12)
    _, _, alpha = fit_moment_ridge(x, moment, y, groups, ALPHAS, folds=2, weights=weights)
    assert alpha == ALPHAS[0]


@pytest.mark.parametrize("alpha", [1e-3, 1.0, 100.0])
def test_weighted_rows_are_scikit_learns_weighted_ridge_on_those_rows(alpha: float):
    gen = np.random.default_rng(1)
    samples, rows, features = 40, 4, 3  # each sample: 4 rows with weights summing to one
    x = gen.normal(size=(samples, rows, features)) * np.array([1.0, 5.0, 0.1])
    weight = gen.dirichlet(np.ones(rows), size=samples)  # (K, R)
    y = gen.normal(size=(samples, 2)) + x[:, 0] @ gen.normal(size=(features, 2))
    mean = np.einsum("kr,krf->kf", weight, x)
    moment = np.einsum("kr,krf,krg->kfg", weight, x, x)
    groups = np.arange(samples) % 8
    coef, intercept, chosen = fit_moment_ridge(mean, moment, y, groups, (alpha,), folds=4)
    assert chosen == alpha
    flat_x, flat_w = x.reshape(-1, features), weight.reshape(-1)
    flat_y = np.repeat(y, rows, axis=0)
    scaler = StandardScaler().fit(flat_x, sample_weight=flat_w)
    ridge = Ridge(alpha=alpha).fit(scaler.transform(flat_x), flat_y, sample_weight=flat_w)
    np.testing.assert_allclose(coef, ridge.coef_.T / scaler.scale_[:, None], rtol=1e-7)
    np.testing.assert_allclose(intercept, ridge.intercept_ - scaler.mean_ @ coef, atol=1e-9)


@pytest.mark.parametrize("alpha", [1e-3, 10.0])
def test_sample_weights_scale_each_samples_rows_as_scikit_learns_sample_weight(alpha: float):
    gen = np.random.default_rng(3)
    samples, rows, features = 30, 3, 3
    x = gen.normal(size=(samples, rows, features)) * np.array([2.0, 0.5, 1.0])
    share = gen.dirichlet(np.ones(rows), size=samples)  # (K, R), rows of a sample sum to one
    mass = gen.uniform(0.05, 1.0, size=samples)  # each sample's total weight
    y = gen.normal(size=(samples, 2)) + x[:, 1] @ gen.normal(size=(features, 2))
    mean = np.einsum("kr,krf->kf", share, x)
    moment = np.einsum("kr,krf,krg->kfg", share, x, x)
    groups = np.arange(samples) % 6
    coef, intercept, _ = fit_moment_ridge(mean, moment, y, groups, (alpha,), folds=3, weights=mass)
    flat_x, flat_w = x.reshape(-1, features), (mass[:, None] * share).reshape(-1)
    flat_y = np.repeat(y, rows, axis=0)
    scaler = StandardScaler().fit(flat_x, sample_weight=flat_w)
    ridge = Ridge(alpha=alpha).fit(scaler.transform(flat_x), flat_y, sample_weight=flat_w)
    np.testing.assert_allclose(coef, ridge.coef_.T / scaler.scale_[:, None], rtol=1e-7)
    np.testing.assert_allclose(intercept, ridge.intercept_ - scaler.mean_ @ coef, atol=1e-9)
    unit = fit_moment_ridge(mean, moment, y, groups, ALPHAS, 3, weights=np.ones(samples))
    plain = fit_moment_ridge(mean, moment, y, groups, ALPHAS, 3)
    np.testing.assert_array_equal(unit[0], plain[0])
    assert unit[2] == plain[2]
    with pytest.raises(ValueError, match="positive"):
        fit_moment_ridge(mean, moment, y, groups, ALPHAS, 3, weights=np.zeros(samples))


def test_one_group_cannot_be_cross_validated():
    x, y, _ = noisy_linear(10, 2, 1, seed=2)
    with pytest.raises(ValueError, match="two groups"):
        fit_moment_ridge(x, x[:, :, None] * x[:, None, :], y, np.zeros(10), ALPHAS, folds=5)


def test_uncentred_form_is_scikit_learns_ridge_without_centring_or_intercept():
    # the targets have an offset the uncentred form cannot fit: it must still be scikit-learn's
    # fit of the same form (alpha, predictions), with a zero intercept
    x, y, groups = noisy_linear(90, 5, 3, seed=7)
    y = y + 4.0
    moment = x[:, :, None] * x[:, None, :]
    form = RidgeForm(centred=False)
    coef, intercept, alpha = fit_moment_ridge(x, moment, y, groups, ALPHAS, folds=5, form=form)
    search = grid_search(x, y, groups, ALPHAS, folds=5, centred=False)
    assert alpha == search.best_params_["ridge__alpha"]
    assert not intercept.any()
    np.testing.assert_allclose(x @ coef, search.best_estimator_.predict(x), rtol=1e-8, atol=1e-8)
    names, inverse = np.unique(groups, return_inverse=True)
    stats = group_statistics(x, moment, y, np.ones(len(x)), inverse, len(names))
    scores = alpha_scores(x, y, np.ones(len(x)), inverse, stats, ALPHAS, 5, form)
    np.testing.assert_allclose(scores, -search.cv_results_["mean_test_score"], rtol=1e-9)


@pytest.mark.parametrize("centred", [True, False])
def test_min_std_scales_a_nearly_constant_feature_by_the_floor(centred: bool):
    # feature 1 varies by ~1e-6 (rounding-like); with a floor of 1e-3 it is scaled by 1e-3, so
    # the penalty on its coefficient is alpha (b * 1e-3)^2: scikit-learn's ridge on x / scale
    gen = np.random.default_rng(8)
    x = np.stack([gen.normal(size=60), 1e-6 * gen.normal(size=60)], axis=1)
    y = x[:, :1] * 2.0 + gen.normal(size=(60, 1)) + 1e4 * x[:, 1:]
    groups = np.arange(60) % 6
    alpha = 10.0
    form = RidgeForm(centred=centred, min_std=1e-3)
    moment = x[:, :, None] * x[:, None, :]
    coef, intercept, _ = fit_moment_ridge(x, moment, y, groups, (alpha,), folds=3, form=form)
    scale = np.maximum(x.std(0), 1e-3)
    assert scale[1] == 1e-3
    ridge = Ridge(alpha=alpha, fit_intercept=centred).fit(x / scale, y)
    np.testing.assert_allclose(coef[:, 0], ridge.coef_.ravel() / scale, rtol=1e-6)
    np.testing.assert_allclose(intercept, np.atleast_1d(ridge.intercept_), atol=1e-9)
    # unfloored, the same feature is standardised to unit variance and read far more
    plain, _, _ = fit_moment_ridge(
        x, moment, y, groups, (alpha,), folds=3, form=RidgeForm(centred=centred)
    )
    assert abs(plain[1, 0]) > 10 * abs(coef[1, 0])


def test_group_statistics_are_each_groups_weighted_sums():
    # unsorted groups, weights and moments that are not outer products of the means (edge
    # rows): every statistic against an explicit sum over the group's samples
    gen = np.random.default_rng(11)
    samples, features, outputs, count = 40, 4, 3, 6
    mean = gen.normal(size=(samples, features))
    moment = gen.normal(size=(samples, features, features))
    target = gen.normal(size=(samples, outputs))
    weights = gen.uniform(0.1, 2.0, size=samples)
    group = gen.permutation(np.arange(samples) % count)
    stats = group_statistics(mean, moment, target, weights, group, count)
    for g in range(count):
        rows = group == g
        w = weights[rows]
        expected = (
            w.sum(),
            w @ mean[rows],
            w @ target[rows],
            np.einsum("n,nij->ij", w, moment[rows]),
            np.einsum("n,ni,nd->id", w, mean[rows], target[rows]),
        )
        for got, want in zip(stats, expected, strict=True):
            np.testing.assert_allclose(got[g], want, rtol=1e-12, atol=1e-12)


def test_group_statistics_refuse_a_group_without_samples():
    x, y, _ = noisy_linear(10, 2, 1, seed=3)
    group = np.array([0, 0, 2, 2, 0, 2, 0, 0, 2, 2])  # group 1 of 3 is empty
    with pytest.raises(ValueError, match="at least one sample"):
        group_statistics(x, x[:, :, None] * x[:, None, :], y, np.ones(10), group, 3)
