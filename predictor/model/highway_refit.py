"""The closed-form fits of the highway part's maps (predictor.model.highway_maps): their
regression samples and ridge fits, returned for the part to keep.

- `fit_at_normalisation`: with the model's normalisation, the own-history maps on the training
  scenes (the maps of all scenes and one without each cross-fitting fold) and the attended
  edges' standardisation statistics;
- `refit_samples` and `refit_maps` (`ModelConfig.attended_refit`, every epoch start): the own
  and attended maps jointly, with the attention the model gives now at the last observed step.
  `attended_fit` chooses the rows: "mean", the attention-weighted mean of the edge features;
  "edges", each edge a row weighted by its attention (predictor.moment_ridge); and
  "edge_relations", each edge read by its relation's map, each agent a sample per relation
  weighted by the relation's share of its attention.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from predictor.highway import (
    constant_velocity_transform,
    future_offsets,
    history_features,
    relation_slots,
    uniform_attention,
)
from predictor.highway_fit import fit_cross_fitted
from predictor.model.pass_inputs import PassInputs
from predictor.model.statistics import MIN_STAT_STD

# The functions below take the highway part (`predictor.model.highway_maps.Highway`, which
# imports this module) as a plain nn.Module, so that the two modules do not import each other.

# "edge_relations": a relation holding less of an agent's attention than this is not fitted on
# for that agent (its rows would carry no weight; the ridge needs positive weights)
MIN_RELATION_SHARE = 1e-6

Maps = tuple[Tensor, Tensor, Tensor, Tensor]  # weight, bias, fold weights, fold biases
Bounds = tuple[Tensor, Tensor, Tensor]  # what `change_bounds` reads: offsets, samples, slots


def fit_at_normalisation(
    highway: nn.Module, steps: PassInputs, roles: Tensor | None, fit_maps: bool
) -> tuple[tuple[Tensor, Tensor] | None, Maps | None, Bounds | None]:
    """The highway fitted on the agents present over the whole history window and future of
    the (training) scenes of `steps`: the attended edges' (mean, std) (None without the
    attended highway or with fewer than two usable edges), and with `fit_maps` the own-history
    maps of all scenes and one without each cross-fitting fold (scene b belongs to fold b mod
    CROSS_FIT_FOLDS) with what their output ranges are fitted on. roles (B, N) pick the map
    (one map if the model reads no roles)."""
    rotation = steps.frame[1]
    t_obs = steps.num_observed
    features, usable = history_features(steps.pos, steps.present, t_obs, rotation, highway.steps)
    offsets, complete = future_offsets(steps.pos, steps.present, t_obs, rotation)
    if highway.num_roles <= 0 or roles is None:
        roles = torch.zeros(usable.shape, dtype=torch.long)
    slots = highway.groups_of(roles.long(), usable)
    statistics = None
    if highway.attended:  # standardisation over the usable edges
        edges, mask = highway.neighbour_features(steps)
        if highway.relation:  # before any attention: the uniform one
            slots = relation_slots(slots, uniform_attention(mask), edges, mask)
            # with highway_head_groups the maps of attended kind 0 (the first refit, before
            # the first epoch, fits every kind)
            slots = slots // 2 * (2 * highway.num_kinds) + slots % 2
        edges = edges[mask]  # (K, F)
        if len(edges) >= 2:
            statistics = (edges.mean(0), edges.std(0).clamp(min=MIN_STAT_STD))
    if not fit_maps:
        return statistics, None, None
    samples = usable & complete
    maps = fit_cross_fitted(features, offsets, samples, slots, highway.num_maps, highway.horizon)
    return statistics, maps, (offsets, samples, slots)


def refit_samples(highway: nn.Module, steps: PassInputs, theta: Tensor) -> tuple[Tensor, ...]:
    """Regression samples of `refit_maps` for one batch: own features (B, N, F_own), attended
    features sum_j theta_ij z_ij (B, N, F_att) and their attention-weighted second moment
    sum_j theta_ij z_ij z_ij^T (B, N, F_att, F_att) (an empty tensor unless `attended_fit` is
    "edges"), future offsets (B, N, T_pred, 2), which agents to fit on (B, N), each agent's
    map (B, N) and its weight (B, N) (ones). Under "edge_relations" each agent is two samples,
    one per relation (B, 2N, ...; 2K per agent with highway_head_groups' K kinds), weighted by
    its share of the attention (predictor.highway.edge_relations). theta (B, N, N-1): the
    attention at the last observed step."""
    rotation, t_obs = steps.frame[1], steps.num_observed
    own, usable = history_features(steps.pos, steps.present, t_obs, rotation, highway.steps)
    edges, mask = highway.neighbour_features(steps)
    # the regression's moments in float64: from float32 products, the centred gram of a
    # nearly constant feature was rounding noise (standardised, entries as large as the
    # gram's own and asymmetric; Double Merge 3 + 10), which the ridge then fitted
    own, edges, theta = own.double(), edges.double(), theta.double()
    slots = highway.groups_of(steps.role_index, usable)
    if highway.attended_fit == "edge_relations":
        slots, masses, attended, second = highway.edge_relations(slots, theta, edges, mask, True)
        offsets, complete = future_offsets(steps.pos, steps.present, t_obs, rotation)
        fitted = (usable & complete).unsqueeze(0) & (masses > MIN_RELATION_SHARE)
        parts = len(slots)
        return (
            torch.cat([own] * parts, 1),
            torch.cat(list(attended), 1),
            torch.cat(list(second), 1),
            torch.cat([offsets] * parts, 1),
            torch.cat(list(fitted), 1),
            torch.cat(list(slots), 1),
            torch.cat(list(masses), 1),
        )
    if highway.relation:
        slots = relation_slots(slots, theta, edges, mask)
    standard = torch.where(
        mask.unsqueeze(-1), (edges - highway.attended_mean) / highway.attended_std, 0.0
    )
    attended = (theta.unsqueeze(-1) * standard).sum(2)  # (B, N, F_att)
    second = attended.new_zeros(0)
    if highway.attended_fit == "edges":
        second = torch.einsum("bne,bnef,bneg->bnfg", theta, standard, standard)
    offsets, complete = future_offsets(steps.pos, steps.present, t_obs, rotation)
    return (
        own,
        attended,
        second,
        offsets,
        usable & complete,
        slots,
        torch.ones_like(theta[..., 0]),
    )


def refit_maps(
    highway: nn.Module, samples: list[tuple[Tensor, ...]], num_observed: int
) -> tuple[Maps, Bounds, int]:
    """The own and attended maps fitted jointly (cross-fitted, `fit_cross_fitted`) on the
    batches' `refit_samples`: the maps over the features (own, attended), what their output
    ranges are fitted on, and the number of own features (where the attended ones begin)."""
    own, attended, second, offsets, fitted, slots, masses = (
        torch.cat(column) for column in zip(*samples)
    )
    features = torch.cat([own, attended], -1)  # (B, N, F_own + F_att)
    split = own.shape[-1]
    moments = zero_at_cv = None
    if highway.attended_fit != "mean" or highway.zero_at_cv or highway.min_std > 0:
        moments = features.unsqueeze(-1) * features.unsqueeze(-2)  # (B, N, F, F)
    if highway.attended_fit != "mean":  # rows (own_i, z_ij) weighted by theta_ij
        moments[..., split:, split:] = second
    if highway.zero_at_cv:
        zero_at_cv = constant_velocity_transform(highway.steps, num_observed, attended.shape[-1])
    maps = fit_cross_fitted(
        features,
        offsets,
        fitted,
        slots,
        highway.num_maps,
        highway.horizon,
        moments,
        masses if highway.attended_fit == "edge_relations" else None,
        zero_at_cv,
        highway.min_std,
    )
    return maps, (offsets, fitted, slots), split
