"""The highway's closed-form fits (predictor.highway reads the maps they make).

Each map is a ridge regression (alpha by grouped cross-validation, one map per agent role or
map slot, as the ridge baseline) from an agent's history features (and, for the attended
highway, its attended features) to its future offsets from constant velocity, stored as
per-step velocity changes. It is fitted on the training split when the model's normalisation
is, and with `ModelConfig.attended_refit` again at every epoch start jointly with the attended
map (`SmoothAttentionPredictor.refit_attended`); `fit_cross_fitted` also fits one map without
each cross-fitting fold (`predictor.highway.CROSS_FIT_FOLDS`).

`ModelConfig.highway_zero_at_cv` fits each map a second time in a form that is zero at constant
velocity (the own history's velocity changes, no intercept, no attended reading) and keeps the
form with the lower cross-validated error: a map fitted on cases that differ in their base rate
(Halting Car's `stop` and `go`) otherwise predicts part of one case's manoeuvre for an agent that
drives on at constant speed in the other. `change_bounds` gives each map's output range, to
which predictor.highway clamps it.
"""

from __future__ import annotations

import numpy as np
import torch
from threadpoolctl import threadpool_limits
from torch import Tensor

from predictor.highway import CROSS_FIT_FOLDS, fold_of
from predictor.moment_ridge import RidgeForm, cross_validated, group_statistics
from predictor.ridge_cv import fit_ridge_cv

HIGHWAY_ALPHAS: tuple[float, ...] = tuple(float(a) for a in np.logspace(-3, 4, 15))
HIGHWAY_FOLDS = 5  # grouped cross-validation folds (fewer if there are fewer training scenes)


def fit_highway(
    features: Tensor,
    offsets: Tensor,
    usable: Tensor,
    roles: Tensor,
    num_roles: int,
    horizon: int,
    moments: Tensor | None = None,
    weights: Tensor | None = None,
) -> tuple[Tensor, Tensor, dict[int, float]]:
    """Per-role linear maps from history features (B, N, F) to velocity changes.

    offsets (B, N, T_pred, 2) are the targets (offsets from constant velocity), `usable` (B, N)
    the samples to fit on, roles (B, N) in [0, num_roles). With `moments` (B, N, F, F) each
    sample stands for weighted rows whose mean is its features and whose second moment is
    that (the attended highway's per-edge fit; predictor.moment_ridge), and `weights` (B, N),
    positive where usable, the total weight of each sample's rows (one without). Returns
    weight (R, F, horizon, 2), bias (R, horizon, 2) and the chosen alpha per fitted role.
    Steps beyond the data's T_pred repeat its last velocity change; a role with fewer than two
    training scenes keeps zeros (constant velocity).
    """
    every_scene = torch.ones(features.shape[0], dtype=torch.bool)
    return fit_highway_subsets(
        features, offsets, usable, roles, num_roles, horizon, [every_scene], moments, weights
    )[0]


