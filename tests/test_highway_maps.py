"""The highway part (predictor.model.highway_maps) on its own: built only with highway_steps,
its maps' count and kind (buffers, or a learnt attended map), its reading before and after a
fit, the roles it needs and the unbounded range of old checkpoints. The fits' results are
tested through the model in test_highway.py and test_attended_highway.py."""

from __future__ import annotations

import math

import pytest
import torch
from test_highway import ANCHORED, accelerating_scenes

from predictor.config import ModelConfig
from predictor.highway import CROSS_FIT_FOLDS
from predictor.model.highway_maps import Highway, build_highway
from predictor.model.pass_inputs import prepare_pass

torch.set_num_threads(1)

HIGHWAY = {**ANCHORED, "highway_steps": 3, "highway_horizon": 4}
REFIT = {**HIGHWAY, "highway_attended": True, "attended_refit": True}
OBSERVED = 6
ANCHOR_STD = torch.tensor([0.1, 0.05])


def pass_of(config: ModelConfig, batch: int = 8, roles: torch.Tensor | None = None):
    positions, valid = accelerating_scenes(batch=batch, steps=10, agents=3, seed=1)
    return prepare_pass(config, positions, valid, OBSERVED, None, roles)


def test_the_config_builds_a_highway_only_with_highway_steps():
    assert build_highway(ModelConfig(**ANCHORED)) is None
    assert isinstance(build_highway(ModelConfig(**HIGHWAY)), Highway)


@pytest.mark.parametrize(
    ("settings", "maps"),
    [
        ({**HIGHWAY}, 1),
        ({**HIGHWAY, "num_roles": 3}, 3),
        ({**REFIT, "num_roles": 3, "highway_relation": True}, 6),
        (
            {**REFIT, "num_roles": 3, "highway_relation": True}
            | {"attended_fit": "edge_relations", "highway_head_groups": True},
            18,
        ),
    ],
)
def test_maps_per_role_relation_and_attended_group(settings, maps):
    highway = Highway(ModelConfig(**settings))
    assert highway.num_maps == maps
    own = 4 * 3 - 3  # three velocities and their differences
    assert highway.highway_weight.shape == (maps, own, 4, 2)
    assert highway.highway_fold_weight.shape == (CROSS_FIT_FOLDS, maps, own, 4, 2)
    assert highway.highway_low.shape == highway.highway_high.shape == (maps, 4, 2)


def test_the_attended_map_is_learnt_unless_refitted():
    learnt = Highway(ModelConfig(**HIGHWAY, highway_attended=True))
    assert [name for name, _ in learnt.named_parameters()] == ["attended_weight"]
    assert not hasattr(learnt, "attended_fold_weight")
    refitted = Highway(ModelConfig(**REFIT))
    assert list(refitted.parameters()) == []
    assert refitted.attended_fold_weight.shape == (CROSS_FIT_FOLDS, 1, 2 * 3 + 2, 4, 2)
    assert not list(Highway(ModelConfig(**HIGHWAY)).parameters())


def test_unfitted_maps_change_nothing_and_fitted_ones_stay_in_their_range():
    config = ModelConfig(**REFIT)
    highway = Highway(config)
    steps = pass_of(config)
    theta = torch.full((8, 3, 2), 0.5)
    assert not highway(steps, theta, ANCHOR_STD).any()
    highway.fit(steps, None)
    assert highway.attended_std.ne(1.0).all()  # the edges' statistics, with the maps
    changes = highway(steps, theta, ANCHOR_STD)  # (B, N, horizon, 2) world axes
    assert changes.shape == (8, 3, 4, 2) and changes.abs().max() > 0
    reach = torch.maximum(-highway.highway_low, highway.highway_high).norm(dim=-1)  # (1, 4)
    assert (changes.norm(dim=-1) <= reach + 1e-6).all()  # a rotation keeps the length


def test_a_fit_without_maps_fits_the_edge_statistics_alone():
    config = ModelConfig(**REFIT)
    highway = Highway(config)
    highway.fit(pass_of(config), None, fit_maps=False)
    assert highway.attended_std.ne(1.0).all()
    assert not highway.highway_weight.any() and not highway.highway_high.any()


def test_a_refit_keeps_the_attended_maps_in_units_of_anchor_std():
    config = ModelConfig(**REFIT)
    highway = Highway(config)
    steps = pass_of(config)
    highway.fit(steps, None, fit_maps=False)
    theta = torch.full((8, 3, 2), 0.5)
    samples = [highway.samples(steps, theta)]
    highway.refit(samples, OBSERVED, ANCHOR_STD)
    halved = Highway(config)
    halved.load_state_dict(highway.state_dict())
    halved.refit(samples, OBSERVED, ANCHOR_STD / 2)
    torch.testing.assert_close(halved.attended_weight, 2 * highway.attended_weight)
    torch.testing.assert_close(
        halved(steps, theta, ANCHOR_STD / 2), highway(steps, theta, ANCHOR_STD)
    )


def test_maps_chosen_by_role_need_roles():
    config = ModelConfig(**HIGHWAY, num_roles=2)
    highway = Highway(config)
    with pytest.raises(ValueError, match="reads agent roles; fit_normalisation needs them"):
        highway.fit(pass_of(config, roles=torch.zeros(8, 3, dtype=torch.long)), None)
    with pytest.raises(ValueError, match="refit_attended needs them"):
        highway.require_roles(None, "refit_attended")


def test_a_checkpoint_without_a_range_gets_an_unbounded_one():
    highway = Highway(ModelConfig(**HIGHWAY))
    state = {"highway_weight": highway.highway_weight}
    filled = highway.fill_unclamped_range(state)
    assert filled["highway_high"].isinf().all() and (filled["highway_low"] == -math.inf).all()
    assert filled["highway_low"].shape == highway.highway_low.shape
    ranged = {**state, "highway_low": highway.highway_low, "highway_high": highway.highway_high}
    assert highway.fill_unclamped_range(ranged) is ranged
