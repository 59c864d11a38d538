"""The predictor's settings as one tree, read from `predictor.config`: section `model`
(ModelConfig) and section `train` (TrainConfig), each field with its doc (the comment written
beside it in predictor/config.py), its default, its allowed values (`MODEL_RULES`,
`TRAIN_RULES`) and what it needs (`MODEL_NEEDS`).

The command line is built on it (tools/train.py: `--preset`, repeatable
`--set section.field=value`, `--show-config`, `--list-settings`), so a new option is one field
in predictor/config.py plus its use.
"""

from __future__ import annotations

import difflib
import inspect
import json
import re
from dataclasses import MISSING, dataclass, fields
from typing import Any

from predictor.config import (
    MODEL_NEEDS,
    MODEL_RULES,
    TRAIN_RULES,
    ModelConfig,
    TrainConfig,
)
from predictor.presets import DEFAULT_PRESET, PRESETS, make_configs
from predictor.stored_config import config_to_dict

SECTIONS: dict[str, type] = {"model": ModelConfig, "train": TrainConfig}
# settings that are not --set: each has a flag of its own or is fixed by the variant
NOT_SET = {
    "model.attention_mode": "fixed by --variant",
    "train.variant": "use --variant",
    "train.sequence_loss": "fixed by --variant",
    "train.seed": "use --seed",
    "train.epochs": "use --epochs",
    "train.device": "use --device",
}
_FIELD_LINE = re.compile(r"^    (\w+): [^=]+=[^#]*(?:#\s?(.*))?$")


@dataclass(frozen=True)
class Setting:
    """One field of the tree."""

    key: str  # section.field
    kind: type  # bool, int, float or str
    default: Any  # the dataclass default (the paper's value)
    doc: str  # the comment beside the field in predictor/config.py
    allowed: str  # the rule ("one of (...)", ">= 1", ...) or "" for any value of its kind
    needs: tuple[str, ...]  # what it needs when not at its default
    choices: tuple | None = None


def field_docs(cls: type) -> dict[str, str]:
    """Field name -> the comment lines written above it (after the last blank line or section
    rule) and beside it, joined, from the class's source."""
    docs: dict[str, str] = {}
    pending: list[str] = []
    for line in inspect.getsource(cls).splitlines():
        stripped = line.strip()
        if stripped.startswith("# ---") or not stripped:
            pending = []
        elif stripped.startswith("#") and line.startswith("    #"):
            pending.append(stripped.lstrip("#").strip())
        elif match := _FIELD_LINE.match(line):
            beside = [match.group(2)] if match.group(2) else []
            docs[match.group(1)] = " ".join(pending + beside).strip()
            pending = []
        else:
            pending = []
    return docs


def settings() -> dict[str, Setting]:
    """Every setting of the tree by key ("model.frame", "train.lr", ...), in field order."""
    rules = {"model": MODEL_RULES, "train": TRAIN_RULES}
    needs = {"model": MODEL_NEEDS, "train": {}}
    tree: dict[str, Setting] = {}
    for section, cls in SECTIONS.items():
        docs = field_docs(cls)
        for item in fields(cls):
            default = item.default if item.default is not MISSING else None
            rule = rules[section].get(item.name)
            tree[f"{section}.{item.name}"] = Setting(
                key=f"{section}.{item.name}",
                kind=type(default),
                default=default,
                doc=docs.get(item.name, ""),
                allowed=rule.describe() if rule else "",
                needs=tuple(text for text, _ in needs[section].get(item.name, ())),
                choices=rule.choices if rule else None,
            )
    return tree


