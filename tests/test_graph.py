"""The neighbour graph (predictor.graph) and the packed-edge model: neighbour sets against a
brute-force numpy computation, the packed complete graph against the dense reference model
(tests/dense_reference.py), attention on the graph, absent agents, one-agent windows."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
from dense_reference import DensePredictor, dense_input_stats

from predictor.config import ModelConfig, resolve_roles
from predictor.graph import (
    adjacency,
    anchor_steps,
    neighbour_graph,
    role_balance,
    segment_softmax,
    segment_uniform,
)
from predictor.losses import LossWeights, compute_loss
from predictor.model import SmoothAttentionPredictor
from predictor.outputs import expand_attention
from predictor.presets import make_configs

torch.set_num_threads(1)

SMALL = {"embed_dim": 8, "edge_hidden": 8, "node_hidden": 12, "attn_dim": 4}
ROLE_NAMES = ("main_green", "main_brown", "distractor")


def crowd(batch: int = 3, steps: int = 10, agents: int = 9, seed: int = 0, full: bool = False):
    """Random walks in a 30 m square; unless `full`, agent 1 leaves after step 2, agent 2
    enters at step 6 (after the 5 observed steps), agent 3 enters at step 2, and the last slot
    is never present (padding); absent positions are zero."""
    gen = torch.Generator().manual_seed(seed)
    start = torch.rand(batch, 1, agents, 2, generator=gen) * 30
    walk = torch.randn(batch, steps, agents, 2, generator=gen).cumsum(1) * 0.5
    positions = start + walk  # (B, T, N, 2)
    valid = torch.ones(batch, steps, agents, dtype=torch.bool)
    if not full:
        valid[:, 3:, 1] = False
        valid[:, :6, 2] = False
        valid[:, :2, 3] = False
        valid[:, :, -1] = False
    positions = torch.where(valid.unsqueeze(-1), positions, 0.0)
    labels = torch.full((batch, steps, agents), -1, dtype=torch.long)
    if agents > 4:  # agents 0 and 4 attend to each other from step 2
        labels[:, 2:, 0], labels[:, 2:, 4] = 4, 0
    roles = torch.randint(0, 3, (batch, agents), generator=gen)
    return positions, valid, labels, roles


def brute_force_adjacency(positions, valid, num_observed, mode, radius, k) -> np.ndarray:
    """The graph of the docstring of predictor.graph, by loops over numpy arrays."""
    pos, val = positions.numpy(), valid.numpy()
    batch, steps, agents = val.shape
    out = np.zeros((batch, agents, agents), dtype=bool)
    for b in range(batch):
        for i in range(agents):
            if mode == "all":
                for j in range(agents):
                    out[b, i, j] = j != i and val[b, :, i].any() and val[b, :, j].any()
                continue
            seen = [t for t in range(min(num_observed, steps)) if val[b, t, i]]
            later = [t for t in range(steps) if val[b, t, i]]
            if not later:
                continue
            t = seen[-1] if seen else later[0]
            others = [j for j in range(agents) if j != i and val[b, t, j]]
            dist = {j: float(np.linalg.norm(pos[b, t, j] - pos[b, t, i])) for j in others}
            if mode == "radius":
                chosen = [j for j in others if dist[j] <= radius]
            else:
                chosen = sorted(others, key=lambda j: (dist[j], j))[:k]
            out[b, i, chosen] = True
    return out


@pytest.mark.parametrize(
    ("mode", "radius", "k"),
    [("all", 1.0, 1), ("radius", 8.0, 1), ("radius", 0.5, 1)]
    + [("knn", 1.0, k) for k in (1, 3, 20)],
)
def test_neighbour_sets_equal_a_brute_force_computation(mode, radius, k):
    positions, valid, _, _ = crowd(batch=4, steps=10, agents=9, seed=1)
    for observed in (1, 5, 9):
        got = adjacency(positions, valid, observed, mode, radius, k).numpy()
        expected = brute_force_adjacency(positions, valid, observed, mode, radius, k)
        np.testing.assert_array_equal(got, expected)
    if mode == "knn":  # the brute force is not vacuous: degrees are min(k, present others)
        degrees = adjacency(positions, valid, 5, mode, radius, k).sum(-1)[:, 0]
        assert torch.all(degrees == min(k, 5))  # present at step 4 besides 0: agents 3-7


def test_anchor_is_the_last_observed_step_else_the_first():
    _, valid, _, _ = crowd()
    anchor = anchor_steps(valid, num_observed=5)[0]
    assert anchor.tolist() == [4, 2, 6, 4, 4, 4, 4, 4, -1]


def test_absent_agents_get_no_edges():
    positions, valid, _, _ = crowd(agents=9)
    for mode in ("all", "radius", "knn"):
        graph = neighbour_graph(positions, valid, 5, mode, 100.0, 3)
        padding = {b * 9 + 8 for b in range(3)}  # the never-present slot of each scene
        assert not padding & set(graph.tail.tolist()) and not padding & set(graph.head.tolist())
        assert graph.num_edges > 0
    # predict reads the observed steps only: agent 2 (present from step 6) has no edges there
    graph = neighbour_graph(positions[:, :5], valid[:, :5], 5, "all")
    assert 2 not in (graph.tail % 9).tolist() and 2 not in (graph.head % 9).tolist()


def test_complete_graph_of_a_full_batch_is_the_dense_edge_order():
    positions, valid, _, _ = crowd(batch=2, agents=4, full=True)
    graph = neighbour_graph(positions, valid, 5, "all")
    pairs = [(int(t) // 4, int(t) % 4, int(h) % 4) for t, h in zip(graph.tail, graph.head)]
    assert pairs == [(b, i, j) for b in range(2) for i in range(4) for j in range(4) if i != j]
    values = torch.arange(graph.num_edges, dtype=torch.float32).unsqueeze(0)  # (1, E)
    assert torch.equal(graph.to_compact(values).flatten(), values[0])


def test_a_complete_graph_is_marked_so_and_others_are_not():
    positions, valid, _, _ = crowd(batch=2, agents=5, full=True)
    assert neighbour_graph(positions, valid, 5, "all").complete
    assert not neighbour_graph(positions, valid, 5, "knn", k=2).complete
    positions, valid, _, _ = crowd(batch=2, agents=5)  # a padding slot: no edges to it
    assert not neighbour_graph(positions, valid, 5, "all").complete
    one = neighbour_graph(positions[:, :, :1], valid[:, :, :1], 5, "all")
    assert not one.complete and one.num_edges == 0


def test_the_complete_graphs_dense_path_equals_the_packed_one():
    """Every per-edge operation of a complete graph (dense path) against the same graph with
    the flag off (the packed index_select / index_add path): values, and gradients in float64
    (gradcheck for the gather with a hand-written backward)."""
    positions, valid, _, _ = crowd(batch=3, agents=6, full=True)
    dense = neighbour_graph(positions, valid, 5, "all")
    packed = dataclasses.replace(dense, complete=False)
    gen = torch.Generator().manual_seed(2)
    per_agent = torch.randn(4, dense.num_slots, 3, generator=gen, dtype=torch.float64)
    per_edge = torch.randn(4, dense.num_edges, 3, generator=gen, dtype=torch.float64)
    scores = torch.randn(4, dense.num_edges, generator=gen, dtype=torch.float64)
    mask = torch.rand(4, dense.num_edges, generator=gen) > 0.3
    mask[0, : dense.num_agents - 1] = False  # one agent with no present neighbour
    for name in ("at_tail", "at_head"):
        assert torch.equal(getattr(dense, name)(per_agent), getattr(packed, name)(per_agent))
        assert torch.autograd.gradcheck(getattr(dense, name), per_agent.requires_grad_())
    torch.testing.assert_close(dense.sum_by_tail(per_edge), packed.sum_by_tail(per_edge))
    assert torch.equal(dense.to_compact(scores), packed.to_compact(scores))
    for graph in (dense, packed):
        assert torch.equal(graph.edge_present(valid.transpose(0, 1)), valid.new_ones(10, 90))
    torch.testing.assert_close(
        dense.dot_with_tail(per_edge, per_agent), packed.dot_with_tail(per_edge, per_agent)
    )
    torch.testing.assert_close(
        segment_softmax(scores, mask, dense), segment_softmax(scores, mask, packed)
    )
    for graph in (dense, packed):  # the dense path's gradients against a plain check
        assert torch.autograd.gradcheck(
            lambda values, graph=graph: segment_softmax(values, mask, graph),
            scores.clone().requires_grad_(),
        )
    torch.testing.assert_close(segment_uniform(mask, dense), segment_uniform(mask, packed))
    roles = torch.tensor([[0, 1, 2, 2, 2, 2]]).expand(3, -1)
    assert torch.equal(role_balance(roles, mask, dense, 3), role_balance(roles, mask, packed, 3))


@pytest.mark.parametrize("neighbours", ["knn", "all"])
def test_segment_softmax_equals_a_softmax_per_agent(neighbours: str):
    positions, valid, _, _ = crowd(batch=2, agents=6, seed=3)
    if neighbours == "all":  # everyone present throughout: the complete graph's dense path
        valid = torch.ones_like(valid)
    graph = neighbour_graph(positions, valid, 5, neighbours, k=3)
    assert graph.complete == (neighbours == "all")
    scores = torch.randn(4, graph.num_edges, generator=torch.Generator().manual_seed(0))
    mask = torch.rand(4, graph.num_edges, generator=torch.Generator().manual_seed(1)) > 0.3
    theta = segment_softmax(scores, mask, graph)
    uniform = segment_uniform(mask, graph)
    for s in range(4):
        for tail in graph.tail.unique():
            edges = (graph.tail == tail) & mask[s]
            if edges.any():
                expected = torch.softmax(scores[s, edges], 0)
                torch.testing.assert_close(theta[s, edges], expected)
                torch.testing.assert_close(
                    uniform[s, edges], torch.full_like(expected, 1 / len(expected))
                )
    assert torch.all(theta[~mask] == 0) and torch.all(uniform[~mask] == 0)


def test_role_balance_gives_each_role_of_the_neighbours_one_share():
    """Equal scores plus the role balance: agent 0 (role 0) among one role-1 agent and three
    role-2 agents gives 1/2 to the role-1 agent and 1/6 to each role-2 agent (hand-computed);
    when one role-2 agent is absent, 1/4 to each of the other two; masked edges get 0."""
    positions = torch.randn(1, 4, 5, 2, generator=torch.Generator().manual_seed(0))
    valid = torch.ones(1, 4, 5, dtype=torch.bool)
    graph = neighbour_graph(positions, valid, 3)
    roles = torch.tensor([[0, 1, 2, 2, 2]])
    present = valid.transpose(0, 1).clone()  # (S, B, N)
    present[1, 0, 4] = False  # agent 4 absent at step 1
    mask = graph.edge_present(present)  # (S, E)
    theta = graph.to_compact(segment_softmax(role_balance(roles, mask, graph, 3), mask, graph))
    torch.testing.assert_close(theta[0, 0, 0], torch.tensor([1 / 2, 1 / 6, 1 / 6, 1 / 6]))
    torch.testing.assert_close(theta[1, 0, 0], torch.tensor([1 / 2, 1 / 4, 1 / 4, 0.0]))
    # a role-2 agent sees one role-0, one role-1 and two other role-2 agents
    torch.testing.assert_close(theta[0, 0, 2], torch.tensor([1 / 3, 1 / 3, 1 / 6, 1 / 6]))
    assert torch.all(role_balance(roles, mask, graph, 3)[~mask] == 0)


# --------------------------------------------------------------------------- packed == dense
def model_pair(mode: str = "learned", preset: str = "paper", seed: int = 0, **overrides):
    """The packed model and the dense reference with the same weights and buffers."""
    if preset == "paper":
        config = ModelConfig(**{**SMALL, "attention_mode": mode, **overrides})
    else:
        variant = {"learned": "ours", "uniform": "average", "oracle": "correct"}[mode]
        # the dense reference predates the role-pair attention bias and the role balance (both
        # tested in test_highway)
        fixed = {
            **SMALL,
            "highway_steps": 3,
            "role_attention_bias": False,
            "role_balanced_attention": False,
            **overrides,
        }
        config, _ = make_configs(variant, fixed, preset)
        config = resolve_roles(config, ROLE_NAMES)
    torch.manual_seed(seed)
    packed = SmoothAttentionPredictor(config)
    dense = DensePredictor(config)
    return packed, dense


def live_heads(model: SmoothAttentionPredictor) -> SmoothAttentionPredictor:
    """The model with fixed nonzero output heads (they start at zero, which would make every
    prediction the prior whatever the graph)."""
    with torch.no_grad():
        for head in (model.head.f_pred, model.head.f_cov, model.head.f_roll):
            if head is not None:
                pattern = torch.linspace(-0.2, 0.2, head.weight.numel())
                head.weight.copy_(pattern.view_as(head.weight))
    return model


def fitted_pair(mode, preset, positions, valid, roles, **overrides):
    packed, dense = model_pair(mode, preset, **overrides)
    live_heads(packed)
    if packed.config.frame == "agent":
        packed.fit_normalisation(positions, valid, 5, roles)
    dense.load_state_dict(packed.state_dict())
    return packed, dense


def loss_and_grads(model, positions, valid, labels, roles, focal):
    torch.manual_seed(7)  # the same rollout samples
    out = model(positions, valid, 5, labels, rollout=True, sample=True, roles=roles)
    weights = LossWeights(main_weight=3.0)
    loss, terms = compute_loss(out, positions, valid, 5, weights, focal)
    model.zero_grad()
    loss.backward()
    grads = {name: p.grad.clone() for name, p in model.named_parameters() if p.grad is not None}
    return out, terms, grads


def assert_same_losses_and_gradients(terms, grads, expected_terms, expected_grads):
    """Loss terms and parameter gradients equal to float32 rounding (sums in another order)."""
    assert terms.keys() == expected_terms.keys()
    for name in terms:
        assert terms[name] == pytest.approx(expected_terms[name], rel=1e-5, abs=1e-6), name
    assert grads.keys() == expected_grads.keys() and len(grads) > 5
    for name in grads:
        scale = float(expected_grads[name].abs().max())
        torch.testing.assert_close(grads[name], expected_grads[name], rtol=1e-4, atol=1e-5 * scale)


@pytest.mark.parametrize("full", [True, False])
@pytest.mark.parametrize(
    ("mode", "preset"),
    [("learned", "paper"), ("uniform", "paper"), ("oracle", "paper"), ("learned", "agent")],
)
def test_packed_complete_graph_equals_the_dense_model(mode, preset, full):
    positions, valid, labels, roles = crowd(batch=3, steps=10, agents=7, full=full)
    focal = torch.zeros(3, 7, dtype=torch.bool)
    focal[:, :2] = True
    packed, dense = fitted_pair(mode, preset, positions, valid, roles)
    out_p, terms_p, grads_p = loss_and_grads(packed, positions, valid, labels, roles, focal)
    out_d, terms_d, grads_d = loss_and_grads(dense, positions, valid, labels, roles, focal)
    for name in ("one_step", "rollout"):
        torch.testing.assert_close(getattr(out_p, name).mean, getattr(out_d, name).mean)
        torch.testing.assert_close(getattr(out_p, name).tril, getattr(out_d, name).tril)
    torch.testing.assert_close(out_p.attention, out_d.attention)
    torch.testing.assert_close(out_p.rollout_attention, out_d.rollout_attention)
    assert_same_losses_and_gradients(terms_p, grads_p, terms_d, grads_d)
    pred_p = packed.predict(positions, valid, 5, labels, roles)
    pred_d = dense.predict(positions, valid, 5, labels, roles)
    torch.testing.assert_close(pred_p.rollout.mean, pred_d.rollout.mean)
    torch.testing.assert_close(pred_p.rollout_attention, pred_d.rollout_attention)


@pytest.mark.parametrize("preset", ["paper", "agent"])
def test_the_dense_path_gives_the_packed_paths_losses_and_gradients(preset, monkeypatch):
    """The whole model (the agent preset with its role-pair bias and role balance) on a
    complete graph, taking the dense path, against the same graph with the flag off."""
    positions, valid, labels, roles = crowd(batch=3, steps=10, agents=7, full=True)
    focal = torch.zeros(3, 7, dtype=torch.bool)
    focal[:, :2] = True
    switches = {"role_attention_bias": True, "role_balanced_attention": True}
    model, _ = model_pair("learned", preset, **(switches if preset == "agent" else {}))
    live_heads(model)
    if model.config.frame == "agent":
        model.fit_normalisation(positions, valid, 5, roles)
    if model.role_bias is not None:
        role_pair = model.role_bias.role_pair
        with torch.no_grad():
            role_pair.copy_(torch.linspace(-1, 1, role_pair.numel()).view(3, 3))
    runs = []
    for complete in (True, False):

        def graph(*args, complete=complete):
            return dataclasses.replace(neighbour_graph(*args), complete=complete)

        monkeypatch.setattr("predictor.model.pass_inputs.neighbour_graph", graph)
        assert model._prepare(positions, valid, 5, labels, roles).graph.complete is complete
        runs.append(loss_and_grads(model, positions, valid, labels, roles, focal))
    (out_d, terms_d, grads_d), (out_p, terms_p, grads_p) = runs
    torch.testing.assert_close(out_d.rollout.mean, out_p.rollout.mean)
    torch.testing.assert_close(out_d.rollout_attention, out_p.rollout_attention)
    assert_same_losses_and_gradients(terms_d, grads_d, terms_p, grads_p)


def test_standardisation_statistics_equal_the_dense_ones():
    positions, valid, _, roles = crowd(batch=3, agents=7)
    packed, _ = model_pair("learned", "agent")
    packed.fit_normalisation(positions, valid, 5, roles)
    mean, std = dense_input_stats(packed, positions, valid, 5)
    torch.testing.assert_close(packed.encoder.input_mean, mean)
    torch.testing.assert_close(packed.encoder.input_std, std)


# --------------------------------------------------------------------------- sparse graphs
@pytest.mark.parametrize(
    ("mode", "preset"), [("radius", "paper"), ("knn", "agent"), ("knn", "crowd")]
)
def test_attention_sums_to_one_over_present_neighbours_and_is_zero_off_the_graph(mode, preset):
    positions, valid, _, roles = crowd(batch=3, steps=10, agents=9)
    packed, _ = fitted_pair(
        "learned",
        preset,
        positions,
        valid,
        roles,
        neighbours=mode,
        neighbour_radius_m=8.0,
        neighbour_k=3,
    )
    out = packed(positions, valid, 5, rollout=True, roles=roles)
    theta = expand_attention(out.attention)  # (B, T-1, N, N)
    graph = adjacency(positions, valid, 5, mode, 8.0, 3)  # (B, N, N)
    present = valid[:, :-1]  # (B, T-1, N)
    live = graph.unsqueeze(1) & present.unsqueeze(-1) & present.unsqueeze(-2)  # (B, T-1, N, N)
    assert torch.all(theta[~live] == 0)
    rows = theta.sum(-1)
    has = live.any(-1)
    assert has.any()
    if mode == "radius":  # 8 m in a 30 m square: some agents have no neighbour at all
        assert (~has & present).any()
    torch.testing.assert_close(rows[has], torch.ones_like(rows[has]))
    assert torch.all(rows[~has] == 0)
    assert torch.isfinite(out.one_step.mean).all() and torch.isfinite(out.rollout.mean).all()
    roll = expand_attention(out.rollout_attention)  # rollout: neighbours rolled out
    rolled = out.rollout_present
    live_roll = graph & rolled.unsqueeze(-1) & rolled.unsqueeze(-2)  # (B, N, N)
    assert torch.all(roll[~live_roll.unsqueeze(1).expand_as(roll)] == 0)


def test_an_agent_without_neighbours_predicts_as_if_alone():
    """attended = 0 for an isolated agent: in the agent frame (no scene origin shared with the
    others) its predictions equal those of a window holding it alone."""
    positions, valid, _, _ = crowd(batch=2, steps=10, agents=6, full=True, seed=4)
    positions[:, :, 0] += 1000.0  # agent 0 far from everyone
    model, _ = model_pair(
        "learned", "agent", neighbours="radius", neighbour_radius_m=100.0, num_roles=0
    )
    live_heads(model).fit_normalisation(positions, valid, 5)
    together = model.predict(positions, valid, 5)
    alone = model.predict(positions[:, :, :1], valid[:, :, :1], 5)
    assert alone.attention.shape[-1] == 0
    torch.testing.assert_close(together.rollout.mean[:, :, :1], alone.rollout.mean)
    torch.testing.assert_close(together.one_step.mean[:, :, :1], alone.one_step.mean)
    theta = expand_attention(together.rollout_attention)  # (B, T_pred, N, N)
    assert torch.all(theta[:, :, 0] == 0) and torch.all(theta[:, :, :, 0] == 0)
    torch.testing.assert_close(theta[:, :, 1:].sum(-1), torch.ones(2, 5, 5))


@pytest.mark.parametrize("mode", ["all", "radius", "knn"])
def test_a_one_agent_window_trains(mode):
    positions, valid, labels, _ = crowd(batch=2, steps=10, agents=1, full=True)
    model, _ = model_pair("learned", "paper", neighbours=mode)
    out = model(positions, valid, 5, labels, rollout=True)
    loss, terms = compute_loss(out, positions, valid, 5, LossWeights())
    loss.backward()
    assert out.attention.shape == (2, 9, 1, 0) and np.isfinite(terms["loss"])
    assert all(torch.isfinite(p.grad).all() for p in model.parameters() if p.grad is not None)


def test_knn_with_every_agent_equals_the_complete_graph():
    positions, valid, _, _ = crowd(batch=2, agents=6, full=True)
    outputs = {}
    for k in (5, 2, None):  # k = N - 1: every other agent; None: the complete graph
        graph = {} if k is None else {"neighbours": "knn", "neighbour_k": k}
        model = live_heads(model_pair("learned", "paper", seed=2, **graph)[0])
        outputs[k] = model(positions, valid, 5, rollout=True, sample=False)
    torch.testing.assert_close(outputs[5].rollout.mean, outputs[None].rollout.mean)
    torch.testing.assert_close(outputs[5].attention, outputs[None].attention)
    assert not torch.allclose(outputs[2].rollout.mean, outputs[None].rollout.mean)
    assert (expand_attention(outputs[2].attention) > 0).sum(-1).max() == 2


@pytest.mark.parametrize("mode", ["radius", "knn"])
def test_prediction_reads_only_the_observed_steps_with_a_sparse_graph(mode):
    positions, valid, _, _ = crowd(batch=2, agents=7)
    model = live_heads(model_pair("learned", "paper", neighbours=mode, neighbour_radius_m=10.0)[0])
    changed_pos, changed_valid = positions.clone(), valid.clone()
    changed_pos[:, 5:] += torch.randn_like(changed_pos[:, 5:]) * 20
    changed_valid[:, 5:, 4] = False  # the future presence is not read either
    a = model.predict(positions, valid, 5)
    b = model.predict(changed_pos, changed_valid, 5)
    assert torch.equal(a.rollout.mean, b.rollout.mean)
    # the training pass (means fed back) rolls the same agents out the same way
    fed = model(positions, valid, 5, rollout=True, sample=False)
    rolled = fed.rollout_present
    torch.testing.assert_close(fed.rollout.mean[:, :, rolled[0]], a.rollout.mean[:, :, rolled[0]])
    assert not rolled[0].all() and rolled[0].sum() > 2


def test_config_rejects_bad_graph_settings():
    with pytest.raises(ValueError, match="neighbours"):
        ModelConfig(neighbours="grid")
    with pytest.raises(ValueError, match="neighbour_radius_m"):
        ModelConfig(neighbours="radius", neighbour_radius_m=0.0)
    with pytest.raises(ValueError, match="neighbour_k"):
        ModelConfig(neighbour_k=0)
