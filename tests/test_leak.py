"""No predictor reads the future: for every importer's output and every preset (and the
baselines), the forecasts (means, attention, sampled futures) are bit-identical when every
position and presence after the last observed step is replaced by noise. This is the trap
that cost Trajectron++, MID and AgentFormer their published ETH/UCY figures: velocities from
central differences read the next position (Trajectron++ issues 26, 40 and 53)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import torch
from test_import_data import make_pairs_scene, write_interaction
from test_import_interaction_recordings import write_location

from predictor.config import resolve_roles
from predictor.forecasting import fit_baseline, forecast_model
from predictor.model import SmoothAttentionPredictor
from predictor.presets import PRESETS, make_configs
from trajectory_data.importers.eth_ucy import EthUcyConfig, import_eth_ucy
from trajectory_data.importers.interaction import InteractionConfig, import_interaction
from trajectory_data.torch_dataset import TrajectoryDataset

IMPORTERS = ("eth_ucy", "interaction_cases", "interaction_recording")


@pytest.fixture(scope="module")
def imported(tmp_path_factory) -> dict[str, Path]:
    """One small file from each importer."""
    root = tmp_path_factory.mktemp("leak")
    make_pairs_scene(root / "eth_raw", "zara1")
    write_interaction(root / "cases_raw")
    write_location(root / "recording_raw")
    eth = import_eth_ucy(root / "eth_raw", root / "eth", EthUcyConfig(scenes=("zara1",)), False)
    config = InteractionConfig()
    return {
        "eth_ucy": Path(eth[0]),
        "interaction_cases": import_interaction([root / "cases_raw"], root / "c.h5", config, False),
        "interaction_recording": import_interaction(
            [root / "recording_raw"], root / "r.h5", config, False
        ),
    }


def future_replaced(batch, num_observed: int, seed: int = 0):
    """`batch` with every position and presence from step num_observed on drawn at random."""
    rng = np.random.default_rng(seed)
    states, valid = batch.states.clone(), batch.valid.clone()
    future = states[:, num_observed:]
    states[:, num_observed:] = torch.from_numpy(
        rng.normal(0.0, 50.0, future.shape).astype(np.float32)
    )
    valid[:, num_observed:] = torch.from_numpy(rng.random(valid[:, num_observed:].shape) < 0.5)
    return replace(batch, states=states, valid=valid)


def model_for(preset: str, dataset: TrajectoryDataset, train: TrajectoryDataset):
    model_config, _ = make_configs("ours", preset=preset)
    model = SmoothAttentionPredictor(resolve_roles(model_config, dataset.meta.role_names))
    if model_config.frame == "agent":
        fit = train.all()
        model.fit_normalisation(fit.positions, fit.valid, dataset.meta.num_observed, fit.roles)
    return model


@pytest.mark.parametrize("importer", IMPORTERS)
@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_forecasts_never_read_after_the_last_observed_step(imported, importer, preset):
    torch.manual_seed(0)
    test = TrajectoryDataset(imported[importer], "test")
    train = TrajectoryDataset(imported[importer], "train")
    num_observed = test.meta.num_observed
    model = model_for(preset, test, train)
    batch = test.all()
    changed = future_replaced(batch, num_observed)
    assert not torch.equal(batch.positions[:, num_observed:], changed.positions[:, num_observed:])
    first = forecast_model(model, batch, num_observed, num_samples=3, seed=1, nll=False)
    second = forecast_model(model, changed, num_observed, num_samples=3, seed=1, nll=False)
    np.testing.assert_array_equal(first.pred_mean, second.pred_mean)
    np.testing.assert_array_equal(first.attention, second.attention)
    np.testing.assert_array_equal(first.samples, second.samples)
    rollout = forecast_model(model, batch, num_observed, 3, 1, nll=False, method="rollout")
    rollout_changed = forecast_model(
        model, changed, num_observed, 3, 1, nll=False, method="rollout"
    )
    np.testing.assert_array_equal(rollout.samples, rollout_changed.samples)


@pytest.mark.parametrize("importer", IMPORTERS)
@pytest.mark.parametrize("baseline", ["const_vel", "ridge"])
def test_baselines_never_read_after_the_last_observed_step(imported, importer, baseline):
    test = TrajectoryDataset(imported[importer], "test")
    train = TrajectoryDataset(imported[importer], "train")
    num_observed = test.meta.num_observed
    fitted = fit_baseline(baseline, test.meta, train.data)
    data = test.data
    batch = future_replaced(test.all(), num_observed)
    changed = replace(data, states=batch.states.numpy(), valid=batch.valid.numpy())
    np.testing.assert_array_equal(fitted.predict(data), fitted.predict(changed))
    samples, _ = fitted.distribution(data, 4, 0)
    changed_samples, _ = fitted.distribution(changed, 4, 0)
    np.testing.assert_array_equal(samples, changed_samples)
