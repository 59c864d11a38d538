"""SmoothAttentionPredictor: masking, invariances, attention modes, gradients."""

from __future__ import annotations

import pytest
import torch

from predictor.config import ModelConfig
from predictor.losses import attention_tv
from predictor.model import SmoothAttentionPredictor
from predictor.outputs import Gaussian2D, edge_index, expand_attention
from predictor.presets import make_configs

torch.set_num_threads(1)

SMALL = {"embed_dim": 8, "edge_hidden": 8, "node_hidden": 12, "attn_dim": 4}


def make_model(mode: str = "learned", seed: int = 0, **sizes) -> SmoothAttentionPredictor:
    torch.manual_seed(seed)
    return SmoothAttentionPredictor(ModelConfig(**{**SMALL, **sizes, "attention_mode": mode}))


def make_scene(batch: int = 2, steps: int = 9, agents: int = 5, seed: int = 0):
    """Agents at constant velocity along x with some absent (agent 4 leaves, agent 3 enters)."""
    gen = torch.Generator().manual_seed(seed)
    start = torch.rand(batch, 1, agents, 2, generator=gen) * torch.tensor([60.0, 8.0])
    velocity = torch.rand(batch, 1, agents, 2, generator=gen) * torch.tensor([1.5, 0.1])
    positions = start + velocity * torch.arange(steps).view(1, steps, 1, 1)  # (B, T, N, 2)
    valid = torch.ones(batch, steps, agents, dtype=torch.bool)
    valid[:, :2, 3] = False  # enters at t = 2
    valid[0, 6:, 4] = False  # leaves at t = 6 in scene 0
    positions = torch.where(valid.unsqueeze(-1), positions, torch.zeros(()))
    labels = torch.full((batch, steps, agents), -1, dtype=torch.long)
    labels[:, 3:, 0], labels[:, 3:, 1] = 1, 0
    return positions, valid, labels


def test_edge_index_lists_every_ordered_pair_once():
    tail, head = edge_index(4)
    pairs = set(zip(tail.tolist(), head.tolist(), strict=True))
    assert len(pairs) == 12 == len(tail)
    assert pairs == {(i, j) for i in range(4) for j in range(4) if i != j}


def test_attention_rows_sum_to_one_over_present_agents():
    model = make_model()
    positions, valid, _ = make_scene()
    out = model(positions, valid, num_observed=4, rollout=False)
    theta = expand_attention(out.attention)  # (B, T-1, N, N)
    present = valid[:, :-1]  # (B, T-1, N)
    others = present.unsqueeze(-2) & present.unsqueeze(-1)  # (B, T-1, N, N) i and j present
    others &= ~torch.eye(5, dtype=torch.bool)
    assert torch.all(theta[~others] == 0)  # absent agents, self and absent rows get nothing
    rows = theta.sum(-1)  # (B, T-1, N)
    has_others = others.any(-1)
    torch.testing.assert_close(rows[has_others], torch.ones_like(rows[has_others]))
    assert torch.all(rows[~present] == 0)


def test_padded_absent_agents_do_not_change_predictions():
    model = make_model()
    positions, valid, _ = make_scene()
    pad_pos = torch.randn(2, 9, 3, 2) * 50  # garbage positions of agents that are never valid
    big_pos = torch.cat([positions, pad_pos], 2)
    big_valid = torch.cat([valid, torch.zeros(2, 9, 3, dtype=torch.bool)], 2)
    small = model.predict(positions, valid, 4)
    big = model.predict(big_pos, big_valid, 4)
    torch.testing.assert_close(big.rollout.mean[:, :, :5], small.rollout.mean)
    torch.testing.assert_close(big.rollout.tril[:, :, :5], small.rollout.tril)
    theta_small = expand_attention(small.rollout_attention)
    theta_big = expand_attention(big.rollout_attention)[..., :5, :5]
    torch.testing.assert_close(theta_big, theta_small)
    tf_small = model(positions, valid, 4, rollout=False).one_step
    tf_big = model(big_pos, big_valid, 4, rollout=False).one_step
    torch.testing.assert_close(tf_big.mean[:, :, :5], tf_small.mean)


