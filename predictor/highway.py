"""A linear autoregressive highway for the rollout (`ModelConfig.highway_steps`).

Linear extrapolation of an agent's own recent motion is what a ridge regression does well and
what the recurrent graph, measured, does not learn: its teacher-forced one-step error stayed at
constant velocity's (docs/PREDICTOR.md). As in LSTNet's autoregressive component (Lai et al.,
SIGIR 2018), a linear map from the agent's observed velocities to its future is added next to
the network, and the network predicts what is left: the part of the future that its own
history does not explain, which is where the other agents enter.

The map is fitted in closed form on the training split when the model's normalisation is
(ridge regression, alpha by grouped cross-validation, one map per agent role, as the ridge
baseline) and kept as buffers in the checkpoint; training does not change it, except that with
`ModelConfig.attended_refit` it is refitted at every epoch start jointly with the attended map
(`SmoothAttentionPredictor.refit_attended`). Inputs: the
last `highway_steps` velocities p^t - p^{t-1} in the agent's frame [m/step] and their
differences. Output: per
predicted step k, the velocity change v^{T_obs+k} - v^{T_obs-1} in the agent's frame
[m/step], whose running sum is the offset from constant velocity that the regression was
fitted to. Agents whose history window is incomplete get no highway (constant velocity).
This module computes the features and reads the maps; predictor.highway_fit fits them.

Stacking a network on a regression fitted to the same scenes trains it on the regression's
in-sample residuals, which are smaller than its residuals elsewhere; the model therefore also
keeps `CROSS_FIT_FOLDS` maps, each fitted without one fold of the training scenes, and a
training scene's rollout uses the map that never saw it (cross-fitting). Prediction uses the
map fitted on all training scenes.

A linear map is trusted only where it was fitted: the highway's velocity changes are clamped,
per map, predicted step and axis, to the range of its training targets (zero included, see
`predictor.highway_fit.change_bounds`). Unclamped, a map fitted on few scenes extrapolated
without bound: on Halting Car v1 the leader's maps per relation (fitted on 21 and 31 scenes,
coefficients up to 6.7e4 on raw features) sent 4 test scenes 3.4e4-4.5e4 m away (main-car
ADE 751 m; validation 5.15 m).
"""

from __future__ import annotations

import torch
from torch import Tensor

from predictor.agent_frame import rotate

# Cross-fitting: during training each scene's rollout uses a map fitted without its fold, so
# the network learns from residuals like those it meets on new scenes. Fitted on all training
# scenes, the map's residuals there were half its test ones (Double Merge, main cars: ADE
# 0.129 m on the training split, 0.261 m on the test split), and the network trained on them
# learnt corrections that did not carry over.
CROSS_FIT_FOLDS = 5


def history_features(
    pos: Tensor, present: Tensor, num_observed: int, rotation: Tensor, steps: int
) -> tuple[Tensor, Tensor]:
    """The agent-frame velocities [m/step] of the last `steps` observed steps and their
    differences (accelerations), as the ridge baseline's features; time-first inputs
    pos (T, B, N, 2), present (T, B, N), rotation (B, N, 2). Returns features
    (B, N, 4 * steps - 3), oldest first (velocities, then accelerations; without the last
    velocity's lateral component, which the frame makes zero), and (B, N) whether
    the agent is present over the whole window. With fewer observed steps than `steps` + 1
    the oldest velocities and accelerations are zeros (the fit gives them no weight); with
    fewer than 3 no agent is usable (constant velocity).

    The accelerations are linear in the velocities, but standardised on their own they make
    the regularised fit read them cheaply (Double Merge, 12 steps: test ADE of the main cars
    0.33 m from velocities alone)."""
    span = min(steps, num_observed - 1)
    if span < 2:  # no acceleration observed yet: no highway
        shape = (*present.shape[1:], 4 * steps - 3)
        return pos.new_zeros(shape), torch.zeros_like(present[0])
    window = pos[num_observed - 1 - span : num_observed]  # (span + 1, B, N, 2)
    usable = present[num_observed - 1 - span : num_observed].all(0)  # (B, N)
    velocity = rotate(window[1:] - window[:-1], rotation, inverse=True)  # (span, B, N, 2)
    accel = velocity[1:] - velocity[:-1]  # (span - 1, B, N, 2)
    missing = velocity.new_zeros(steps - span, *velocity.shape[1:])
    parts = [missing, velocity, missing, accel]  # oldest first, each block padded at its start
    features = torch.cat(parts, 0).permute(1, 2, 0, 3).flatten(2)  # (B, N, 4 * steps - 2)
    # the last velocity's lateral component is zero by construction of the frame (its x axis
    # is that velocity): standardised, its rounding noise became a unit-variance feature that
    # the regression used (measured: fits with float32 and float64 features differed by up to
    # 1.9 m on Double Merge, test ADE of the main cars 0.286 m, ridge 0.255 m)
    keep = [k for k in range(features.shape[-1]) if k != 2 * steps - 1]
    features = features[..., keep]  # (B, N, 4 * steps - 3)
    return torch.where(usable.unsqueeze(-1), features, 0.0), usable


