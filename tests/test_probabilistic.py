"""Best-of-K metrics and NLLs against hand-computed cases, the deterministic metrics at K = 1 and
scipy's densities."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import gaussian_kde, multivariate_normal

from predictor.metrics import displacement_metrics
from predictor.probabilistic import (
    KDE_LOG_PDF_LOWER_BOUND,
    KDE_MIN_STD_M,
    gaussian_nll,
    kde_nll,
    mixture_nll,
    sample_metrics,
)


def random_trils(rng: np.random.Generator, shape: tuple[int, ...]) -> np.ndarray:
    return np.stack(
        [rng.uniform(0.2, 2, shape), rng.normal(0, 1, shape), rng.uniform(0.2, 2, shape)], -1
    )


def covariance(tril: np.ndarray) -> np.ndarray:
    l11, l21, l22 = tril
    low = np.array([[l11, 0.0], [l21, l22]])
    return low @ low.T


def test_one_sample_gives_the_pooled_ade_and_fde_of_the_metrics():
    rng = np.random.default_rng(0)
    n, steps, agents = 7, 5, 4
    pred = rng.normal(0, 3, (n, steps, agents, 2))
    true = rng.normal(0, 3, (n, steps, agents, 2))
    mask = rng.random((n, steps, agents)) > 0.3
    focal = rng.random((n, agents)) > 0.5
    focal[0] = False  # a scene without main agents
    case = rng.integers(0, 2, n)
    want = displacement_metrics(pred, true, mask, case, ["a", "b"], focal)
    got = sample_metrics(pred[:, None], true, mask, case, ["a", "b"], focal)
    for group in ("all_agents", "main_agents"):
        pairs = [(want[group]["overall"], got[group]["overall"])]
        pairs += [(want[group]["cases"][c], got[group]["cases"][c]) for c in ("a", "b")]
        for w, g in pairs:
            assert g["min_ade"] == pytest.approx(w["ade"], rel=1e-12)
            assert g["min_fde"] == pytest.approx(w["fde"], rel=1e-12)
            assert (g["count"], g["final_count"], g["scenes"]) == (
                w["count"],
                w["final_count"],
                w["scenes"],
            )
            assert g["k"] == 1 and g["nll"] is None


def test_best_of_k_by_hand():
    # one scene, 2 predicted steps, 2 agents, 2 samples; errors along x only
    true = np.zeros((1, 2, 2, 2))
    samples = np.zeros((1, 2, 2, 2, 2))
    samples[0, 0, :, 0, 0] = [1.0, 3.0]  # agent 0, sample 0: errors 1, 3 (sum 4, final 3)
    samples[0, 1, :, 0, 0] = [2.5, 1.0]  # agent 0, sample 1: errors 2.5, 1 (sum 3.5, final 1)
    samples[0, 0, :, 1, 0] = [0.5, 5.0]  # agent 1, sample 0: errors 0.5, 5 (step 1 not counted)
    samples[0, 1, :, 1, 0] = [2.0, 0.0]  # agent 1, sample 1: error 2
    mask = np.array([[[True, True], [True, False]]])
    focal = np.array([[False, True]])
    nll = np.array([[[1.0, 2.0], [4.0, np.nan]]])  # NaN at the uncounted item: ignored
    got = sample_metrics(samples, true, mask, np.array([0]), ["x"], focal, nll=nll)
    every = got["all_agents"]["overall"]
    # minADE: (min(4, 3.5) + min(0.5, 2)) / 3 items; minFDE: agent 0 only, min(3, 1) = 1
    assert every["min_ade"] == pytest.approx(4.0 / 3.0)
    assert every["min_fde"] == pytest.approx(1.0)
    assert every["miss_rate"] == 0.0
    assert every["nll"] == pytest.approx(7.0 / 3.0)
    assert (every["count"], every["final_count"], every["k"]) == (3, 1, 2)
    main = got["main_agents"]["overall"]  # agent 1: counted at step 0 only
    assert main["min_ade"] == pytest.approx(0.5) and main["nll"] == pytest.approx(2.0)
    assert main["min_fde"] is None and main["miss_rate"] is None and main["final_count"] == 0
    strict = sample_metrics(samples, true, mask, np.array([0]), ["x"], focal, 0.99)
    assert strict["all_agents"]["cases"]["x"]["miss_rate"] == 1.0  # minFDE 1 m > 0.99 m


def test_sample_metrics_refuses_mismatched_shapes():
    true, mask = np.zeros((1, 2, 3, 2)), np.ones((1, 2, 3), bool)
    focal, case = np.ones((1, 3), bool), np.array([0])
    with pytest.raises(ValueError, match="samples must be"):
        sample_metrics(np.zeros((1, 2, 3, 2)), true, mask, case, ["x"], focal)
    with pytest.raises(ValueError, match="nll must be"):
        sample_metrics(np.zeros((1, 4, 2, 3, 2)), true, mask, case, ["x"], focal, nll=mask[0])


def test_gaussian_nll_is_scipys_density():
    rng = np.random.default_rng(1)
    tril = random_trils(rng, (6,))
    mean, true = rng.normal(0, 2, (6, 2)), rng.normal(0, 2, (6, 2))
    want = [-multivariate_normal(mean[i], covariance(tril[i])).logpdf(true[i]) for i in range(6)]
    np.testing.assert_allclose(gaussian_nll(true, mean, tril), want, rtol=1e-10)


def test_mixture_nll_is_the_log_of_the_weighted_densities():
    rng = np.random.default_rng(2)
    items, modes = 5, 3
    logits = rng.normal(0, 1, (items, modes))  # unnormalised: normalised inside
    means, trils = rng.normal(0, 2, (items, modes, 2)), random_trils(rng, (items, modes))
    true = rng.normal(0, 2, (items, 2))
    weights = np.exp(logits) / np.exp(logits).sum(-1, keepdims=True)
    want = [
        -math.log(
            sum(
                weights[i, m]
                * multivariate_normal(means[i, m], covariance(trils[i, m])).pdf(true[i])
                for m in range(modes)
            )
        )
        for i in range(items)
    ]
    np.testing.assert_allclose(mixture_nll(true, logits, means, trils), want, rtol=1e-10)
    # one mode: the Gaussian NLL; a far-away truth stays finite (log-sum-exp, no underflow)
    one = mixture_nll(true, np.zeros((items, 1)), means[:, :1], trils[:, :1])
    np.testing.assert_allclose(one, gaussian_nll(true, means[:, 0], trils[:, 0]), rtol=1e-12)
    far = mixture_nll(true + 1e3, logits, means, trils)
    assert np.isfinite(far).all() and (far > 1e4).all()


def test_kde_nll_is_scipys_kde_clipped_like_trajectron():
    rng = np.random.default_rng(3)
    n, k, steps, agents = 2, 12, 3, 2
    samples = rng.normal(0, 1, (n, k, steps, agents, 2)) * [1.0, 0.4] + 5.0
    true = samples.mean(axis=1) + rng.normal(0, 1, (n, steps, agents, 2))
    true[1, 2, 1] = [60.0, 60.0]  # far outside: clipped at -20
    mask = np.ones((n, steps, agents), bool)
    mask[0, 1, 0] = False
    got = kde_nll(samples, true, mask)
    assert got.shape == mask.shape and np.isnan(got[0, 1, 0])
    for s, t, a in zip(*np.nonzero(mask)):
        density = gaussian_kde(samples[s, :, t, a].T).logpdf(true[s, t, a][:, None])[0]
        want = -max(density, KDE_LOG_PDF_LOWER_BOUND)
        assert got[s, t, a] == pytest.approx(want, rel=1e-9)
    assert got[1, 2, 1] == -KDE_LOG_PDF_LOWER_BOUND


def test_kde_nll_of_a_set_without_spread_uses_the_kernel_floor():
    samples = np.full((1, 8, 1, 3, 2), 2.0)  # all samples equal: scipy raises LinAlgError
    samples[0, :, 0, 2, 0] = np.linspace(0, 7, 8)  # agent 2: spread along x only
    true = np.full((1, 1, 3, 2), 2.0)
    true[0, 0, 1] = [2.0, 2.3]  # 30 floor stds away: clipped
    got = kde_nll(samples, true, np.ones((1, 1, 3), bool))
    # agent 0: the truth on the samples, kernel N(0, floor^2 I): log(2 pi floor^2)
    assert got[0, 0, 0] == pytest.approx(math.log(2 * math.pi * KDE_MIN_STD_M**2))
    assert got[0, 0, 1] == -KDE_LOG_PDF_LOWER_BOUND
    # agent 2: scipy's kernel std along x, the floor along y: a product of 1-D KDEs
    bandwidth_x = np.std(np.linspace(0, 7, 8), ddof=1) * 8 ** (-1 / 6)
    x_density = np.mean(
        np.exp(-0.5 * ((2.0 - np.linspace(0, 7, 8)) / bandwidth_x) ** 2)
        / (math.sqrt(2 * math.pi) * bandwidth_x)
    )
    y_log_density = -math.log(math.sqrt(2 * math.pi) * KDE_MIN_STD_M)
    assert got[0, 0, 2] == pytest.approx(-(math.log(x_density) + y_log_density), rel=1e-10)
    one = kde_nll(samples[:, :1], true, np.ones((1, 1, 3), bool))  # K = 1: the floor kernel
    assert one[0, 0, 0] == pytest.approx(got[0, 0, 0])
