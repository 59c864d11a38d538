"""The dense graph step of the model before packed edges (predictor/model.py at commit 1f23181),
kept as the reference the packed implementation is tested against.

`DensePredictor` is `SmoothAttentionPredictor` with the pre-change graph step: every agent
slot has N-1 edge slots, the edge LSTM runs on all B*N*(N-1) sequences, and the attention is a
masked softmax over the N-1 slots of each row. Its methods `_run`, `_agent_inputs`,
`_edge_inputs` and `_attention` are the old ones verbatim but for reading the layers and
statistics from the packed model's parts (`encoder`, `recurrent`, `attention`, `node`,
`head`); the graph of `_Steps` is ignored. `dense_input_stats` is the old `fit_normalisation`
statistics over all present pairs. Same parameters and buffers as the new model, so one state
dict loads into both.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from predictor.agent_frame import AgentFrame, rotate
from predictor.model import SmoothAttentionPredictor
from predictor.model.pass_inputs import PassInputs as _Steps
from predictor.outputs import RecurrentState, StepOutputs, edge_index


def edge_present(present: Tensor, head: Tensor) -> Tensor:
    """Edges whose tail and head agents are both present: (..., N) -> (..., N, N-1)."""
    num_agents = present.shape[-1]
    heads = present.index_select(-1, head).view(*present.shape, num_agents - 1)
    return heads & present.unsqueeze(-1)


def agent_features(
    pos: Tensor, prev_pos: Tensor, present: Tensor, frame: AgentFrame, head: Tensor
) -> tuple[Tensor, Tensor]:
    """Raw agent-frame features: own (S, B, N, 4) and pair (S, B, N, N-1, 4), in i's frame."""
    origin, rotation = frame
    vel = torch.where(present.unsqueeze(-1), pos - prev_pos, 0.0)  # (S, B, N, 2)
    own = rotate(pos - origin, rotation, inverse=True)  # (S, B, N, 2)
    own_vel = rotate(vel, rotation, inverse=True)  # (S, B, N, 2)
    num_agents = pos.shape[2]
    shape = (*pos.shape[:2], num_agents, num_agents - 1, 2)
    rel = pos.index_select(2, head).view(shape) - pos.unsqueeze(3)  # (S, B, N, N-1, 2)
    rel_vel = vel.index_select(2, head).view(shape) - vel.unsqueeze(3)  # (S, B, N, N-1, 2)
    rot = rotation.unsqueeze(2)  # (B, N, 1, 2)
    pair = torch.cat([rotate(rel, rot, inverse=True), rotate(rel_vel, rot, inverse=True)], -1)
    return torch.cat([own, own_vel], -1), pair


def masked_softmax(scores: Tensor, mask: Tensor) -> Tensor:
    """Softmax over the last dim restricted to `mask`; rows without any True are all zero."""
    lowest = torch.finfo(scores.dtype).min
    weights = torch.softmax(scores.masked_fill(~mask, lowest), dim=-1)  # (..., K)
    return weights * mask.to(scores.dtype)  # (..., K)


def dense_input_stats(
    model: SmoothAttentionPredictor, positions: Tensor, valid: Tensor, num_observed: int
) -> tuple[Tensor, Tensor]:
    """The old fit_normalisation's (input_mean, input_std) before the std floor, over all
    present agent-steps and all pairs present together."""
    no_labels = torch.full(valid.shape, -1, dtype=torch.long)
    no_roles = torch.zeros(valid.shape[0], valid.shape[2], dtype=torch.long)
    steps = model._prepare(positions, valid, num_observed, no_labels, no_roles)
    _, head = edge_index(positions.shape[2], positions.device)
    own, pair = agent_features(steps.pos, steps.prev_pos, steps.present, steps.frame, head)
    own, pair = own[steps.present], pair[edge_present(steps.present, head)]
    return (
        torch.cat([own.mean(0), pair.mean(0)]),
        torch.cat([own.std(0), pair.std(0)]),
    )