def parse_value(setting: Setting, text: str) -> Any:
    """The typed value of `text` for `setting`; ValueError naming the key and what it takes."""
    if setting.kind is bool:
        lowered = text.strip().lower()
        if lowered in ("yes", "true", "1"):
            return True
        if lowered in ("no", "false", "0"):
            return False
        raise ValueError(f"{setting.key} takes yes or no, got {text!r}")
    if setting.choices is not None and text not in setting.choices:
        raise ValueError(f"{setting.key} must be one of {', '.join(setting.choices)}, got {text!r}")
    try:
        return setting.kind(text)
    except ValueError:
        kind = {int: "an integer", float: "a number"}.get(setting.kind, setting.kind.__name__)
        raise ValueError(f"{setting.key} takes {kind}, got {text!r}") from None


def parse_assignments(items: list[str]) -> dict[str, dict[str, Any]]:
    """`--set` items "section.field=value" -> {"model": {...}, "train": {...}}; ValueError
    (one line naming the key and the allowed keys or values) on a bad item."""
    tree = settings()
    values: dict[str, dict[str, Any]] = {section: {} for section in SECTIONS}
    for item in items:
        key, sep, text = item.partition("=")
        key = key.strip()
        if not sep:
            raise ValueError(f"--set takes section.field=value, got {item!r}")
        section, _, name = key.partition(".")
        if section not in SECTIONS:
            raise ValueError(
                f"unknown setting {key!r}: its section must be one of {', '.join(SECTIONS)}"
            )
        if key in NOT_SET:
            raise ValueError(f"{key} is not set with --set: {NOT_SET[key]}")
        if key not in tree:
            names = [k.partition(".")[2] for k in tree if k.startswith(section + ".")]
            names = [n for n in names if f"{section}.{n}" not in NOT_SET]
            close = difflib.get_close_matches(name, names, n=1)
            hint = f" (did you mean {section}.{close[0]}?)" if close else ""
            raise ValueError(
                f"unknown setting {key!r}{hint}; {section} settings: {', '.join(sorted(names))}"
            )
        values[section][name] = parse_value(tree[key], text)
    return values


def resolve(
    variant: str = "ours",
    preset: str = DEFAULT_PRESET,
    assignments: list[str] | None = None,
    **train_values: Any,
) -> tuple[ModelConfig, TrainConfig]:
    """The configs of a run: `preset`, then the variant, then `--set` assignments and
    `train_values` (seed, epochs, ...). ValueError in one line with the tree's key names."""
    values = parse_assignments(assignments or [])
    try:
        return make_configs(
            variant, values["model"], preset=preset, **{**values["train"], **train_values}
        )
    except ValueError as err:
        raise ValueError(tree_names(str(err))) from None


def tree_names(message: str) -> str:
    """A config error with the tree's key names (ModelConfig.x -> model.x)."""
    return message.replace("ModelConfig.", "model.").replace("TrainConfig.", "train.")


def show_config(model: ModelConfig, train: TrainConfig, preset: str | None) -> str:
    """The resolved configuration as a run stores it in config.json (without the data
    description, which training adds)."""
    return json.dumps(
        {"model": config_to_dict(model), "train": config_to_dict(train), "preset": preset},
        indent=2,
    )


def list_settings(preset: str = DEFAULT_PRESET) -> str:
    """Every setting, one block each: key, value under `preset` (and the default where it
    differs), allowed values, what it needs, and its doc."""
    preset_model, preset_train = PRESETS[preset]
    chosen = {
        **{f"model.{k}": v for k, v in preset_model.items()},
        **{f"train.{k}": v for k, v in preset_train.items()},
    }
    blocks = []
    for key, setting in settings().items():
        value = chosen.get(key, setting.default)
        head = f"{key} = {value!r}"
        if value != setting.default:
            head += f" (default {setting.default!r})"
        if key in NOT_SET:
            head += f" [{NOT_SET[key]}]"
        lines = [head]
        if setting.allowed:
            lines.append(f"    allowed: {setting.allowed}")
        if setting.needs:
            lines.append(f"    needs: {', '.join(setting.needs)}")
        lines.append(f"    {setting.doc}")
        blocks.append("\n".join(lines))
    return f"settings under preset {preset!r} (predictor/config.py):\n\n" + "\n".join(blocks)