def constant_velocity_transform(steps: int, num_observed: int, extra: int = 0) -> Tensor:
    """The linear map T (F_own - 1, F_own + extra) from `history_features`' features
    (F_own = 4 * steps - 3), followed by `extra` others (the attended highway's, which it
    drops), to the features of the highway's form that is zero at constant velocity
    (`ModelConfig.highway_zero_at_cv`): each observed velocity minus the last one (the last's
    longitudinal component dropped; its lateral one is zero) and the accelerations. A
    constant-velocity history maps to zeros, so a map of these features without intercept
    predicts constant velocity for it, whatever the other agents do. Velocities missing from a
    short history stay zero."""
    span = min(steps, num_observed - 1)
    own = 4 * steps - 3
    last = 2 * steps - 2  # the last velocity's longitudinal component
    transform = torch.eye(own + extra, dtype=torch.float64)
    for slot in range(steps - span, steps - 1):
        transform[2 * slot, last] = -1.0
    return torch.cat([transform[:last], transform[last + 1 : own]])


def future_offsets(
    pos: Tensor, present: Tensor, num_observed: int, rotation: Tensor
) -> tuple[Tensor, Tensor]:
    """Offsets of the predicted positions from constant velocity, agent frame: (B, N, T_pred, 2)
    [m], and (B, N) whether the agent is present at every predicted step."""
    last, velocity = pos[num_observed - 1], pos[num_observed - 1] - pos[num_observed - 2]
    ahead = torch.arange(1, pos.shape[0] - num_observed + 1, dtype=pos.dtype)  # (T_pred,)
    constant = last + ahead.view(-1, 1, 1, 1) * velocity  # (T_pred, B, N, 2)
    offset = rotate(pos[num_observed:] - constant, rotation, inverse=True)  # (T_pred, B, N, 2)
    return offset.permute(1, 2, 0, 3), present[num_observed:].all(0)


def velocity_changes(features: Tensor, usable: Tensor, weight: Tensor, bias: Tensor) -> Tensor:
    """The highway's velocity changes (B, N, horizon, 2), agent frame, zero where not usable;
    weight (B, N, F, horizon, 2) and bias (B, N, horizon, 2) are each agent's map."""
    change = torch.einsum("bnf,bnfkc->bnkc", features, weight) + bias  # (B, N, horizon, 2)
    return torch.where(usable[..., None, None], change, 0.0)


def clamp_changes(change: Tensor, low: Tensor, high: Tensor) -> Tensor:
    """Velocity changes (B, N, horizon, 2) clamped to each agent's map range (B, N, horizon, 2)
    (`predictor.highway_fit.change_bounds`)."""
    return torch.maximum(torch.minimum(change, high), low)


def fold_of(scenes: Tensor, folds: int) -> Tensor:
    """The cross-fitting fold of training scenes, by their index in the training split."""
    return scenes % folds


def agent_maps(
    weight: Tensor,
    bias: Tensor,
    fold_weight: Tensor,
    fold_bias: Tensor,
    roles: Tensor,
    scenes: Tensor | None,
) -> tuple[Tensor, Tensor]:
    """Each agent's map (B, N, F, horizon, 2), (B, N, horizon, 2) by its role (B, N): the map
    of all training scenes, or with `scenes` (B,) (training-split indices) the map fitted
    without the scene's fold."""
    if scenes is None:
        return weight[roles], bias[roles]
    fold = fold_of(scenes, CROSS_FIT_FOLDS).unsqueeze(-1).expand_as(roles)  # (B, N)
    return fold_weight[fold, roles], fold_bias[fold, roles]


def neighbour_features(
    pos: Tensor, present: Tensor, num_observed: int, rotation: Tensor, steps: int, head: Tensor
) -> tuple[Tensor, Tensor]:
    """Edge features g_ij of the attended highway (`ModelConfig.highway_attended`), as the
    ridge baseline's neighbour features: the other agent j's position relative to agent i at
    the last observed step and j's velocities [m/step] over the last `steps` observed steps,
    both in i's frame. Time-first inputs pos (T, B, N, 2), present (T, B, N), rotation
    (B, N, 2), head (N*(N-1),) the edges' other agents (i-major). Returns (B, N, N-1,
    2 * steps + 2), oldest velocity first (zeros before the first observed step), and (B, N,
    N-1) whether i and j are both present over the window (features zero elsewhere)."""
    num_agents, batch = pos.shape[2], pos.shape[1]
    edges = (batch, num_agents, num_agents - 1)
    span = min(steps, num_observed - 1)
    if span < 1 or num_agents < 2:
        return pos.new_zeros(*edges, 2 * steps + 2), torch.zeros(edges, dtype=torch.bool)
    last = num_observed - 1
    window = pos[last - span : last + 1]  # (span + 1, B, N, 2)
    usable = present[last - span : last + 1].all(0)  # (B, N)
    frame = rotation.unsqueeze(2)  # (B, N, 1, 2): agent i's frame for each of its edges
    theirs = window.index_select(2, head).view(span + 1, *edges, 2)  # (span+1, B, N, N-1, 2)
    relative = rotate(theirs[-1] - window[-1].unsqueeze(2), frame, inverse=True)  # (B,N,N-1,2)
    velocity = rotate(theirs[1:] - theirs[:-1], frame, inverse=True)  # (span, B, N, N-1, 2)
    missing = velocity.new_zeros(steps - span, *velocity.shape[1:])
    velocity = torch.cat([missing, velocity], 0).permute(1, 2, 3, 0, 4).flatten(3)
    mask = usable.index_select(-1, head).view(edges) & usable.unsqueeze(-1)  # (B, N, N-1)
    features = torch.cat([relative, velocity], -1)  # (B, N, N-1, 2 * steps + 2)
    return torch.where(mask.unsqueeze(-1), features, 0.0), mask


