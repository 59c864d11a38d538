"""The model's predictive distribution: Gaussian and mixture densities against
torch.distributions, mixture sampling, the mode loss by hand, the tiled sampled rollout against
the full pass over the repeated batch, and batches cut to the agents present."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torch.distributions import Categorical, MixtureSameFamily, MultivariateNormal

from predictor.config import resolve_roles
from predictor.forecasting import EvaluationError, SampleSettings, forecast_model
from predictor.losses import mode_nll
from predictor.model import SmoothAttentionPredictor
from predictor.outputs import Gaussian2D, TrajectoryMixture
from predictor.presets import make_configs
from trajectory_data.torch_dataset import Batch


def random_tril(generator: torch.Generator, *shape: int) -> torch.Tensor:
    diag = torch.rand(*shape, 2, generator=generator) + 0.2
    off = torch.randn(*shape, 1, generator=generator)
    return torch.cat([diag[..., :1], off, diag[..., 1:]], -1)


def full_tril(tril: torch.Tensor) -> torch.Tensor:
    return Gaussian2D(torch.zeros(*tril.shape[:-1], 2), tril).scale_tril()


def test_gaussian_log_prob_matches_torch_distributions():
    g = torch.Generator().manual_seed(0)
    mean, x = torch.randn(5, 3, 2, generator=g), torch.randn(5, 3, 2, generator=g)
    tril = random_tril(g, 5, 3)
    expected = MultivariateNormal(mean, scale_tril=full_tril(tril)).log_prob(x)
    torch.testing.assert_close(Gaussian2D(mean, tril).log_prob(x), expected)


def mixture(generator: torch.Generator, batch=2, steps=4, agents=3, modes=3) -> TrajectoryMixture:
    logits = torch.randn(batch, agents, modes, generator=generator)
    return TrajectoryMixture(
        torch.log_softmax(logits, -1),
        torch.randn(batch, steps, agents, modes, 2, generator=generator) * 3,
        random_tril(generator, batch, steps, agents, modes),
    )


def test_mixture_densities_match_torch_distributions():
    g = torch.Generator().manual_seed(1)
    mix = mixture(g)
    target = torch.randn(2, 4, 3, 2, generator=g) * 3
    weights = Categorical(logits=mix.log_weights.unsqueeze(1).expand(-1, 4, -1, -1))
    per_step = MixtureSameFamily(
        weights, MultivariateNormal(mix.mean, scale_tril=full_tril(mix.tril))
    )
    torch.testing.assert_close(mix.step_log_prob(target), per_step.log_prob(target))
    # whole futures: log sum_m pi_m prod_t N_mt over the masked steps, by hand
    mask = torch.rand(2, 4, 3, generator=g) < 0.7
    component = MultivariateNormal(mix.mean, scale_tril=full_tril(mix.tril))
    log_n = component.log_prob(target.unsqueeze(-2)) * mask.unsqueeze(-1)  # (B, T, N, M)
    expected = torch.logsumexp(log_n.sum(1) + mix.log_weights, -1)
    torch.testing.assert_close(mix.trajectory_log_prob(target, mask), expected)
    # the loss: minus their sum over agents per counted step
    expected_loss = -expected.sum() / mask.sum()
    torch.testing.assert_close(mode_nll(mix, target, mask), expected_loss)


def test_mixture_samples_pick_modes_by_weight_with_one_draw_per_future():
    g = torch.Generator().manual_seed(2)
    mean = torch.zeros(1, 3, 1, 2, 2)
    mean[..., 1, 0] = 100.0  # mode 1 is 100 m away in x
    tril = random_tril(g, 1, 3, 1, 2) * 0.1
    weights = torch.log(torch.tensor([[[0.25, 0.75]]]))
    mix = TrajectoryMixture(weights, mean, tril)
    samples = mix.sample(20_000, torch.Generator().manual_seed(3))  # (K, 1, 3, 1, 2)
    far = samples[:, 0, 0, 0, 0] > 50
    assert abs(far.float().mean().item() - 0.75) < 0.02  # binomial sd 0.003
    # each future solves to one standard normal draw through every step's Cholesky factor
    near = samples[~far][:, 0, :, 0]  # (K', 3, 2), mode 0
    steps = tril[0, :, 0, 0]  # (3, 3)
    e0 = near[..., 0] / steps[:, 0]
    e1 = (near[..., 1] - steps[:, 1] * e0) / steps[:, 2]
    torch.testing.assert_close(e0, e0[:, :1].expand_as(e0))
    torch.testing.assert_close(e1, e1[:, :1].expand_as(e1))
    assert abs(e0[:, 0].std().item() - 1) < 0.05 and abs(e1[:, 0].mean().item()) < 0.05


def small_model(preset: str, **overrides) -> SmoothAttentionPredictor:
    torch.manual_seed(0)
    config, _ = make_configs("ours", overrides, preset=preset)
    return SmoothAttentionPredictor(resolve_roles(config, ("walker",)))


def walks(scenes=3, steps=14, agents=6, seed=0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    positions = torch.cumsum(torch.randn(scenes, steps, agents, 2, generator=g), 1)
    valid = torch.ones(scenes, steps, agents, dtype=torch.bool)
    valid[1, :, agents - 1] = False
    valid[2, :3, agents - 2] = False
    return positions, valid


@pytest.mark.parametrize("preset", ["paper", "crowd", "agent"])
def test_sampled_rollout_equals_the_full_pass_over_the_repeated_batch(preset):
    model = small_model(preset)
    positions, valid = walks()
    roles = torch.zeros(3, 6, dtype=torch.long)
    if model.config.frame == "agent":
        model.fit_normalisation(positions, valid, 6, roles)
    torch.manual_seed(5)
    tiled = model.sample_rollouts(positions, valid, 6, 4, roles=roles)
    torch.manual_seed(5)
    steps = model._prepare(
        positions.repeat(4, 1, 1, 1), valid.repeat(4, 1, 1), 6, None, roles.repeat(4, 1), 6
    )
    rollout = model._rollout(steps, model._block(steps, 0, 6, None), True, keep_draws=True)
    # equal up to float rounding (batch size changes summation order in the LSTM kernels)
    torch.testing.assert_close(tiled, rollout.draws.view(4, 3, 8, 6, 2), rtol=0, atol=1e-5)
    assert tiled.std(0).mean() > 0  # the futures differ


def test_forecast_cuts_batches_to_the_agents_present():
    model = small_model("crowd", modes=3)
    positions, valid = walks(agents=5)
    roles = torch.zeros(3, 5, dtype=torch.long)
    model.fit_normalisation(positions, valid, 6, roles)

    def batch(width: int) -> Batch:  # padded with absent slots up to `width`
        pad = width - 5
        states = torch.cat([positions, torch.zeros(3, 14, pad, 2)], 2)
        present = torch.cat([valid, torch.zeros(3, 14, pad, dtype=torch.bool)], 2)
        return Batch(
            states,
            present,
            torch.full(present.shape, -1),
            torch.zeros(3, 14, dtype=torch.bool),
            torch.zeros(3, dtype=torch.long),
            torch.zeros(3, dtype=torch.long),
            torch.zeros(3, width, dtype=torch.long),
        )

    narrow = forecast_model(model, batch(5), 6, num_samples=5, seed=3)
    wide = forecast_model(model, batch(40), 6, num_samples=5, seed=3)
    np.testing.assert_allclose(wide.pred_mean[:, :, :5], narrow.pred_mean, rtol=0, atol=1e-5)
    np.testing.assert_allclose(wide.samples[..., :5, :], narrow.samples, rtol=0, atol=1e-5)
    np.testing.assert_allclose(wide.nll[..., :5], narrow.nll, rtol=1e-5, atol=1e-5)
    assert not wide.samples[..., 5:, :].any() and np.isnan(wide.nll[..., 5:]).all()
    # the NLL is the mixture's, in closed form
    out = model.predict(positions, valid, 6, roles=roles)
    expected = -out.modes.step_log_prob(positions[:, 6:]).numpy()
    np.testing.assert_allclose(narrow.nll, expected, rtol=1e-5, atol=1e-5)


def test_sample_settings_refuse_bad_values_in_one_line():
    for kwargs, message in (
        ({"k": -1}, "number of samples"),
        ({"miss_threshold_m": 0.0}, "miss threshold"),
        ({"miss_threshold_m": math.inf}, "miss threshold"),
        ({"method": "walk"}, "sampling method"),
    ):
        with pytest.raises(EvaluationError, match=message):
            SampleSettings(**kwargs)
