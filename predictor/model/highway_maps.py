"""The highway's maps inside the predictor: which map each agent reads, its rollout's velocity
changes, and the closed-form fits (at normalisation, and `refit_attended` every epoch).

`HighwayMaps` is a mixin of `SmoothAttentionPredictor` (predictor.model), which owns the
passes it calls (`_prepare`, `_block`); the maps' buffers (`highway_weight`,
`attended_weight`, ...) are registered here (`_register_maps`, called by the model's
constructor). The arithmetic itself is in predictor.highway (features, readings) and
predictor.highway_fit (the fits).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from torch import Tensor

from predictor.agent_frame import rotate
from predictor.config import ModelConfig
from predictor.highway import (
    CROSS_FIT_FOLDS,
    agent_maps,
    attended_changes,
    clamp_changes,
    constant_velocity_transform,
    edge_relations,
    fold_of,
    future_offsets,
    history_features,
    neighbour_features,
    relation_slots,
    uniform_attention,
    velocity_changes,
)
from predictor.highway_fit import change_bounds, fit_cross_fitted
from predictor.model.statistics import MIN_STAT_STD
from predictor.outputs import edge_index

if TYPE_CHECKING:  # annotations only: the model module imports this one
    from predictor.model.pass_inputs import PassInputs as _Steps

# "edge_relations": a relation holding less of an agent's attention than this is not fitted on
# for that agent (its rows would carry no weight; the ridge needs positive weights)
MIN_RELATION_SHARE = 1e-6


class HighwayMaps:
    """The highway part of `SmoothAttentionPredictor` (see the module docstring)."""

    config: ModelConfig

    def _register_maps(self) -> None:
        """Register the highway's maps (buffers; a learnt attended map is a parameter), zero
        until fitted with the normalisation (`_fit_highway`) or, with attended_refit, at every
        epoch start (`refit_attended`)."""
        cfg = self.config
        if cfg.highway_steps:
            features = 4 * cfg.highway_steps - 3  # velocities and their differences
            shape = (self.num_maps, features, cfg.highway_horizon)
            self.register_buffer("highway_weight", torch.zeros(*shape, 2))
            self.register_buffer("highway_bias", torch.zeros(shape[0], shape[2], 2))
            folds = CROSS_FIT_FOLDS  # the maps that training scenes use (cross-fitting)
            self.register_buffer("highway_fold_weight", torch.zeros(folds, *shape, 2))
            self.register_buffer("highway_fold_bias", torch.zeros(folds, shape[0], shape[2], 2))
            # each map's output range (predictor.highway_fit.change_bounds): zero until fitted
            self.register_buffer("highway_low", torch.zeros(shape[0], shape[2], 2))
            self.register_buffer("highway_high", torch.zeros(shape[0], shape[2], 2))
        if cfg.highway_attended:  # its edge statistics are fitted with the normalisation
            features = 2 * cfg.highway_steps + 2  # relative position and velocities
            self.register_buffer("attended_mean", torch.zeros(features))
            self.register_buffer("attended_std", torch.ones(features))
            shape = (self.num_maps, features, cfg.highway_horizon, 2)
            if cfg.attended_refit:  # refitted in closed form every epoch (refit_attended)
                self.register_buffer("attended_weight", torch.zeros(shape))
                self.register_buffer("attended_fold_weight", torch.zeros(CROSS_FIT_FOLDS, *shape))
            else:  # learnt by gradient
                self.attended_weight = torch.nn.Parameter(torch.zeros(shape))

    @property
    def num_maps(self) -> int:
        """Highway maps: one per role group (one without roles), twice that with
        highway_relation, and that per attended group with highway_head_groups."""
        return self.num_groups * (2 if self.config.highway_relation else 1) * self.num_kinds

    @property
    def num_kinds(self) -> int:
        """Kinds of edge read by maps of their own: the attended agent's role group with
        highway_head_groups, else one."""
        return self.num_groups if self.config.highway_head_groups else 1

    def _edge_relations(
        self, groups: Tensor, theta: Tensor, edges: Tensor, mask: Tensor, second: bool
    ) -> tuple[Tensor, Tensor, Tensor, Tensor | None]:
        """`edge_relations` of a pass, split by the attended agent's group with
        highway_head_groups."""
        kinds = None
        if self.num_kinds > 1:
            _, head = edge_index(groups.shape[1], groups.device)
            kinds = groups[:, head].view(*mask.shape)  # (B, N, N-1)
        return edge_relations(
            groups,
            theta,
            edges,
            mask,
            self.attended_mean,
            self.attended_std,
            kinds,
            self.num_kinds,
            second,
        )

    @property
    def num_groups(self) -> int:
        """Role groups with highway maps of their own: one per role (one without roles)."""
        return max(self.config.num_roles, 1)

    def _groups_of(self, roles: Tensor | None, like: Tensor) -> Tensor:
        """Each agent's highway map group (B, N): its role (group 0 for every agent of a model
        without roles; `like` gives the shape and device)."""
        if roles is None:
            return torch.zeros(like.shape, dtype=torch.long, device=like.device)
        return roles

    def fill_unclamped_range(self, state: dict[str, Tensor]) -> dict[str, Tensor]:
        """A state dict of this model with the highway's output range added where it lacks one
        (checkpoints written before `change_bounds` existed): an unbounded range, so such a
        model keeps the behaviour it was trained with."""
        if not self.config.highway_steps or "highway_low" in state:
            return state
        shape = self.highway_low.shape
        infinite = torch.full(shape, float("inf"))
        return {**state, "highway_low": -infinite, "highway_high": infinite}

    def _highway(self, steps: _Steps, theta: Tensor) -> Tensor | None:
        """The highway's velocity changes over the rollout (B, N, horizon, 2), world axes
        (None without a highway); theta (B, N, N-1): the attention at the last observed step
        (read by the attended highway)."""
        if not self.config.highway_steps:
            return None
        rotation = steps.frame[1]
        features, usable = history_features(
            steps.pos, steps.present, steps.num_observed, rotation, self.config.highway_steps
        )
        slots = self._groups_of(steps.role_index, usable)
        edges = mask = None
        if self.config.highway_attended:
            edges, mask = self._neighbour_features(steps)
            if self.config.attended_fit == "edge_relations":
                change = self._edge_relation_changes(
                    steps, theta, slots, features, usable, edges, mask
                )
                return rotate(change.permute(2, 0, 1, 3), rotation).permute(1, 2, 0, 3)
            if self.config.highway_relation:
                slots = relation_slots(slots, theta, edges, mask)
        weight, bias = agent_maps(
            self.highway_weight,
            self.highway_bias,
            self.highway_fold_weight,
            self.highway_fold_bias,
            slots,
            steps.scenes,
        )  # (B, N, F, horizon, 2), (B, N, horizon, 2)
        change = velocity_changes(features, usable, weight, bias)  # (B, N, horizon, 2)
        if self.config.highway_attended:
            change = change + self._attended(steps, theta, slots, edges, mask)
        change = clamp_changes(change, self.highway_low[slots], self.highway_high[slots])
        return rotate(change.permute(2, 0, 1, 3), rotation).permute(1, 2, 0, 3)

    def _neighbour_features(self, steps: _Steps) -> tuple[Tensor, Tensor]:
        """The attended highway's edge features (B, N, N-1, F) and their mask (B, N, N-1)."""
        _, head = edge_index(steps.pos.shape[2], steps.pos.device)
        return neighbour_features(
            steps.pos,
            steps.present,
            steps.num_observed,
            steps.frame[1],
            self.config.highway_steps,
            head,
        )

    def _attended_maps(self, steps: _Steps, slots: Tensor) -> Tensor:
        """Each agent's attended map (B, N, F, horizon, 2) for its map slot (B, N): the one
        fitted without the scene's fold on training scenes of a refitted model."""
        if self.config.attended_refit and steps.scenes is not None:  # cross-fitted maps
            fold = fold_of(steps.scenes, CROSS_FIT_FOLDS).unsqueeze(-1).expand_as(slots)
            return self.attended_fold_weight[fold, slots]
        return self.attended_weight[slots]

    def _attended(
        self, steps: _Steps, theta: Tensor, slots: Tensor, features: Tensor, mask: Tensor
    ) -> Tensor:
        """The attended highway's velocity changes (B, N, horizon, 2), agent frame [m/step];
        slots (B, N): each agent's map."""
        weight = self._attended_maps(steps, slots)
        change = attended_changes(
            features, mask, theta, self.attended_mean, self.attended_std, weight
        )
        return change * self.head.anchor_std  # (B, N, horizon, 2)

    def _edge_relation_changes(
        self,
        steps: _Steps,
        theta: Tensor,
        groups: Tensor,
        features: Tensor,
        usable: Tensor,
        edges: Tensor,
        mask: Tensor,
    ) -> Tensor:
        """The highway's velocity changes under attended_fit "edge_relations" (B, N, horizon,
        2), agent frame [m/step]: each relation's map reads the agent's own history and the
        attention-weighted mean of the edges in that relation, clamped to that map's range,
        and the readings are mixed by the relation's share of the attention. groups (B, N):
        each agent's map group; features, usable: its own history (`history_features`);
        edges, mask: its edge features (`neighbour_features`)."""
        slots, masses, attended, _ = self._edge_relations(groups, theta, edges, mask, False)
        parts = []
        for side in range(len(slots)):
            weight, bias = agent_maps(
                self.highway_weight,
                self.highway_bias,
                self.highway_fold_weight,
                self.highway_fold_bias,
                slots[side],
                steps.scenes,
            )
            own = velocity_changes(features, usable, weight, bias)  # (B, N, horizon, 2)
            read = torch.einsum(
                "bnf,bnfkc->bnkc", attended[side], self._attended_maps(steps, slots[side])
            )
            reading = clamp_changes(
                own + read * self.head.anchor_std,
                self.highway_low[slots[side]],
                self.highway_high[slots[side]],
            )
            parts.append(masses[side][..., None, None] * reading)
        return torch.stack(parts).sum(0)

    @torch.no_grad()
    def refit_attended(
        self,
        positions: Tensor,
        valid: Tensor,
        num_observed: int,
        labels: Tensor | None = None,
        roles: Tensor | None = None,
        batch_size: int = 64,
    ) -> None:
        """Refit the highway's own and attended maps jointly in closed form
        (`ModelConfig.attended_refit`) on the training scenes (B, T, N, .), in the order
        `fit_normalisation` saw them (the cross-fitting folds follow the scene index), with the
        attention the model gives now at the last observed step. labels (B, T, N) are needed
        for oracle attention, roles (B, N) where the model reads roles."""
        cfg = self.config
        if not cfg.attended_refit:
            raise ValueError("refit_attended needs ModelConfig.attended_refit")
        if cfg.num_roles > 0 and roles is None:
            raise ValueError("the model reads agent roles; refit_attended needs them")
        parts: list[tuple[Tensor, ...]] = []
        for first in range(0, positions.shape[0], batch_size):
            sl = slice(first, first + batch_size)
            steps = self._prepare(
                positions[sl],
                valid[sl],
                num_observed,
                None if labels is None else labels[sl],
                None if roles is None else roles[sl],
            )
            theta = self._block(steps, 0, num_observed, None).attention[-1]  # (B, N, N-1)
            parts.append(self._refit_samples(steps, theta))
        own, attended, second, offsets, samples, slots, masses = (
            torch.cat(column) for column in zip(*parts)
        )
        features = torch.cat([own, attended], -1)  # (B, N, F_own + F_att)
        moments = zero_at_cv = None
        if cfg.attended_fit != "mean" or cfg.highway_zero_at_cv or cfg.highway_min_std > 0:
            moments = features.unsqueeze(-1) * features.unsqueeze(-2)  # (B, N, F, F)
        if cfg.attended_fit != "mean":  # rows (own_i, z_ij) weighted by theta_ij
            split = own.shape[-1]
            moments[..., split:, split:] = second
        if cfg.highway_zero_at_cv:
            zero_at_cv = constant_velocity_transform(
                cfg.highway_steps, num_observed, attended.shape[-1]
            )
        weight, bias, fold_weight, fold_bias = fit_cross_fitted(
            features,
            offsets,
            samples,
            slots,
            self.num_maps,
            cfg.highway_horizon,
            moments,
            masses if cfg.attended_fit == "edge_relations" else None,
            zero_at_cv,
            cfg.highway_min_std,
        )
        split = own.shape[-1]
        scale = self.head.anchor_std.view(1, 1, 1, 2)  # attended maps are in units of anchor_std
        self.highway_weight.copy_(weight[:, :split])
        self.highway_bias.copy_(bias)
        self.highway_fold_weight.copy_(fold_weight[:, :, :split])
        self.highway_fold_bias.copy_(fold_bias)
        self.attended_weight.copy_(weight[:, split:] / scale)
        self.attended_fold_weight.copy_(fold_weight[:, :, split:] / scale)
        self._fit_bounds(offsets, samples, slots)

    def _fit_bounds(self, offsets: Tensor, samples: Tensor, slots: Tensor) -> None:
        """The maps' output ranges (`change_bounds`) from the fitted samples' targets."""
        low, high = change_bounds(
            offsets, samples, slots, self.num_maps, self.config.highway_horizon
        )
        self.highway_low.copy_(low)
        self.highway_high.copy_(high)

    def _refit_samples(self, steps: _Steps, theta: Tensor) -> tuple[Tensor, ...]:
        """Regression samples of `refit_attended` for one batch: own features (B, N, F_own),
        attended features sum_j theta_ij z_ij (B, N, F_att) and their attention-weighted second
        moment sum_j theta_ij z_ij z_ij^T (B, N, F_att, F_att) (an empty tensor unless
        `attended_fit` is "edges"), future offsets (B, N, T_pred, 2), which agents to fit on
        (B, N), each agent's map (B, N) and its weight (B, N) (ones). Under "edge_relations"
        each agent is two samples, one per relation (B, 2N, ...; 2K per agent with
        highway_head_groups' K kinds), weighted by its share of the attention
        (predictor.highway.edge_relations)."""
        rotation, t_obs = steps.frame[1], steps.num_observed
        own, usable = history_features(
            steps.pos, steps.present, t_obs, rotation, self.config.highway_steps
        )
        edges, mask = self._neighbour_features(steps)
        # the regression's moments in float64: from float32 products, the centred gram of a
        # nearly constant feature was rounding noise (standardised, entries as large as the
        # gram's own and asymmetric; Double Merge 3 + 10), which the ridge then fitted
        own, edges, theta = own.double(), edges.double(), theta.double()
        slots = self._groups_of(steps.role_index, usable)
        if self.config.attended_fit == "edge_relations":
            slots, masses, attended, second = self._edge_relations(slots, theta, edges, mask, True)
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
        if self.config.highway_relation:
            slots = relation_slots(slots, theta, edges, mask)
        standard = torch.where(
            mask.unsqueeze(-1), (edges - self.attended_mean) / self.attended_std, 0.0
        )
        attended = (theta.unsqueeze(-1) * standard).sum(2)  # (B, N, F_att)
        second = attended.new_zeros(0)
        if self.config.attended_fit == "edges":
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

    def _fit_highway(self, steps: _Steps, roles: Tensor | None, fit_maps: bool = True) -> None:
        """Fit the highway (predictor.highway) on the agents present over the whole history
        window and future: the map of all scenes, and one map without each cross-fitting fold
        (scene b belongs to fold b mod CROSS_FIT_FOLDS); roles (B, N) pick the map (one map if
        the model reads no roles). fit_maps=False: only the attended edges' statistics."""
        rotation = steps.frame[1]
        t_obs = steps.num_observed
        features, usable = history_features(
            steps.pos, steps.present, t_obs, rotation, self.config.highway_steps
        )
        offsets, complete = future_offsets(steps.pos, steps.present, t_obs, rotation)
        if self.config.num_roles <= 0 or roles is None:
            if self.config.num_roles > 0:
                raise ValueError("the model reads agent roles; fit_normalisation needs them")
            roles = torch.zeros(usable.shape, dtype=torch.long)
        slots = self._groups_of(roles.long(), usable)
        if self.config.highway_attended:  # standardisation over the usable edges
            edges, mask = self._neighbour_features(steps)
            if self.config.highway_relation:  # before any attention: the uniform one
                slots = relation_slots(slots, uniform_attention(mask), edges, mask)
                # with highway_head_groups the maps of attended kind 0 (the first refit, before
                # the first epoch, fits every kind)
                slots = slots // 2 * (2 * self.num_kinds) + slots % 2
            edges = edges[mask]  # (K, F)
            if len(edges) >= 2:
                self.attended_mean.copy_(edges.mean(0))
                self.attended_std.copy_(edges.std(0).clamp(min=MIN_STAT_STD))
        if not fit_maps:
            return
        horizon = self.config.highway_horizon
        maps = fit_cross_fitted(features, offsets, usable & complete, slots, self.num_maps, horizon)
        buffers = ("highway_weight", "highway_bias", "highway_fold_weight", "highway_fold_bias")
        for name, value in zip(buffers, maps):
            getattr(self, name).copy_(value)
        self._fit_bounds(offsets, usable & complete, slots)
