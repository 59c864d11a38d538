"""The named presets train the same weights as when their fingerprints were stored
(tests/data/preset_weights.json, written by the code before the predictor's redesign): a short
run of each preset on a small Double Merge file, the same seed, compared parameter by parameter.

Each parameter is fingerprinted by its sum and its sum of squares in float64, compared with a
relative tolerance of 1e-4: another CPU's vector instructions may round differently (the runs
stored here were made on the development machine), while a changed computation moves the
fingerprints by orders of magnitude more (a weight initialised differently, a loss term
added, a highway fitted on other features)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from pipeline.generation import GenerateConfig, generate_dataset
from predictor.presets import make_configs
from predictor.training import train

STORED = Path(__file__).parent / "data" / "preset_weights.json"
PRESET_NAMES = ("paper", "agent", "agent_zero_cv", "crowd")
RTOL = 1e-4


def make_data(folder: Path) -> Path:
    """6 + 2 training/validation and 2 + 2 test Double Merge v1 scenes, seed 5."""
    config = GenerateConfig.for_scenario(
        "double_merge_v1", num_major=6, num_minor=2, num_test=2, seed=5
    )
    return generate_dataset(config, folder / "dm.h5", progress=False).path


def train_short(data: Path, preset: str, out: Path) -> Path:
    """Two epochs of the preset's `ours` variant, seed 3, batches of 2: its last.pt."""
    model_cfg, train_cfg = make_configs("ours", preset=preset, epochs=2, seed=3, batch_size=2)
    train(data, model_cfg, train_cfg, out, progress=False, preset=preset)
    return out / "last.pt"


def fingerprints_of_run(checkpoint: Path) -> dict[str, list[float]]:
    """Parameter and buffer name -> [size, sum, sum of squares] (float64) of a checkpoint's
    model's floating-point tensors."""
    state = torch.load(checkpoint, weights_only=True)["model_state"]
    return {
        name: [t.numel(), float(t.double().sum()), float(t.double().square().sum())]
        for name, t in sorted(state.items())
        if torch.is_tensor(t) and t.is_floating_point()
    }


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return make_data(tmp_path_factory.mktemp("preset_weights"))


@pytest.mark.parametrize("preset", PRESET_NAMES)
def test_preset_trains_the_stored_weights(data, preset, tmp_path):
    """Compared as sorted lists, so that a part that moved (a new parameter name) compares
    with its former self."""
    stored = sorted(json.loads(STORED.read_text())[preset].values())
    actual = sorted(fingerprints_of_run(train_short(data, preset, tmp_path / preset)).values())
    assert len(actual) == len(stored), "the model has other tensors than the stored run"
    for got, expected in zip(actual, stored):
        assert got == pytest.approx(expected, rel=RTOL, abs=1e-9)
