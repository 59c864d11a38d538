"""Stored configurations: configs as plain dicts (config.json, checkpoints) and back, the
fields added since stored configs became strict, and the key that identifies a run's config.

A stored config is read strictly (an unknown or missing field is an error) so that a saved model
never silently picks up a newer default; the only exceptions are the fields listed here with the
value that reproduces the behaviour from before they existed.
"""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

from predictor.config import ModelConfig, TrainConfig, build_config


def config_to_dict(config: ModelConfig | TrainConfig) -> dict[str, Any]:
    """Plain-type dict of a config (for JSON and weights-only checkpoints)."""
    return asdict(config)


# Fields added after stored configs became strict (checkpoints, run directories), each with the
# value that does what the code did before the field existed (the paper's behaviour: every one
# was added as a switch that is off by default). A stored config lacking one of them takes this
# value, never a current default that may differ; lacking any other field is still an error.
ADDED_MODEL_FIELDS: dict[str, Any] = {
    "frame": "scene",
    "standardise": False,
    "edge_velocity": False,
    "offset_scale": "step",
    "detach_covariance": False,
    "rollout_prior": "previous",
    "num_roles": 0,
    "role_input": True,
    "acceleration_input": False,
    "attention_gain": 1.0,
    "highway_steps": 0,
    "highway_horizon": 45,
    "highway_attended": False,
    "attended_refit": False,
    "attended_fit": "mean",
    "highway_relation": False,
    "highway_head_groups": False,
    "highway_zero_at_cv": False,
    "highway_min_std": 0.0,
    "role_attention_bias": False,
    "role_bias_by_group": False,
    "role_balanced_attention": False,
    "refit_on_prior": False,
    "highway_role_groups": "",
    "neighbours": "all",
    "neighbour_radius_m": 50.0,
    "neighbour_k": 16,
}
ADDED_TRAIN_FIELDS: dict[str, Any] = {
    "lr_schedule": "constant",
    "lr_final_ratio": 0.01,
    "rollout_feed": "sample",
    "mean_loss": "nll",
    "one_step_needs_previous": False,
    "weight_decay": 0.0,
    "observed_jitter": 0,
    "main_agent_weight": 1.0,
    "one_step_weight": 1.0,
    "bucket_batches": False,  # the batches of every split padded to its largest window
    "compile_graph_step": False,
}


# TrainConfig fields that change how a run is computed, not what: the same mathematics to float
# rounding (tested), so they are not part of a run's key, and a result row may hold runs of
# either value (the reproduction records each run's in its eval.json)
EXECUTION_FIELDS = ("compile_graph_step",)


def config_key(config: ModelConfig | TrainConfig) -> dict[str, Any]:
    """`config_to_dict` without the added fields (`ADDED_MODEL_FIELDS`, `ADDED_TRAIN_FIELDS`)
    that hold their former values and without `EXECUTION_FIELDS`: what identifies a run's
    configuration (cache keys), so a later version that adds a switch leaves the keys of the
    runs that do not use it unchanged."""
    added = ADDED_MODEL_FIELDS if isinstance(config, ModelConfig) else ADDED_TRAIN_FIELDS
    values = config_to_dict(config)
    return {
        k: v
        for k, v in values.items()
        if (k not in added or added[k] != v) and k not in EXECUTION_FIELDS
    }


def model_config_from_dict(values: dict[str, Any]) -> ModelConfig:
    """Rebuild a ModelConfig written by `config_to_dict`; unknown or missing keys are an error
    (a stored model must not silently pick up a newer default), except the fields of
    `ADDED_MODEL_FIELDS`, which older versions did not write."""
    return build_config(ModelConfig, {**ADDED_MODEL_FIELDS, **values}, complete=True)


def train_config_from_dict(values: dict[str, Any]) -> TrainConfig:
    """Rebuild a TrainConfig written by `config_to_dict`; unknown or missing keys are an error,
    except the fields of `ADDED_TRAIN_FIELDS`."""
    return build_config(TrainConfig, {**ADDED_TRAIN_FIELDS, **values}, complete=True)