def fit_highway_subsets(
    features: Tensor,
    offsets: Tensor,
    usable: Tensor,
    roles: Tensor,
    num_roles: int,
    horizon: int,
    subsets: list[Tensor],
    moments: Tensor | None = None,
    weights: Tensor | None = None,
    zero_at_cv: Tensor | None = None,
    min_std: float = 0.0,
) -> list[tuple[Tensor, Tensor, dict[int, float]]]:
    """`fit_highway` on the scenes of each subset (B,) bool, in one pass: the same maps and
    alphas as fitting each subset's scenes alone (bit for bit, tested), with the per-scene
    sums of the moment fit (`group_statistics`) computed once for all subsets and one BLAS
    thread limit for all the solves. For the cross-fitting's six fits this took the agent
    preset's refit on Halting Car v1's 52 training scenes from 5.4-5.7 s to 3.3-3.4 s (beside
    three trainings on 2 cores; benchmarks/README.md).

    zero_at_cv (F', F), with moments: each map is also fitted in the form that is zero at
    constant velocity (`ModelConfig.highway_zero_at_cv`): on the features mapped by this
    transform (`constant_velocity_transform`), uncentred, with no intercept; per role and
    subset the form with the lower cross-validated error is kept (its map on the raw
    features, bias zero). min_std, with moments: the least standardising scale of a feature
    (`ModelConfig.highway_min_std`)."""
    if weights is not None and moments is None:
        raise ValueError("fit_highway: sample weights need moments")
    if (zero_at_cv is not None or min_std > 0) and moments is None:
        raise ValueError("fit_highway: the zero-at-constant-velocity form and min_std need moments")
    affine, zero_form = RidgeForm(min_std=min_std), RidgeForm(centred=False, min_std=min_std)
    num_features, num_pred = features.shape[-1], offsets.shape[2]
    fitted = min(num_pred, horizon)
    results = [
        (
            torch.zeros(num_roles, num_features, horizon, 2, dtype=torch.float64),
            torch.zeros(num_roles, horizon, 2, dtype=torch.float64),
            {},
        )
        for _ in subsets
    ]
    scene = torch.arange(features.shape[0]).view(-1, 1).expand(usable.shape)
    chosen = [subset.numpy() for subset in subsets]  # (B,) each
    # one BLAS thread for all the solves (as fit_moment_ridge, which limits per call)
    with threadpool_limits(limits=1):
        for role in range(num_roles):
            rows = usable & (roles == role)
            groups = scene[rows].numpy()  # (K,) scene of each sample
            x = features[rows].double().numpy()  # (K, F)
            y = offsets[rows][:, :fitted].flatten(1).double().numpy()  # (K, fitted * 2)
            if moments is None:
                fits = _plain_fits(x, y, groups, chosen)
            else:
                second = moments[rows].double().numpy()  # (K, F, F)
                mass = np.ones(len(x)) if weights is None else weights[rows].double().numpy()
                fits = _moment_fits(x, second, y, mass, groups, chosen, affine)
                if zero_at_cv is not None:
                    transform = zero_at_cv.double().numpy()  # (F', F)
                    read = transform.any(0)  # the features it reads: the moments' cost is F^2
                    part, inner = transform[:, read], second[:, read][:, :, read]
                    zero = _moment_fits(
                        x[:, read] @ part.T,
                        part @ inner @ part.T,
                        y,
                        mass,
                        groups,
                        chosen,
                        zero_form,
                    )
                    fits = [_lower_score(a, b, transform) for a, b in zip(fits, zero, strict=True)]
            for (weight, bias, alphas), fit in zip(results, fits, strict=True):
                if fit is None:
                    continue
                coef, intercept, alphas[role], _ = fit
                _store_map(weight[role], bias[role], coef, intercept, fitted)
    return [(weight.float(), bias.float(), alphas) for weight, bias, alphas in results]


# coef (F, D) and intercept (D,) on raw features, alpha, cross-validated mean squared error
Fit = tuple[np.ndarray, np.ndarray, float, float]


def _plain_fits(
    x: np.ndarray, y: np.ndarray, groups: np.ndarray, subsets: list[np.ndarray]
) -> list[Fit | None]:
    """Ridge (fit_ridge_cv) on the samples of each subset's scenes; None with < 2 scenes."""
    fits: list[Fit | None] = []
    for subset in subsets:
        keep = subset[groups]
        if len(np.unique(groups[keep])) < 2:
            fits.append(None)
            continue
        model, alpha = fit_ridge_cv(x[keep], y[keep], groups[keep], HIGHWAY_ALPHAS, HIGHWAY_FOLDS)
        scaler, ridge = model[0], model[-1]
        coef = ridge.coef_.T / scaler.scale_[:, None]  # (F, D) on raw features
        fits.append((coef, ridge.intercept_ - scaler.mean_ @ coef, alpha, float("nan")))
    return fits


def _moment_fits(
    x: np.ndarray,
    second: np.ndarray,
    y: np.ndarray,
    mass: np.ndarray,
    groups: np.ndarray,
    subsets: list[np.ndarray],
    form: RidgeForm,
) -> list[Fit | None]:
    """fit_moment_ridge on the samples of each subset's scenes, from per-scene sums computed
    once: a subset's sums are its scenes' rows of them, and its samples keep their order, so
    each fit is the one on the subset alone. None with < 2 scenes. `form`: centring and the
    least scale (`RidgeForm`)."""
    if not np.all(mass > 0):
        raise ValueError("fit_highway: sample weights must be positive where usable")
    names, inverse = np.unique(groups, return_inverse=True)
    if len(names) < 2:
        return [None] * len(subsets)
    stats = group_statistics(x, second, y, mass, inverse, len(names))
    fits: list[Fit | None] = []
    for subset in subsets:
        kept = subset[names]  # (G,) groups of this subset
        if kept.sum() < 2:
            fits.append(None)
            continue
        keep = kept[inverse]  # (K,) its samples
        renumbered = (np.cumsum(kept) - 1)[inverse[keep]]  # group index within the subset
        fits.append(
            cross_validated(
                x[keep],
                y[keep],
                mass[keep],
                renumbered,
                tuple(s[kept] for s in stats),
                HIGHWAY_ALPHAS,
                HIGHWAY_FOLDS,
                form,
            )
        )
    return fits


