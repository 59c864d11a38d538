"""predictor.registry: one entry per predictor, from which the configs, the baselines, the
command-line choices and the report's labels, colours and comparisons derive."""

from __future__ import annotations

import re

import pytest
from conftest import run_tool
from matplotlib.colors import to_rgba

from pipeline.protocol import ALL_VARIANTS, TRAINED_VARIANTS
from pipeline.report.figures import COLORS as FIGURE_COLORS
from pipeline.report.records import LABELS as REPORT_LABELS
from pipeline.report.records import label
from pipeline.report.statistics import PAIRS as REPORT_PAIRS
from predictor.baselines import RidgeConfig
from predictor.presets import make_configs
from predictor.registry import BASELINES, BY_NAME, PREDICTORS, VARIANTS, Predictor


def test_names_labels_and_colours_are_unique_and_valid():
    names = [entry.name for entry in PREDICTORS]
    assert len(set(names)) == len(names) == len(BY_NAME)
    assert len({entry.label for entry in PREDICTORS}) == len(names)
    assert len({entry.color for entry in PREDICTORS}) == len(names)
    for entry in PREDICTORS:
        to_rgba(entry.color)  # a colour matplotlib draws
        assert entry.role in ("ours", "rival", "baseline", "oracle", "")
        assert (entry.variant is None) or entry.ridge is None
        assert all(other in BY_NAME for other in entry.compared_with)


@pytest.mark.parametrize("name", list(VARIANTS))
def test_a_trained_entry_fixes_its_configs(name):
    spec = VARIANTS[name]
    model, train = make_configs(name, preset="paper")
    assert model.attention_mode == spec.attention_mode
    assert train.sequence_loss == spec.sequence_loss
    assert (train.beta2 > 0) == spec.smooth


@pytest.mark.parametrize("name", [n for n in BASELINES if n != "const_vel"])
def test_every_ridge_entry_builds_its_regression(name):
    assert RidgeConfig.named(name) == RidgeConfig(**BY_NAME[name].ridge)


def test_the_report_and_the_protocol_read_the_registry():
    assert TRAINED_VARIANTS == tuple(VARIANTS)
    assert ALL_VARIANTS == tuple(
        e.name for e in PREDICTORS if e.trained or e.role in ("baseline", "oracle")
    )
    assert REPORT_LABELS == {e.name: e.label for e in PREDICTORS}
    assert FIGURE_COLORS == {e.name: e.color for e in PREDICTORS}
    assert label("ours@agent_zero_cv") == "Ours [agent_zero_cv]"
    assert REPORT_PAIRS[0] == ("ours", "s_attn") and ("correct", "average") in REPORT_PAIRS


def test_the_tools_offer_the_registry_names():
    train_help = run_tool("train.py", "--help").stdout
    listed = re.search(r"--variant \{([^}]*)\}", train_help).group(1).split(",")
    assert sorted(listed) == sorted(VARIANTS)
    evaluate_help = run_tool("evaluate.py", "--help").stdout
    offered = re.search(r"--baseline \{([^}]*)\}", evaluate_help).group(1).split(",")
    assert offered == list(BASELINES)


def test_an_entry_without_a_variant_or_ridge_is_constant_velocity():
    assert [e.name for e in PREDICTORS if e.variant is None and e.ridge is None] == ["const_vel"]
    assert not Predictor("x", "X", "#000000", "").trained
