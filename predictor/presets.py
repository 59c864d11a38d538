"""Named configurations: the presets (`PRESETS`) a run starts from, and `make_configs`, which
composes a preset with a variant of the paper (`predictor.config.VARIANTS`) and field overrides.
The fields themselves, their defaults and their rules are `predictor.config`'s."""

from __future__ import annotations

from dataclasses import fields
from typing import Any

from predictor.config import (
    HIGHWAY_SWITCHES,
    ROLES_FROM_DATA,
    VARIANTS,
    ModelConfig,
    TrainConfig,
    build_config,
)

# Named settings: (ModelConfig values, TrainConfig values) over the dataclass defaults.
# "paper": the literal paper model and optimiser (the dataclass defaults).
# "agent": agent-centric standardised inputs, relative velocity on edges, deviation-scaled
# agent-frame offsets, an anchored rollout, agent roles as inputs, and a longer cosine schedule
# with smaller batches (more optimiser steps: 52 training scenes at batch 8 are only 7 steps
# per epoch), the main agents' loss terms weighted 5x, a cross-fitted linear highway for the
# agent's own motion and for the attended agents (refitted every epoch, one map per relation,
# each edge read by its own relation's map and its attended agent's role group's), a learned
# attention bias per pair of roles, attention that starts with equal shares per neighbour role
# and scores times 10. docs/PREDICTOR.md has the measurement behind each switch.
# "agent_zero_cv": "agent" whose highway refit scales no feature by less than 1e-4 m/step (~10x
# the float32 rounding of a velocity a few hundred metres out) and keeps, per map, the form that
# is zero at constant velocity where cross-validation prefers it (the agent preset's Halting
# Car v1 `go`-major runs put the constant-speed leader 0.5-0.9 m off; docs/PREDICTOR.md).
PRESETS: dict[str, tuple[dict[str, Any], dict[str, Any]]] = {
    "paper": ({}, {}),
    "agent": (
        {
            "frame": "agent",
            "standardise": True,
            "edge_velocity": True,
            "offset_scale": "deviation",
            "detach_covariance": True,
            "rollout_prior": "anchored",
            "num_roles": ROLES_FROM_DATA,
            "highway_steps": 12,
            "highway_attended": True,
            "attended_refit": True,
            "highway_relation": True,
            "attended_fit": "edge_relations",
            "role_attention_bias": True,
            "role_balanced_attention": True,
            "highway_head_groups": True,
            "attention_gain": 10.0,
        },
        {
            "lr_schedule": "cosine",
            "batch_size": 4,
            "epochs": 90,
            "lr": 3e-3,
            "rollout_feed": "mean",
            "mean_loss": "displacement",
            "one_step_needs_previous": True,
            "main_agent_weight": 5.0,
        },
    ),
}
PRESETS["agent_zero_cv"] = (
    {**PRESETS["agent"][0], "highway_zero_at_cv": True, "highway_min_std": 1e-4},
    PRESETS["agent"][1],
)
# "crowd": "agent" for crowds of pedestrians (ETH/UCY, docs/REAL_DATA.md): each agent attends
# its 8 nearest neighbours, the highway reads the agent's own history only (with the attended
# agents, the first of the highway's per-epoch fits had not finished after 5 minutes at
# ETH/UCY's size, ~3,000 training windows of ~16 pedestrians), and batches of 16 windows for 20
# epochs (~180 optimiser steps an epoch).
PRESETS["crowd"] = (
    {
        **PRESETS["agent"][0],
        "highway_attended": False,
        "attended_refit": False,
        "attended_fit": "mean",
        "highway_relation": False,
        "highway_head_groups": False,
        "neighbours": "knn",
        "neighbour_k": 8,
    },
    # the variance penalty linear beyond 10 m: its exp spiked crowd's loss to 3.6e15 on
    # ETH/UCY (the means, trained by displacement with the covariance detached, do not read it;
    # `agent` keeps the paper's exp, as its published runs, whose run keys name it, did)
    {**PRESETS["agent"][1], "batch_size": 16, "epochs": 20, "penalty_linear_from_m": 10.0},
)
# `crowd` with six trajectory modes trained by their likelihood (predictor.model.modes): the
# field scores best-of-K samples (minADE_K), which one Gaussian per step covers poorly
PRESETS["crowd_modes"] = ({**PRESETS["crowd"][0], "modes": 6}, PRESETS["crowd"][1])
DEFAULT_PRESET = "agent"  # the preset make_configs and tools/train.py use unless told
# the ModelConfig and TrainConfig fields some preset sets: where the presets differ
PRESET_FIELDS: tuple[tuple[str, ...], tuple[str, ...]] = (
    tuple(sorted({name for model, _ in PRESETS.values() for name in model})),
    tuple(sorted({name for _, train in PRESETS.values() for name in train})),
)


def make_configs(
    variant: str,
    model_overrides: dict[str, Any] | None = None,
    preset: str = DEFAULT_PRESET,
    **train_overrides: Any,
) -> tuple[ModelConfig, TrainConfig]:
    """Model and training configs for a variant and preset (`PRESETS`), with field overrides.

    Raises ValueError for an unknown variant or preset, an unknown field, or a nonzero beta2 on
    a variant that has no smoothness term.
    """
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; choose from {sorted(VARIANTS)}")
    if preset not in PRESETS:
        raise ValueError(f"unknown preset {preset!r}; choose from {sorted(PRESETS)}")
    spec = VARIANTS[variant]
    preset_model, preset_train = PRESETS[preset]
    if not spec.sequence_loss and preset_model.get("rollout_prior") == "anchored":
        # only the rollout loss trains F_roll: without it the anchored rollout would stay
        # constant velocity, so such a variant rolls out its one-step model (the paper's S-Attn)
        if (model_overrides or {}).get("rollout_prior") == "anchored":
            raise ValueError(f"variant {variant!r} has no rollout loss to train rollout_prior")
        # the highway sits in the anchored rollout's prior, so it goes with it
        defaults = {item.name: item.default for item in fields(ModelConfig)}
        # without the rollout loss nothing trains the highway or the trajectory modes either
        no_rollout = {name: defaults[name] for name in (*HIGHWAY_SWITCHES, "modes")}
        preset_model = {**preset_model, "rollout_prior": "previous", **no_rollout}
        model_overrides = {**(model_overrides or {}), **no_rollout}
    model_overrides = {**preset_model, **(model_overrides or {})}
    train_overrides = {**preset_train, **train_overrides}
    if "attention_mode" in model_overrides:
        raise ValueError("attention_mode is fixed by the variant")
    model = build_config(ModelConfig, {**model_overrides, "attention_mode": spec.attention_mode})
    if not spec.smooth and train_overrides.get("beta2", 0.0):
        raise ValueError(f"variant {variant!r} has no smoothness term; beta2 must be 0")
    if "sequence_loss" in train_overrides:
        raise ValueError("sequence_loss is fixed by the variant")
    train_values = {**train_overrides, "variant": variant, "sequence_loss": spec.sequence_loss}
    if not spec.smooth:
        train_values["beta2"] = 0.0
    return model, build_config(TrainConfig, train_values)
