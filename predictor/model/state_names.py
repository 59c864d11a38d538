"""The names a checkpoint gives the predictor's tensors: each tensor's name within its part,
without the part (`f_attn.weight`, not `attention.f_attn.weight`; `highway_weight`, not
`highway.highway_weight`), which are the names the predictor gave them when it was one module.

So checkpoints written before and after the predictor was composed of parts read both ways, the
readers that look tensors up by name (`fill_unclamped_range`, the run fingerprints of
tests/test_preset_weights.py) keep their names, and the parts can be regrouped without a
checkpoint format change. This module is the one place that maps the two namings:
`use_checkpoint_names` makes a model's `state_dict()` write the checkpoint names and its
`load_state_dict` read them (and the part-qualified ones), and report missing tensors by them.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from typing import Any

from torch import nn


def checkpoint_names(model: nn.Module, parts: Sequence[str]) -> dict[str, str]:
    """Part-qualified name -> checkpoint name of every tensor the named parts (children of
    `model`, or None where a configuration has no such part) hold; ValueError if two parts
    hold tensors of one name, or a checkpoint name starts like a part's."""
    names: dict[str, str] = {}
    for part in parts:
        module = getattr(model, part)
        if module is None:
            continue
        for name in module.state_dict(keep_vars=True):
            names[f"{part}.{name}"] = name
    flat = list(names.values())
    if len(set(flat)) != len(flat):
        raise ValueError(f"parts {list(parts)} hold tensors of the same name")
    if any(name.split(".")[0] in parts for name in flat):
        raise ValueError(f"a checkpoint name of parts {list(parts)} begins with a part's name")
    return names


def use_checkpoint_names(model: nn.Module, parts: Sequence[str]) -> None:
    """Make `model` (the root of what is saved) write and read the checkpoint names of the
    tensors of its `parts`; its own tensors and other children keep their names. ValueError
    if the parts' names would clash (`checkpoint_names`)."""
    parts = tuple(parts)
    checkpoint_names(model, parts)
    model.register_state_dict_post_hook(functools.partial(_write, parts=parts))
    model.register_load_state_dict_pre_hook(functools.partial(_read, parts=parts))
    model.register_load_state_dict_post_hook(functools.partial(_report, parts=parts))


def _write(module: nn.Module, state: dict, prefix: str, _metadata: dict, parts: tuple) -> None:
    """state_dict post-hook: part-qualified names to checkpoint names, in place and in order."""
    renamed = {prefix + old: prefix + new for old, new in checkpoint_names(module, parts).items()}
    items = list(state.items())
    state.clear()
    for key, value in items:
        state[renamed.get(key, key)] = value


def _read(module: nn.Module, state: dict, prefix: str, *_args: object, parts: tuple) -> None:
    """load_state_dict pre-hook: checkpoint names to part-qualified names, in place."""
    renamed = {prefix + new: prefix + old for old, new in checkpoint_names(module, parts).items()}
    for key in [key for key in state if key in renamed]:
        state[renamed[key]] = state.pop(key)


def _report(module: nn.Module, incompatible: Any, parts: tuple) -> None:
    """load_state_dict post-hook: the missing tensors (`incompatible.missing_keys`, torch's
    list, which its error message reads) named as the checkpoint names them."""
    names = checkpoint_names(module, parts)
    missing = incompatible.missing_keys
    missing[:] = [names.get(key, key) for key in missing]