class DensePredictor(SmoothAttentionPredictor):
    """The model with the dense (pre-packed-edges) graph step."""

    def _run(
        self,
        pos: Tensor,
        prev_pos: Tensor,
        present: Tensor,
        steps: _Steps,
        labels: Tensor | None,
        state: RecurrentState | None,
        anchor: Tensor | None = None,
        presence: object = None,  # the packed model's edge terms, which this one has not
    ) -> StepOutputs:
        num_steps, batch, num_agents, _ = pos.shape
        cfg = self.config
        tail, head = edge_index(num_agents, pos.device)  # (M,), (M,)
        mask = present.unsqueeze(-1)  # (S, B, N, 1)
        if steps.frame is None:
            rel = (pos - steps.origin[None, :, None]) / cfg.position_scale_m  # (S, B, N, 2)
            rel = torch.where(mask, rel, torch.zeros_like(rel))  # (S, B, N, 2)
            step = torch.where(mask, (pos - prev_pos) / cfg.step_scale_m, torch.zeros_like(pos))
            x_edge = self._edge_inputs(rel, head)  # (S, B, N, N-1, E)
        else:
            rel, step, x_edge = self._agent_inputs(pos, prev_pos, present, steps.frame, head)
        own = rel
        if steps.roles is not None:  # one-hot roles (B, N, R) at every step
            role = steps.roles.unsqueeze(0).expand(num_steps, -1, -1, -1)  # (S, B, N, R)
            own = torch.cat([rel, role], -1)
            step = torch.cat([step, role], -1)
        x_self = self.encoder.f_self(torch.cat([own[..., :2], step], -1))  # (S, B, N, E)
        state = state or RecurrentState(None, None, None)
        g_self, g_interact = self.recurrent.g_self, self.recurrent.g_interact
        o_edge, h_edge = g_interact(x_edge.flatten(1, 3), state.edge)  # (S, B*M, H)
        o_self, h_self = g_self(x_self.flatten(1, 2), state.self_loop)  # (S, B*N, H)
        hidden = self.config.edge_hidden  # explicit: a scene of one agent has no edges
        o_edge = o_edge.view(num_steps, batch, num_agents, num_agents - 1, hidden)  # (S,B,N,N-1,H)
        o_self = o_self.view(num_steps, batch, num_agents, -1)  # (S, B, N, H)
        theta = self._attention(o_self, o_edge, present, labels, head)  # (S, B, N, N-1)
        attended = (theta.unsqueeze(-1) * o_edge).sum(-2)  # (S, B, N, H)
        node_in = torch.cat([self.encoder.f_embed(own), attended, o_self], -1)  # (S, B, N, E+2H)
        o_node, h_node = self.node.g_pred(node_in.flatten(1, 2), state.node)  # (S, B*N, Hn)
        head = self.head  # the packed model's output head (predictor.model.head), unchanged
        raw = head.raw_outputs(o_node, anchor is not None)
        raw = raw.view(num_steps, batch, num_agents, 5)  # (S, B, N, 5)
        if anchor is not None:
            gaussian = head.gaussian(raw, pos + anchor, steps.frame[1], head.anchor_std)
        elif steps.frame is None:
            base = pos + (pos - prev_pos) if cfg.mean_prior == "velocity" else pos  # (S, B, N, 2)
            gaussian = head.gaussian(raw, base, None)
        else:
            base = pos + (pos - prev_pos) if cfg.mean_prior == "velocity" else pos  # (S, B, N, 2)
            gaussian = head.gaussian(raw, base, steps.frame[1])
        return StepOutputs(gaussian, theta, RecurrentState(h_edge, h_self, h_node))

    def _agent_inputs(
        self, pos: Tensor, prev_pos: Tensor, present: Tensor, frame: AgentFrame, head: Tensor
    ) -> tuple[Tensor, Tensor, Tensor]:
        own, pair = agent_features(pos, prev_pos, present, frame, head)
        mean, std = self.encoder.input_mean, self.encoder.input_std  # the packed model's
        own = (own - mean[:4]) / std[:4]  # (S, B, N, 4)
        pair = (pair - mean[4:]) / std[4:]  # (S, B, N, N-1, 4)
        own = torch.where(present.unsqueeze(-1), own, 0.0)
        both = edge_present(present, head)  # (S, B, N, N-1)
        pair = torch.where(both.unsqueeze(-1), pair, 0.0)
        width = 4 if self.config.edge_velocity else 2
        own_per_edge = own[..., :2].unsqueeze(3).expand(*pair.shape[:-1], 2)
        x_edge = self.encoder.f_interact(torch.cat([own_per_edge, pair[..., :width]], -1))
        return own[..., :2], own[..., 2:], x_edge

    def _edge_inputs(self, rel: Tensor, head: Tensor) -> Tensor:
        linear = self.encoder.f_interact[0]
        gain = self.config.position_scale_m / self.config.interaction_scale_m
        w_tail, w_rel = linear.weight[:, :2], linear.weight[:, 2:] * gain  # (E, 2), (E, 2)
        per_tail = F.linear(rel, w_tail - w_rel, linear.bias)  # (S, B, N, E)
        per_head = F.linear(rel, w_rel)  # (S, B, N, E)
        shape = (*rel.shape[:2], rel.shape[2], rel.shape[2] - 1, per_head.shape[-1])
        heads = per_head.index_select(2, head).view(shape)  # (S, B, N, N-1, E)
        return self.encoder.f_interact[1](per_tail.unsqueeze(-2) + heads)  # (S, B, N, N-1, E)

    def _attention(
        self, o_self: Tensor, o_edge: Tensor, present: Tensor, labels: Tensor | None, head: Tensor
    ) -> Tensor:
        shape = o_edge.shape[:-1]  # (S, B, N, N-1)
        others = present.index_select(-1, head).view(shape)  # (S, B, N, N-1) head j present
        mask = others & present.unsqueeze(-1)  # (S, B, N, N-1) tail i present too
        mode = self.config.attention_mode
        if mode == "learned":
            f_attn = self.attention.f_attn
            query = f_attn(o_self) @ f_attn.weight  # (S, B, N, H)
            scores = (o_edge * query.unsqueeze(-2)).sum(-1) * self.config.attention_gain
            return masked_softmax(scores, mask)
        uniform = masked_softmax(torch.zeros(shape, device=o_edge.device), mask)  # (S,B,N,N-1)
        if mode == "uniform":
            return uniform
        heads = head.view(present.shape[-1], -1)  # (N, N-1) index of the k-th other agent
        onehot = (heads == labels.unsqueeze(-1)) & mask  # (S, B, N, N-1)
        labelled = onehot.any(-1, keepdim=True)  # (S, B, N, 1)
        return torch.where(labelled, onehot.to(uniform.dtype), uniform)  # (S, B, N, N-1)
