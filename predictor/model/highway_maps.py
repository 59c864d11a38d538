"""The highway part (`ModelConfig.highway_steps`): its linear maps, which map each agent reads,
and the velocity changes they add to the anchored rollout's prior.

The own-history maps read the agent's last `highway_steps` observed velocities; with
`highway_attended` the attended maps also read the agents it attends to (sum_j theta_ij z_ij of
their standardised relative positions and velocities, theta the attention at the last observed
step), learnt by gradient or (`attended_refit`) refitted in closed form with the own maps at
every epoch start. The maps are chosen per role group (one without roles), per relation to the
attended agents (`highway_relation`, ahead or behind; per edge under `attended_fit`
"edge_relations") and per attended group (`highway_head_groups`); training scenes read the maps
fitted without their cross-fitting fold. The arithmetic is in predictor.highway (features,
readings) and predictor.highway_fit (ridge fits); the samples and fits of this part's maps are
in predictor.model.highway_refit.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from predictor.agent_frame import rotate
from predictor.config import ModelConfig
from predictor.highway import (
    CROSS_FIT_FOLDS,
    agent_maps,
    attended_changes,
    clamp_changes,
    edge_relations,
    fold_of,
    history_features,
    neighbour_features,
    relation_slots,
    velocity_changes,
)
from predictor.highway_fit import change_bounds
from predictor.model.highway_refit import fit_at_normalisation, refit_maps, refit_samples
from predictor.model.pass_inputs import PassInputs
from predictor.outputs import edge_index


class Highway(nn.Module):
    """The highway's maps and their reading (see the module docstring). Buffers (a learnt
    attended map is a parameter), zero until fitted with the normalisation (`fit`) or, with
    attended_refit, at every epoch start (`refit`)."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        self.steps = config.highway_steps
        self.horizon = config.highway_horizon
        self.num_roles = config.num_roles
        self.attended = config.highway_attended
        self.refits = config.attended_refit
        self.attended_fit = config.attended_fit
        self.relation = config.highway_relation
        self.head_groups = config.highway_head_groups
        self.zero_at_cv = config.highway_zero_at_cv
        self.min_std = config.highway_min_std
        features = 4 * self.steps - 3  # velocities and their differences
        shape = (self.num_maps, features, self.horizon)
        self.register_buffer("highway_weight", torch.zeros(*shape, 2))
        self.register_buffer("highway_bias", torch.zeros(shape[0], shape[2], 2))
        folds = CROSS_FIT_FOLDS  # the maps that training scenes use (cross-fitting)
        self.register_buffer("highway_fold_weight", torch.zeros(folds, *shape, 2))
        self.register_buffer("highway_fold_bias", torch.zeros(folds, shape[0], shape[2], 2))
        # each map's output range (predictor.highway_fit.change_bounds): zero until fitted
        self.register_buffer("highway_low", torch.zeros(shape[0], shape[2], 2))
        self.register_buffer("highway_high", torch.zeros(shape[0], shape[2], 2))
        if self.attended:  # its edge statistics are fitted with the normalisation
            features = 2 * self.steps + 2  # relative position and velocities
            self.register_buffer("attended_mean", torch.zeros(features))
            self.register_buffer("attended_std", torch.ones(features))
            shape = (self.num_maps, features, self.horizon, 2)
            if self.refits:  # refitted in closed form every epoch (refit)
                self.register_buffer("attended_weight", torch.zeros(shape))
                self.register_buffer("attended_fold_weight", torch.zeros(CROSS_FIT_FOLDS, *shape))
            else:  # learnt by gradient
                self.attended_weight = nn.Parameter(torch.zeros(shape))

    @property
    def num_groups(self) -> int:
        """Role groups with highway maps of their own: one per role (one without roles)."""
        return max(self.num_roles, 1)

    @property
    def num_kinds(self) -> int:
        """Kinds of edge read by maps of their own: the attended agent's role group with
        highway_head_groups, else one."""
        return self.num_groups if self.head_groups else 1

    @property
    def num_maps(self) -> int:
        """Highway maps: one per role group (one without roles), twice that with
        highway_relation, and that per attended group with highway_head_groups."""
        return self.num_groups * (2 if self.relation else 1) * self.num_kinds

    def require_roles(self, roles: Tensor | None, reader: str) -> None:
        """ValueError if the maps are chosen by role and `reader` got no roles."""
        if self.num_roles > 0 and roles is None:
            raise ValueError(f"the model reads agent roles; {reader} needs them")

    def groups_of(self, roles: Tensor | None, like: Tensor) -> Tensor:
        """Each agent's highway map group (B, N): its role (group 0 for every agent of a model
        without roles; `like` gives the shape and device)."""
        if roles is None:
            return torch.zeros(like.shape, dtype=torch.long, device=like.device)
        return roles

    def fill_unclamped_range(self, state: dict[str, Tensor]) -> dict[str, Tensor]:
        """A (checkpoint-named) state dict of the model with the highway's output range added
        where it lacks one (checkpoints written before `change_bounds` existed): an unbounded
        range, so such a model keeps the behaviour it was trained with."""
        if "highway_low" in state:
            return state
        shape = self.highway_low.shape
        infinite = torch.full(shape, float("inf"))
        return {**state, "highway_low": -infinite, "highway_high": infinite}

    # ----------------------------------------------------------------------------- reading
    def forward(self, steps: PassInputs, theta: Tensor, anchor_std: Tensor) -> Tensor:
        """The highway's velocity changes over the rollout (B, N, horizon, 2), world axes;
        theta (B, N, N-1): the attention at the last observed step (read by the attended
        highway); anchor_std (2,): the unit of the attended maps' outputs [m/step]."""
        rotation = steps.frame[1]
        features, usable = history_features(
            steps.pos, steps.present, steps.num_observed, rotation, self.steps
        )
        slots = self.groups_of(steps.role_index, usable)
        edges = mask = None
        if self.attended:
            edges, mask = self.neighbour_features(steps)
            if self.attended_fit == "edge_relations":
                change = self.edge_relation_changes(
                    steps, theta, slots, features, usable, edges, mask, anchor_std
                )
                return rotate(change.permute(2, 0, 1, 3), rotation).permute(1, 2, 0, 3)
            if self.relation:
                slots = relation_slots(slots, theta, edges, mask)
        weight, bias = self.own_maps(slots, steps.scenes)  # (B, N, F, K, 2), (B, N, K, 2)
        change = velocity_changes(features, usable, weight, bias)  # (B, N, horizon, 2)
        if self.attended:
            change = change + self.attended_changes(steps, theta, slots, edges, mask, anchor_std)
        change = clamp_changes(change, self.highway_low[slots], self.highway_high[slots])
        return rotate(change.permute(2, 0, 1, 3), rotation).permute(1, 2, 0, 3)

    def own_maps(self, slots: Tensor, scenes: Tensor | None) -> tuple[Tensor, Tensor]:
        """Each agent's own-history map (B, N, F, horizon, 2), (B, N, horizon, 2) for its map
        slot (B, N): the one fitted without the scene's fold for training `scenes` (B,)."""
        return agent_maps(
            self.highway_weight,
            self.highway_bias,
            self.highway_fold_weight,
            self.highway_fold_bias,
            slots,
            scenes,
        )

    def neighbour_features(self, steps: PassInputs) -> tuple[Tensor, Tensor]:
        """The attended highway's edge features (B, N, N-1, F) and their mask (B, N, N-1)."""
        _, head = edge_index(steps.pos.shape[2], steps.pos.device)
        return neighbour_features(
            steps.pos, steps.present, steps.num_observed, steps.frame[1], self.steps, head
        )

    def attended_maps(self, steps: PassInputs, slots: Tensor) -> Tensor:
        """Each agent's attended map (B, N, F, horizon, 2) for its map slot (B, N): the one
        fitted without the scene's fold on training scenes of a refitted model."""
        if self.refits and steps.scenes is not None:  # cross-fitted maps
            fold = fold_of(steps.scenes, CROSS_FIT_FOLDS).unsqueeze(-1).expand_as(slots)
            return self.attended_fold_weight[fold, slots]
        return self.attended_weight[slots]

    def attended_changes(
        self,
        steps: PassInputs,
        theta: Tensor,
        slots: Tensor,
        features: Tensor,
        mask: Tensor,
        anchor_std: Tensor,
    ) -> Tensor:
        """The attended highway's velocity changes (B, N, horizon, 2), agent frame [m/step];
        slots (B, N): each agent's map."""
        weight = self.attended_maps(steps, slots)
        change = attended_changes(
            features, mask, theta, self.attended_mean, self.attended_std, weight
        )
        return change * anchor_std  # (B, N, horizon, 2)

    def edge_relations(
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

    def edge_relation_changes(
        self,
        steps: PassInputs,
        theta: Tensor,
        groups: Tensor,
        features: Tensor,
        usable: Tensor,
        edges: Tensor,
        mask: Tensor,
        anchor_std: Tensor,
    ) -> Tensor:
        """The highway's velocity changes under attended_fit "edge_relations" (B, N, horizon,
        2), agent frame [m/step]: each relation's map reads the agent's own history and the
        attention-weighted mean of the edges in that relation, clamped to that map's range,
        and the readings are mixed by the relation's share of the attention. groups (B, N):
        each agent's map group; features, usable: its own history (`history_features`);
        edges, mask: its edge features (`neighbour_features`)."""
        slots, masses, attended, _ = self.edge_relations(groups, theta, edges, mask, False)
        parts = []
        for side in range(len(slots)):
            weight, bias = self.own_maps(slots[side], steps.scenes)
            own = velocity_changes(features, usable, weight, bias)  # (B, N, horizon, 2)
            read = torch.einsum(
                "bnf,bnfkc->bnkc", attended[side], self.attended_maps(steps, slots[side])
            )
            reading = clamp_changes(
                own + read * anchor_std,
                self.highway_low[slots[side]],
                self.highway_high[slots[side]],
            )
            parts.append(masses[side][..., None, None] * reading)
        return torch.stack(parts).sum(0)

    # ----------------------------------------------------------------------------- fitting
    @torch.no_grad()
    def fit(self, steps: PassInputs, roles: Tensor | None, fit_maps: bool = True) -> None:
        """Fit the own-history maps on (training) scenes with the model's normalisation, and
        the attended edges' statistics (`fit_at_normalisation`); fit_maps=False: only those
        statistics (training leaves the maps to the first `refit`, which replaces them)."""
        self.require_roles(roles, "fit_normalisation")
        statistics, maps, bounds = fit_at_normalisation(self, steps, roles, fit_maps)
        if statistics is not None:
            self.attended_mean.copy_(statistics[0])
            self.attended_std.copy_(statistics[1])
        if maps is not None:
            self._store(maps, bounds)

    @torch.no_grad()
    def refit(
        self, samples: list[tuple[Tensor, ...]], num_observed: int, anchor_std: Tensor
    ) -> None:
        """Refit the own and attended maps jointly in closed form (`refit_maps`) on the
        regression samples of the training scenes' batches (`refit_samples`, in the order of
        the scenes, which the cross-fitting folds follow); anchor_std (2,): the attended maps'
        output unit."""
        maps, bounds, split = refit_maps(self, samples, num_observed)
        weight, bias, fold_weight, fold_bias = maps
        scale = anchor_std.view(1, 1, 1, 2)  # attended maps are in units of anchor_std
        self._store((weight[:, :split], bias, fold_weight[:, :, :split], fold_bias), bounds)
        self.attended_weight.copy_(weight[:, split:] / scale)
        self.attended_fold_weight.copy_(fold_weight[:, :, split:] / scale)

    def samples(self, steps: PassInputs, theta: Tensor) -> tuple[Tensor, ...]:
        """The regression samples of `refit` for one batch of training scenes, read with the
        attention theta (B, N, N-1) at their last observed step (`refit_samples`)."""
        return refit_samples(self, steps, theta)

    def _store(self, maps: tuple[Tensor, ...], bounds: tuple[Tensor, Tensor, Tensor]) -> None:
        """Keep fitted own-history maps (weight, bias, fold weights, fold biases) and their
        output ranges (`change_bounds` of the fitted targets: offsets, samples, slots)."""
        buffers = ("highway_weight", "highway_bias", "highway_fold_weight", "highway_fold_bias")
        for name, value in zip(buffers, maps, strict=True):
            getattr(self, name).copy_(value)
        low, high = change_bounds(*bounds, self.num_maps, self.horizon)
        self.highway_low.copy_(low)
        self.highway_high.copy_(high)


def build_highway(config: ModelConfig) -> Highway | None:
    """The highway part, or None without one (highway_steps 0)."""
    return Highway(config) if config.highway_steps else None