def _lower_score(affine: Fit | None, zero: Fit | None, transform: np.ndarray) -> Fit | None:
    """Of a subset's two fits, the one with the lower cross-validated error (the affine one on
    a tie); the zero-at-constant-velocity fit's coefficients mapped back to the raw features
    (F, D) through the transform (F', F). Both were scored on the same held-out samples (the
    folds follow the groups' sizes only)."""
    if affine is None or zero is None or affine[3] <= zero[3]:
        return affine
    coef, intercept, alpha, score = zero
    return transform.T @ coef, intercept, alpha, score


def _store_map(
    weight: Tensor, bias: Tensor, coef: np.ndarray, intercept: np.ndarray, fitted: int
) -> None:
    """Write one role's map, weight (F, horizon, 2) and bias (horizon, 2), from a fit of the
    offsets of `fitted` steps: per-step velocity changes (differences along the predicted
    steps), steps beyond `fitted` repeating the last."""
    coef_t = torch.from_numpy(coef).view(weight.shape[0], fitted, 2)
    intercept_t = torch.from_numpy(intercept).view(fitted, 2)
    weight[:, :fitted] = torch.diff(coef_t, dim=1, prepend=torch.zeros_like(coef_t[:, :1]))
    bias[:fitted] = torch.diff(intercept_t, dim=0, prepend=torch.zeros_like(intercept_t[:1]))
    weight[:, fitted:] = weight[:, fitted - 1 : fitted]
    bias[fitted:] = bias[fitted - 1 : fitted]


def change_bounds(
    offsets: Tensor, samples: Tensor, maps: Tensor, num_maps: int, horizon: int
) -> tuple[Tensor, Tensor]:
    """The range of each map's training targets as per-step velocity changes: low and high
    (R, horizon, 2), the smallest and largest change over the samples (B, N) fitted with map r
    (maps (B, N)) at each predicted step and axis, widened to include zero (constant velocity,
    the output of a map without training scenes). offsets (B, N, T_pred, 2) as `fit_highway`'s;
    steps beyond T_pred repeat the last step's range."""
    changes = torch.diff(offsets, dim=2, prepend=torch.zeros_like(offsets[:, :, :1]))
    fitted = min(offsets.shape[2], horizon)
    low = offsets.new_zeros(num_maps, horizon, 2)
    high = offsets.new_zeros(num_maps, horizon, 2)
    for index in range(num_maps):
        rows = samples & (maps == index)
        if not rows.any():
            continue
        seen = changes[rows][:, :fitted]  # (K, fitted, 2)
        low[index, :fitted] = seen.amin(0).clamp(max=0.0)
        high[index, :fitted] = seen.amax(0).clamp(min=0.0)
        low[index, fitted:] = low[index, fitted - 1]
        high[index, fitted:] = high[index, fitted - 1]
    return low, high


def fit_cross_fitted(
    features: Tensor,
    offsets: Tensor,
    samples: Tensor,
    roles: Tensor,
    num_roles: int,
    horizon: int,
    moments: Tensor | None = None,
    weights: Tensor | None = None,
    zero_at_cv: Tensor | None = None,
    min_std: float = 0.0,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """`fit_highway` on all scenes (B, ...) and once without each cross-fitting fold (scene b is
    in fold b mod CROSS_FIT_FOLDS): weight (R, F, horizon, 2), bias (R, horizon, 2) and the
    fold maps (CROSS_FIT_FOLDS, R, F, horizon, 2), (CROSS_FIT_FOLDS, R, horizon, 2).
    zero_at_cv, min_std: as `fit_highway_subsets`'."""
    fold = fold_of(torch.arange(features.shape[0]), CROSS_FIT_FOLDS)  # (B,)
    subsets = [torch.ones_like(fold, dtype=torch.bool)]
    subsets += [fold != k for k in range(CROSS_FIT_FOLDS)]
    fits = fit_highway_subsets(
        features,
        offsets,
        samples,
        roles,
        num_roles,
        horizon,
        subsets,
        moments,
        weights,
        zero_at_cv,
        min_std,
    )
    fold_weight = torch.stack([weight for weight, _, _ in fits[1:]])
    fold_bias = torch.stack([bias for _, bias, _ in fits[1:]])
    return fits[0][0], fits[0][1], fold_weight, fold_bias
