"""predictor.settings, the tree the command line is built on: every config field is a setting
with its doc, default and rule; `--set` values are typed and checked in one line each; the
resolved configs equal those composed by hand; tools/train.py stays small."""

from __future__ import annotations

import re
from dataclasses import dataclass, fields
from pathlib import Path

import pytest
from conftest import REPO_ROOT, load_tool, run_tool

from predictor.config import ModelConfig, TrainConfig
from predictor.presets import PRESETS, make_configs
from predictor.settings import (
    NOT_SET,
    field_docs,
    list_settings,
    parse_assignments,
    resolve,
    settings,
)

REMOVED = (  # options the results rejected, removed from the product (docs/PREDICTOR.md)
    "acceleration_input",
    "one_step_weight",
    "weight_decay",
    "observed_jitter",
    "highway_role_groups",
    "role_bias_by_group",
    "refit_on_prior",
)


@dataclass
class Documented:
    a: int = 1  # beside a
    # above b,
    # on two lines
    b: float = 2.0
    # --- a section rule ends a comment block ---
    c: str = "x"
    # above d
    d: bool = False  # and beside it


def test_field_docs_are_the_comments_above_and_beside_each_field():
    assert field_docs(Documented) == {
        "a": "beside a",
        "b": "above b, on two lines",
        "c": "",
        "d": "above d and beside it",
    }


def test_every_config_field_is_a_documented_setting_with_its_default():
    tree = settings()
    expected = [f"model.{f.name}" for f in fields(ModelConfig)]
    expected += [f"train.{f.name}" for f in fields(TrainConfig)]
    assert list(tree) == expected
    for key, setting in tree.items():
        assert setting.doc, f"{key} has no comment in predictor/config.py"
        section, _, name = key.partition(".")
        owner = ModelConfig() if section == "model" else TrainConfig()
        assert setting.default == getattr(owner, name)
    assert tree["model.frame"].allowed == "one of ('scene', 'agent')"
    assert tree["model.standardise"].needs == ("frame='agent'",)
    assert tree["train.epochs"].allowed == ">= 1"


def test_assignments_are_typed_by_their_field():
    values = parse_assignments(
        [
            "model.standardise=yes",
            "model.neighbour_k=8",
            "model.attention_gain=2.5",
            "model.frame=agent",
            "train.bucket_batches=false",
            "train.lr = 1e-3".replace(" ", ""),
        ]
    )
    assert values == {
        "model": {
            "standardise": True,
            "neighbour_k": 8,
            "attention_gain": 2.5,
            "frame": "agent",
        },
        "train": {"bucket_batches": False, "lr": 1e-3},
    }


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("model.frame", "--set takes section.field=value, got 'model.frame'"),
        ("modle.frame=agent", "unknown setting 'modle.frame': its section must be one of"),
        ("model.fram=agent", "unknown setting 'model.fram' (did you mean model.frame?)"),
        ("model.frame=side", "model.frame must be one of scene, agent, got 'side'"),
        ("model.neighbour_k=2.5", "model.neighbour_k takes an integer, got '2.5'"),
        ("train.lr=fast", "train.lr takes a number, got 'fast'"),
        ("model.standardise=maybe", "model.standardise takes yes or no, got 'maybe'"),
        ("train.seed=3", "train.seed is not set with --set: use --seed"),
    ],
)
def test_a_bad_assignment_is_one_line_naming_the_key(item, message):
    with pytest.raises(ValueError) as err:
        parse_assignments([item])
    assert message in str(err.value) and "\n" not in str(err.value)


def test_unknown_key_lists_the_section_settings():
    with pytest.raises(ValueError) as err:
        parse_assignments(["train.learning_rate=1"])
    listed = str(err.value).split("train settings: ")[1].split(", ")
    assert "lr" in listed and "epochs" not in listed  # --epochs has its flag
    assert set(listed) == {f.name for f in fields(TrainConfig) if f"train.{f.name}" not in NOT_SET}


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_resolve_equals_the_preset_composed_by_hand(preset):
    by_tree = resolve("ours", preset, ["model.attn_dim=6", "train.lr=0.002"], seed=4)
    by_hand = make_configs("ours", {"attn_dim": 6}, preset=preset, lr=0.002, seed=4)
    assert by_tree == by_hand


def test_rule_errors_name_the_tree_key():
    with pytest.raises(ValueError, match=r"^model\.highway_min_std=0\.1 needs attended_refit$"):
        resolve("ours", "paper", ["model.highway_min_std=0.1"])


def test_list_settings_shows_the_chosen_preset_values():
    text = list_settings("crowd")
    assert "model.neighbours = 'knn' (default 'all')" in text
    assert "train.epochs = 20 (default 200) [use --epochs]" in text
    assert all(f"\n{key} = " in text for key in settings())


def test_train_help_has_at_most_twenty_options():
    parser_options = re.findall(r"^  (-[-\w]+)", run_tool("train.py", "--help").stdout, re.M)
    assert 10 <= len(parser_options) <= 20, parser_options


def test_show_config_prints_the_resolved_configuration():
    import json

    shown = run_tool("train.py", "--show-config", "--preset", "crowd", "--set", "train.lr=0.01")
    assert shown.returncode == 0, shown.stderr
    config = json.loads(shown.stdout)
    model, train = make_configs("ours", preset="crowd", lr=0.01)
    assert config["preset"] == "crowd" and config["train"]["lr"] == 0.01
    assert config["model"] == {f.name: getattr(model, f.name) for f in fields(ModelConfig)}
    assert config["train"] == {f.name: getattr(train, f.name) for f in fields(TrainConfig)}


def test_the_removed_options_are_gone_from_the_product():
    """Named only where stored runs that used them are recognised and refused."""
    product = [
        path
        for folder in ("carlo_lite", "scenarios", "pipeline", "predictor", "tools", "benchmarks")
        for path in (REPO_ROOT / folder).rglob("*.py")
        if path.name != "stored_config.py"
    ]
    assert product and not (REPO_ROOT / "benchmarks" / "experiments").exists()
    for path in product:
        text = path.read_text()
        for name in REMOVED:
            assert name not in text, f"{path.relative_to(REPO_ROOT)} names {name}"
    stored = (REPO_ROOT / "predictor" / "stored_config.py").read_text()
    assert all(f'"{name}"' in stored for name in REMOVED)
    help_text = run_tool("train.py", "--list-settings").stdout
    assert not any(name in help_text for name in REMOVED)


def test_train_tool_main_lists_settings_in_process(capsys):
    load_tool("train.py").main(["--list-settings", "--preset", "paper"])
    out = capsys.readouterr().out
    assert out.startswith("settings under preset 'paper'") and "model.frame = 'scene'" in out


def test_settings_module_reads_the_config_source():
    """The docs come from predictor/config.py's comments (one source of truth)."""
    source = Path(REPO_ROOT / "predictor" / "config.py").read_text()
    doc = settings()["model.edge_velocity"].doc
    assert doc.split(". ")[0] in " ".join(line.strip("# ") for line in source.splitlines())