def test_permuting_agents_permutes_outputs():
    model = make_model()
    positions, valid, _ = make_scene()
    perm = torch.tensor([3, 0, 4, 1, 2])
    base = model.predict(positions, valid, 4)
    moved = model.predict(positions[:, :, perm], valid[:, :, perm], 4)
    torch.testing.assert_close(moved.rollout.mean, base.rollout.mean[:, :, perm])
    theta = expand_attention(base.rollout_attention)  # (B, T_pred, N, N)
    theta_moved = expand_attention(moved.rollout_attention)
    torch.testing.assert_close(theta_moved, theta[:, :, perm][..., perm])


def test_prediction_reads_only_the_observed_steps():
    model = make_model()
    positions, valid, _ = make_scene()
    changed = positions.clone()
    changed[:, 4:] += torch.randn_like(changed[:, 4:]) * 5
    a, b = model.predict(positions, valid, 4), model.predict(changed, valid, 4)
    assert torch.equal(a.rollout.mean, b.rollout.mean)


def test_rollout_starts_from_the_teacher_forced_prediction():
    model = make_model()
    positions, valid, _ = make_scene()
    out = model(positions, valid, 4, rollout=True)
    assert out.rollout.mean.shape == (2, 5, 5, 2)  # T_pred = 9 - 4 predictions
    torch.testing.assert_close(out.rollout.mean[:, 0], out.one_step.mean[:, 3])  # predicts t = 4
    torch.testing.assert_close(out.rollout_attention[:, 0], out.attention[:, 3])
    assert torch.equal(out.rollout_present, valid[:, 3])


def test_chunked_teacher_forcing_matches_one_call():
    positions, valid, _ = make_scene()
    one = make_model(chunk_steps=100)(positions, valid, 4, rollout=False)
    chunked = make_model(chunk_steps=3)(positions, valid, 4, rollout=False)
    torch.testing.assert_close(chunked.one_step.mean, one.one_step.mean)
    torch.testing.assert_close(chunked.attention, one.attention)


def test_uniform_attention_is_uniform_over_present_others():
    model = make_model("uniform")
    positions, valid, _ = make_scene()
    theta = expand_attention(model(positions, valid, 4, rollout=False).attention)
    present = valid[:, :-1]
    count = present.sum(-1, keepdim=True) - 1  # (B, T-1, 1) other present agents
    expected = present.unsqueeze(-2).float() / count.unsqueeze(-1)  # (B, T-1, 1, N)
    expected = expected * (1 - torch.eye(5)) * present.unsqueeze(-1)  # zero diagonal, absent rows
    torch.testing.assert_close(theta, expected)


def test_oracle_attention_follows_labels():
    model = make_model("oracle")
    positions, valid, labels = make_scene()
    out = model(positions, valid, 4, labels=labels, rollout=True)
    theta = expand_attention(out.attention)  # (B, T-1, N, N)
    assert torch.all(theta[:, 3:, 0, 1] == 1) and torch.all(theta[:, 3:, 1, 0] == 1)
    # no label at t = 0: uniform over the present others 1, 2, 4 (agent 3 enters at t = 2)
    torch.testing.assert_close(theta[:, 0, 0, [1, 2, 4]], torch.full((2, 3), 1 / 3))
    assert torch.all(theta[:, 0, 0, 3] == 0)
    roll = expand_attention(out.rollout_attention)  # labels also drive the fed-back steps
    assert torch.all(roll[:, :, 0, 1] == 1) and torch.all(roll[:, :, 1, 0] == 1)
    with pytest.raises(ValueError, match="labels"):
        model(positions, valid, 4)


def test_smoothness_gradient_reaches_the_attention_module():
    model = make_model()
    positions, valid, _ = make_scene()
    out = model(positions, valid, 4, rollout=True)
    total, count = attention_tv(out.attention, valid[:, :-1])
    roll_total, _ = attention_tv(
        out.rollout_attention,
        out.rollout_present.unsqueeze(1).expand(-1, out.rollout_attention.shape[1], -1),
    )
    (total / count + roll_total).backward()
    grad = model.attention.f_attn.weight.grad
    assert grad is not None and torch.isfinite(grad).all() and grad.abs().sum() > 0


def test_gaussian_samples_have_the_predicted_covariance():
    gaussian = Gaussian2D(torch.tensor([[1.0, -2.0]]), torch.tensor([[0.5, 0.3, 0.2]]))
    torch.manual_seed(0)
    draws = torch.stack([gaussian.rsample()[0] for _ in range(20000)])  # (K, 2)
    torch.testing.assert_close(draws.mean(0), gaussian.mean[0], atol=0.02, rtol=0)
    expected = torch.tensor([[0.25, 0.15], [0.15, 0.13]])  # L L^T by hand
    torch.testing.assert_close(gaussian.covariance()[0], expected)
    torch.testing.assert_close(torch.cov(draws.T), expected, atol=0.01, rtol=0)


