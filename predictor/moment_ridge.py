"""Standardised ridge regression fitted from per-sample moments, alpha by grouped
cross-validation.

The attended highway's per-edge fit (`ModelConfig.attended_fit` "edges") regresses an agent's
future on each of its edges in turn, weighted by the attention: rows x_ij = (own_i, z_ij) with
weight theta_ij, the weights of an agent summing to one. Its normal equations need only each
agent's attention-weighted mean E[x] and second moment E[x x^T] of its rows, so the fit runs on
one sample per agent (N samples with F x F moments, instead of N (N-1) weighted rows), and the
cross-validation's folds are sums of per-group statistics. Under "edge_relations" an agent is
one sample per relation (ahead, behind) whose rows weigh that relation's share of its attention
(`weights`). With one row per sample
(E[x x^T] = E[x] E[x]^T) it is scikit-learn's StandardScaler + Ridge (tested); with
`RidgeForm(centred=False)` it is StandardScaler(with_mean=False) + Ridge(fit_intercept=False), a
map that is zero where the features are (the highway's form that is zero at constant velocity,
`ModelConfig.highway_zero_at_cv`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse
from threadpoolctl import threadpool_limits

# a feature whose variance is below this fraction of its mean square counts as constant
# (scaled by 1, as scikit-learn does): the moments give a variance only to rounding
CONSTANT_RELATIVE_VARIANCE = 1e-12


@dataclass(frozen=True)
class RidgeForm:
    """How the regression treats its features. centred: features and targets centred, with
    an intercept (scikit-learn's defaults); off, the raw moments and no intercept, so the map
    is zero where the features are. min_std: the least standard deviation a feature is scaled
    by (0: scikit-learn's), so that a feature constant up to rounding is not blown up to unit
    variance and read (`ModelConfig.highway_min_std`)."""

    centred: bool = True
    min_std: float = 0.0


def fit_moment_ridge(
    mean: np.ndarray,
    moment: np.ndarray,
    target: np.ndarray,
    groups: np.ndarray,
    alphas: tuple[float, ...],
    folds: int,
    weights: np.ndarray | None = None,
    form: RidgeForm = RidgeForm(),
) -> tuple[np.ndarray, np.ndarray, float]:
    """Ridge on standardised features from each sample's weighted rows, given by their mean
    (K, F) and second moment (K, F, F) (row weights summing to one per sample, or to the
    sample's `weights` (K,), positive, where given), targets (K, D) and groups (K,) (e.g.
    scenes, never split by a fold). Minimises sum_k w_k E_k |y_k - x b - c|^2 + alpha |s b|^2,
    s the features' standard deviations over all rows (weighted, population, 1 where zero),
    as Ridge on StandardScaler's output does. Alpha is the one of `alphas` with the smallest
    (weighted) mean squared error of the held-out samples' predictions E_k[x] b + c, averaged
    over min(folds, groups) folds of whole groups (scikit-learn's GroupKFold assignment, by
    sample counts). `form`: centring and the least scale (`RidgeForm`). Returns coef (F, D),
    intercept (D,) and that alpha."""
    names, inverse = np.unique(groups, return_inverse=True)
    if len(names) < 2:
        raise ValueError(f"ridge cross-validation needs at least two groups, got {len(names)}")
    if weights is None:
        weights = np.ones(len(mean))
    elif not np.all(weights > 0):
        raise ValueError("fit_moment_ridge: sample weights must be positive")
    stats = group_statistics(mean, moment, target, weights, inverse, len(names))
    # one BLAS thread, as fit_ridge_cv (predictor.ridge_cv): the solves are small (15 alphas
    # x 5 folds per map), and OpenBLAS's default threads compete with the trainings beside
    # it. On 2 cores with two trainings running, a refit of the agent preset on Halting Car
    # v1's 52 training scenes took 7.5-9.1 s with them and 5.9-6.6 s with one
    with threadpool_limits(limits=1):
        fit = cross_validated(mean, target, weights, inverse, stats, alphas, folds, form)
    return fit[:3]


def cross_validated(
    mean: np.ndarray,
    target: np.ndarray,
    weights: np.ndarray,
    inverse: np.ndarray,
    stats: tuple[np.ndarray, ...],
    alphas: tuple[float, ...],
    folds: int,
    form: RidgeForm = RidgeForm(),
) -> tuple[np.ndarray, np.ndarray, float, float]:
    """`fit_moment_ridge`'s alpha search and final fit from the per-group statistics
    (`group_statistics`); inverse (K,) is each sample's group index. Returns coef, intercept,
    the chosen alpha and its cross-validated score (`alpha_scores`). The caller limits the
    BLAS threads (see fit_moment_ridge)."""
    scores = alpha_scores(mean, target, weights, inverse, stats, alphas, folds, form)
    chosen = int(np.argmin(scores))  # the first of the best, as GridSearchCV
    best = float(alphas[chosen])
    coef, intercept = _solve(*(s.sum(0) for s in stats), best, form)
    return coef, intercept, best, float(scores[chosen])


def alpha_scores(
    mean: np.ndarray,
    target: np.ndarray,
    weights: np.ndarray,
    inverse: np.ndarray,
    stats: tuple[np.ndarray, ...],
    alphas: tuple[float, ...],
    folds: int,
    form: RidgeForm = RidgeForm(),
) -> np.ndarray:
    """Cross-validated score of each alpha (A,): the held-out samples' (weighted) mean squared
    error, averaged over the folds (GridSearchCV's mean test score, negated). Each fold's fits
    for all alphas come from one eigendecomposition of its standardised gram (`_alpha_path`)
    instead of a solve per alpha: the agent preset's refit does 72 of these searches, 5 folds x
    15 alphas each."""
    fold_of_group = _group_folds(np.bincount(inverse), min(folds, len(stats[0])))
    num_folds = fold_of_group.max() + 1
    # each fold's training sums at once: a (folds x groups) 0/1 matrix of the groups outside
    # the fold times each statistic's groups as rows (one product instead of a selection and
    # a sum per fold and statistic)
    outside = (fold_of_group[None, :] != np.arange(num_folds)[:, None]).astype(np.float64)
    trains = [(outside @ s.reshape(len(s), -1)).reshape(num_folds, *s.shape[1:]) for s in stats]
    path = np.asarray(alphas, dtype=np.float64)
    scores = np.zeros(len(path))
    for fold in range(num_folds):
        held = fold_of_group[inverse] == fold  # (K,)
        train = tuple(float(t[fold]) if t.ndim == 1 else t[fold] for t in trains)
        squared = _alpha_path(*train, mean[held], target[held], path, form)  # (A, K_held)
        scores += squared @ (weights[held] / weights[held].sum())
    return scores / num_folds


def group_statistics(
    mean: np.ndarray,
    moment: np.ndarray,
    target: np.ndarray,
    weights: np.ndarray,
    group: np.ndarray,
    count: int,
) -> tuple[np.ndarray, ...]:
    """Per group, weighted by the samples' weights w: sum of w (G,), of w E[x] (G, F), of w y
    (G, D), of w E[x x^T] (G, F, F) and of w E[x] y^T (G, F, D)."""
    # as products: the sums of w E[x x^T] are a sparse (groups x samples) matrix of the weights
    # times the moments as rows of F^2, and the cross sums one (F x n_g) @ (n_g x D) product
    # per group, so no (n, F, F) or (n, F, D) temporary is made. On the agent preset's refit
    # (Double Merge v1 ratio 0.3, 52 training scenes, 18 maps of 71 features, ~4,400 samples)
    # the 14 calls took 0.07 s this way against 0.64 s sorting the samples and summing the
    # weighted moments and an explicit (n, F, D) product with np.add.reduceat (which had
    # replaced np.add.at's slower unbuffered scatter). Every group in [0, count) needs samples
    # (the caller's np.unique inverse).
    sizes = np.bincount(group, minlength=count)
    if len(sizes) != count or not np.all(sizes > 0):
        raise ValueError("group_statistics: every group needs at least one sample")
    # (G, n) sparse: w of each group's samples (a dense one would grow with groups x samples)
    indicator = sparse.csr_array((weights, (group, np.arange(len(group)))), (count, len(group)))
    samples = indicator @ np.ones(len(group))
    sum_x = indicator @ mean
    sum_y = indicator @ target
    num_features = mean.shape[1]
    sum_xx = (indicator @ moment.reshape(len(group), -1)).reshape(count, num_features, -1)
    weighted_x = weights[:, None] * mean  # (n, F)
    sum_xy = np.empty((count, num_features, target.shape[1]))
    order = np.argsort(group, kind="stable")
    bounds = np.r_[0, np.cumsum(sizes)]
    for index in range(count):
        rows = order[bounds[index] : bounds[index + 1]]
        np.matmul(weighted_x[rows].T, target[rows], out=sum_xy[index])
    return samples, sum_x, sum_y, sum_xx, sum_xy


def _group_folds(sizes: np.ndarray, folds: int) -> np.ndarray:
    """Fold of each group (G,) as scikit-learn's GroupKFold assigns them: largest groups
    first, each to the fold with the fewest samples so far."""
    load = np.zeros(folds)
    fold_of_group = np.zeros(len(sizes), dtype=np.int64)
    for group in np.argsort(sizes, kind="stable")[::-1]:
        fold = int(np.argmin(load))
        fold_of_group[group] = fold
        load[fold] += sizes[group]
    return fold_of_group


def _moments(
    samples: float,
    sum_x: np.ndarray,
    sum_y: np.ndarray,
    sum_xx: np.ndarray,
    sum_xy: np.ndarray,
    form: RidgeForm,
) -> tuple[np.ndarray, ...]:
    """Means x_bar (F,), y_bar (D,), centred moments G_c (F, F), C_c (F, D) and the features'
    variances s^2 = diag(G_c) / n (1 for a constant feature, as scikit-learn scales it; at
    least form.min_std^2). Uncentred (`RidgeForm`): zero means and the raw moments sum_xx,
    sum_xy (a constant feature is then a feature like any other), the variances as centred."""
    x_bar, y_bar = sum_x / samples, sum_y / samples
    gram = sum_xx - samples * np.outer(x_bar, x_bar)
    cross = sum_xy - samples * np.outer(x_bar, y_bar)
    variance = np.diag(gram) / samples
    # constant: a variance within the rounding of E[x^2] - E[x]^2 (a few float64 eps of the
    # mean square). On rows of identical features (Double Merge 3 + 10's relation maps, fits
    # of 2-10 samples) that difference left ~1e-15, which standardising blew up to entries as
    # large as the gram's own; scikit-learn, computing the variance from the rows, finds 0
    mean_square = np.diag(sum_xx) / samples
    constant = variance <= np.maximum(CONSTANT_RELATIVE_VARIANCE * mean_square, 1e-20)
    # centred, a constant feature is zero: its rows of the moments are rounding, dropped
    variance = np.maximum(np.where(constant, 1.0, variance), form.min_std**2)
    if not form.centred:
        return np.zeros_like(x_bar), np.zeros_like(y_bar), sum_xx, sum_xy, variance
    gram[constant] = 0.0
    gram[:, constant] = 0.0
    cross[constant] = 0.0
    return x_bar, y_bar, gram, cross, variance


def _solve(
    samples: float,
    sum_x: np.ndarray,
    sum_y: np.ndarray,
    sum_xx: np.ndarray,
    sum_xy: np.ndarray,
    alpha: float,
    form: RidgeForm,
) -> tuple[np.ndarray, np.ndarray]:
    """Coefficients on raw features (F, D) and intercept (D,) of the standardised ridge:
    (G_c + alpha diag(s^2)) b = C_c with the centred moments G_c, C_c and s^2 (`_moments`;
    uncentred, the raw moments and a zero intercept)."""
    x_bar, y_bar, gram, cross, variance = _moments(samples, sum_x, sum_y, sum_xx, sum_xy, form)
    coef = np.linalg.solve(gram + alpha * np.diag(variance), cross)
    return coef, y_bar - x_bar @ coef


def _alpha_path(
    samples: float,
    sum_x: np.ndarray,
    sum_y: np.ndarray,
    sum_xx: np.ndarray,
    sum_xy: np.ndarray,
    held_x: np.ndarray,
    held_y: np.ndarray,
    alphas: np.ndarray,
    form: RidgeForm,
) -> np.ndarray:
    """Mean squared error over the outputs of each held-out sample (A, K) under `_solve`'s
    fit for each alpha (A,), equal to it up to rounding: with S = diag(s) and the standardised
    gram S^-1 G_c S^-1 = Q diag(lambda) Q^T, b = S^-1 Q diag(1 / (lambda + alpha)) Q^T S^-1 C_c,
    so one eigendecomposition serves every alpha."""
    x_bar, y_bar, gram, cross, variance = _moments(samples, sum_x, sum_y, sum_xx, sum_xy, form)
    inverse_scale = 1.0 / np.sqrt(variance)
    standard_gram = gram * inverse_scale[:, None] * inverse_scale[None, :]
    eigenvalues, vectors = np.linalg.eigh(standard_gram)
    held = ((held_x - x_bar) * inverse_scale) @ vectors  # (K, F) in the eigenbasis
    rotated = vectors.T @ (cross * inverse_scale[:, None])  # (F, D)
    shrink = 1.0 / (eigenvalues[None, :] + alphas[:, None])  # (A, F)
    # one (A K, F) @ (F, D) product for every alpha's predictions
    scaled = (held[None] * shrink[:, None, :]).reshape(-1, held.shape[1])  # (A K, F)
    error = (scaled @ rotated).reshape(len(alphas), *held_y.shape) + (y_bar - held_y)
    return np.einsum("akd,akd->ak", error, error) / held_y.shape[1]  # (A, K)