def attended_changes(
    features: Tensor, mask: Tensor, theta: Tensor, mean: Tensor, std: Tensor, weight: Tensor
) -> Tensor:
    """The attended highway's velocity changes (B, N, horizon, 2), agent frame, in units of
    the model's `anchor_std`: sum_j theta_ij z_ij mapped by each agent's `weight` (B, N, F,
    horizon, 2), where z_ij are the standardised edge features (B, N, N-1, F) (zero off
    `mask`) and theta (B, N, N-1) the attention at the last observed step."""
    standard = torch.where(mask.unsqueeze(-1), (features - mean) / std, 0.0)
    attended = (theta.unsqueeze(-1) * standard).sum(2)  # (B, N, F)
    return torch.einsum("bnf,bnfkc->bnkc", attended, weight)


def relation_slots(roles: Tensor, theta: Tensor, features: Tensor, mask: Tensor) -> Tensor:
    """The highway map of each agent under `ModelConfig.highway_relation` (B, N): 2 x role, or
    2 x role + 1 where the attended agents lie behind it (sum_j theta_ij x_ij <= 0, x_ij the
    longitudinal position of j in i's frame, `neighbour_features`' first channel). roles
    (B, N), theta and mask (B, N, N-1), features (B, N, N-1, F)."""
    along = torch.where(mask, features[..., 0], 0.0)  # (B, N, N-1)
    ahead = (theta * along).sum(-1) > 0  # (B, N)
    return 2 * roles + (~ahead).long()


def edge_relations(
    groups: Tensor,
    theta: Tensor,
    features: Tensor,
    mask: Tensor,
    mean: Tensor,
    std: Tensor,
    kinds: Tensor | None = None,
    num_kinds: int = 1,
    second_moment: bool = True,
) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
    """The attention split by each edge's own relation (`ModelConfig.attended_fit`
    "edge_relations"): for the agents ahead of agent i (x_ij > 0, `neighbour_features`' first
    channel) and those behind it, in that order, and with `kinds` (B, N, N-1) in [0, num_kinds)
    (`ModelConfig.highway_head_groups`: the attended agent's role group) per kind, kind-major,
    the map each of the 2K parts reads (2K, B, N) (2K x group + 2 x kind + 0 ahead, + 1 behind),
    its share of i's attention over the usable edges (2K, B, N) (all of it on kind 0 behind
    where i has none), and the share-weighted mean (2K, B, N, F) and second moment
    (2K, B, N, F, F; None unless second_moment) of their standardised edge features z_ij.
    groups (B, N), theta and mask (B, N, N-1), features (B, N, N-1, F), mean and std (F,)."""
    standard = torch.where(mask.unsqueeze(-1), (features - mean) / std, 0.0)
    used = torch.where(mask, theta, 0.0)
    total = used.sum(-1, keepdim=True)  # (B, N, 1)
    share = used / total.clamp(min=1e-12)
    ahead = mask & (features[..., 0] > 0)
    parts = []
    for kind in range(num_kinds):
        of_kind = mask if kinds is None else mask & (kinds == kind)
        parts += [of_kind & ahead, of_kind & ~ahead]
    weight = torch.where(torch.stack(parts), share, 0.0)  # (2K, B, N, N-1)
    masses = weight.sum(-1)  # (2K, B, N)
    fallback = torch.where(total.squeeze(-1) > 0, masses[1], 1.0)  # (B, N)
    masses = torch.cat([masses[:1], fallback.unsqueeze(0), masses[2:]])
    scale = masses.clamp(min=1e-12).unsqueeze(-1)
    attended = torch.einsum("sbne,bnef->sbnf", weight, standard) / scale
    second = None
    if second_moment:
        second = torch.einsum("sbne,bnef,bneg->sbnfg", weight, standard, standard)
        second = second / scale[..., None]
    count = 2 * num_kinds
    slots = count * groups + torch.arange(count, device=groups.device).view(count, 1, 1)
    return slots, masses, attended, second


def uniform_attention(mask: Tensor) -> Tensor:
    """Equal weights over each agent's usable edges (B, N, N-1) (zeros where it has none)."""
    weights = mask.to(torch.get_default_dtype())
    return weights / weights.sum(-1, keepdim=True).clamp(min=1.0)