def test_variant_configs():
    model_cfg, train_cfg = make_configs("correct", {"edge_hidden": 4}, preset="paper", epochs=3)
    assert model_cfg.attention_mode == "oracle" and model_cfg.edge_hidden == 4
    assert train_cfg.beta2 == 0 and train_cfg.sequence_loss and train_cfg.epochs == 3
    assert not make_configs("s_attn")[1].sequence_loss
    assert make_configs("ours", preset="paper")[1].beta2 == 0.01
    with pytest.raises(ValueError, match="unknown variant"):
        make_configs("bogus")
    with pytest.raises(ValueError, match="beta2"):
        make_configs("nonsmooth", beta2=0.1)
    with pytest.raises(ValueError, match="unknown"):
        make_configs("ours", {"hidden": 3})


def test_untrained_model_predicts_the_mean_prior_with_the_initial_std():
    positions, valid, _ = make_scene()
    for prior in ("velocity", "position"):
        model = make_model(mean_prior=prior, init_std_m=0.3)
        out = model(positions, valid, 4, rollout=False)
        current, previous = positions[:, 1:-1], positions[:, :-2]  # steps t = 1 .. T-2
        expected = 2 * current - previous if prior == "velocity" else current
        keep = valid[:, 1:-1] & valid[:, :-2]  # (B, T-2, N) present at t and t-1
        torch.testing.assert_close(out.one_step.mean[:, 1:][keep], expected[keep])
        torch.testing.assert_close(
            out.one_step.tril, torch.tensor([0.3, 0.0, 0.3]).expand_as(out.one_step.tril)
        )


def test_attention_gain_multiplies_the_scores_before_the_softmax():
    """Same weights, gain g: theta_g = softmax(g * s) where theta_1 = softmax(s), so over the
    present others log theta_g = g log theta_1 - logsumexp(g log theta_1)."""
    positions, valid, _ = make_scene()
    plain = make_model(seed=3)(positions, valid, 4, rollout=False).attention
    gained = make_model(seed=3, attention_gain=3.0)(positions, valid, 4, rollout=False).attention
    keep = plain > 0  # (B, T-1, N, N-1): present tail and head
    assert torch.equal(keep, gained > 0)
    log_plain = torch.where(keep, plain.log(), torch.tensor(float("-inf")))
    expected = torch.softmax(3.0 * log_plain, -1).nan_to_num(0.0)
    torch.testing.assert_close(gained, expected, atol=1e-5, rtol=1e-4)
    assert not torch.allclose(gained, plain)


def test_a_scene_of_one_agent_predicts_as_if_the_others_were_absent():
    """N = 1 has no edges; its predictions equal those of the same agent next to an agent that
    is never present (masked out of the attention, so nothing is attended either way)."""
    model = make_model(seed=3)
    positions, valid, _ = make_scene(batch=2, steps=9, agents=5)
    positions, valid = positions[:, :, :2].clone(), valid[:, :, :2].clone()
    valid[:, :, 1] = False
    positions[:, :, 1] = 0.0
    alone = model.predict(positions[:, :, :1], valid[:, :, :1], num_observed=4)
    paired = model.predict(positions, valid, num_observed=4)
    assert alone.attention.shape == (2, 4, 1, 0)
    torch.testing.assert_close(alone.rollout.mean, paired.rollout.mean[:, :, :1])
    torch.testing.assert_close(alone.one_step.mean, paired.one_step.mean[:, :, :1])


@pytest.mark.parametrize("num_observed", [0, 9])
def test_a_window_with_no_observed_or_no_predicted_step_is_refused(num_observed: int):
    positions, valid, _ = make_scene(steps=9)
    with pytest.raises(ValueError, match=r"num_observed must be in \[1, 8\]"):
        make_model()(positions, valid, num_observed=num_observed)
    with pytest.raises(ValueError, match=r"num_observed must be in \[1, 8\]"):
        make_model().predict(positions, valid, num_observed=num_observed)


def test_oracle_attention_without_labels_is_refused():
    positions, valid, _ = make_scene()
    with pytest.raises(ValueError, match="oracle attention needs attention labels"):
        make_model("oracle")(positions, valid, num_observed=4)
