"""Stored configurations: configs as plain dicts (config.json, checkpoints) and back, the
fields added since stored configs became strict, and the key that identifies a run's config.

A stored config is read strictly (an unknown or missing field is an error) so that a saved model
never silently picks up a newer default; the only exceptions are the fields listed here with the
value that reproduces the behaviour from before they existed.
"""

from __future__ import annotations

from dataclasses import asdict, fields
from typing import Any

from predictor.config import ModelConfig, TrainConfig, build_config


def config_to_dict(config: ModelConfig | TrainConfig) -> dict[str, Any]:
    """Plain-type dict of a config (for JSON and weights-only checkpoints)."""
    return asdict(config)


# The fields every stored config has: those of the configs when stored configs became strict.
# Any field added since is added at a default that keeps the behaviour from before it (the
# paper's: every one was added as a switch that is off by default), so a stored config lacking
# it takes its default, except where a default changed later (`FORMER_VALUES`); lacking one of
# these is still an error. A new option is one field: nothing to list here.
ORIGINAL_MODEL_FIELDS = (
    *("embed_dim", "edge_hidden", "node_hidden", "attn_dim", "position_scale_m"),
    *("interaction_scale_m", "step_scale_m", "min_std_m", "init_std_m", "log_std_gain"),
    *("mean_prior", "attention_mode", "chunk_steps"),
)
ORIGINAL_TRAIN_FIELDS = (
    *("variant", "seed", "epochs", "batch_size", "lr", "beta1", "beta2", "tau"),
    *("sequence_loss", "grad_clip_norm", "eval_every", "threads"),
)
# added fields whose default is no longer the behaviour from before they existed
FORMER_VALUES: dict[str, Any] = {
    "bucket_batches": False,  # the batches of every split padded to its largest window
}


def _added(cls: type, original: tuple[str, ...]) -> dict[str, Any]:
    return {
        item.name: FORMER_VALUES.get(item.name, item.default)
        for item in fields(cls)
        if item.name not in original
    }


# field -> the value a stored config lacking it takes
ADDED_MODEL_FIELDS: dict[str, Any] = _added(ModelConfig, ORIGINAL_MODEL_FIELDS)
ADDED_TRAIN_FIELDS: dict[str, Any] = _added(TrainConfig, ORIGINAL_TRAIN_FIELDS)


# TrainConfig fields that change how a run is computed, not what: the same mathematics to float
# rounding (tested), so they are not part of a run's key, and a result row may hold runs of
# either value (the reproduction records each run's in its eval.json)
EXECUTION_FIELDS = ("compile_graph_step", "device")


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


# Fields removed after the results measured them worse or no better (docs/PREDICTOR.md, "Removed
# options"), each with the value that the code without it computes. A stored config holding that
# value reads as before; one that used the option is refused in one line that names the commit
# whose code still has it.
REMOVED_IN = "17f57bddf9c9"  # the last commit with the options below
REMOVED_MODEL_FIELDS: dict[str, Any] = {
    "acceleration_input": False,
    "refit_on_prior": False,
    "role_bias_by_group": False,
    "highway_role_groups": "",
}
REMOVED_TRAIN_FIELDS: dict[str, Any] = {
    "weight_decay": 0.0,
    "observed_jitter": 0,
    "one_step_weight": 1.0,
}


class RemovedOptionError(ValueError):
    """A stored config used an option this version no longer has."""


def without_removed(values: dict[str, Any], removed: dict[str, Any]) -> dict[str, Any]:
    """`values` less the removed fields that hold the value the current code computes;
    RemovedOptionError naming the first that holds another."""
    for name, neutral in removed.items():
        if name in values and values[name] != neutral:
            raise RemovedOptionError(
                f"trained with {name}={values[name]!r}, an option removed after the results "
                f"rejected it; its code is at commit {REMOVED_IN} (docs/PREDICTOR.md)"
            )
    return {name: value for name, value in values.items() if name not in removed}


def model_config_from_dict(values: dict[str, Any]) -> ModelConfig:
    """Rebuild a ModelConfig written by `config_to_dict`; unknown or missing keys are an error
    (a stored model must not silently pick up a newer default), except the fields of
    `ADDED_MODEL_FIELDS`, which older versions did not write, and those of
    `REMOVED_MODEL_FIELDS` at their neutral values (RemovedOptionError otherwise)."""
    values = without_removed(values, REMOVED_MODEL_FIELDS)
    return build_config(ModelConfig, {**ADDED_MODEL_FIELDS, **values}, complete=True)


def train_config_from_dict(values: dict[str, Any]) -> TrainConfig:
    """Rebuild a TrainConfig written by `config_to_dict`; unknown or missing keys are an error,
    except the fields of `ADDED_TRAIN_FIELDS` and of `REMOVED_TRAIN_FIELDS` (as above)."""
    values = without_removed(values, REMOVED_TRAIN_FIELDS)
    return build_config(TrainConfig, {**ADDED_TRAIN_FIELDS, **values}, complete=True)
