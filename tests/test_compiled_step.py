"""The compiled graph step (`TrainConfig.compile_graph_step`): the same losses and gradients as
the eager model on the same batch, eager outside training, deterministic training, no part in a
run's key, and a clear refusal without a compiler. The first compilation takes minutes (4-6 on
this 2-core machine with a cold inductor cache); the later tests reuse what it compiled."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from test_training import TINY_MODEL, write_braking_dataset

from predictor.compiled_step import compile_graph_step, compiler_missing
from predictor.model import SmoothAttentionPredictor
from predictor.presets import make_configs
from predictor.run_files import RunError
from predictor.stored_config import config_key
from predictor.training import train, train_step
from trajectory_data.torch_dataset import TrajectoryDataset, collate_batch

pytestmark = pytest.mark.skipif(
    compiler_missing() is not None, reason="torch.compile's CPU kernels need a C++ compiler"
)
OBSERVED = 5  # write_braking_dataset's num_observed


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    path = write_braking_dataset(tmp_path_factory.mktemp("compiled") / "braking.h5")
    dataset = TrajectoryDataset(path, "train")
    return collate_batch([dataset[i] for i in range(len(dataset))])


def twin_models():
    """Two equal models (same seed), the second with a compiled graph step."""
    model_cfg, train_cfg = make_configs("ours", TINY_MODEL, preset="paper")
    models = []
    for _ in range(2):
        torch.manual_seed(0)
        models.append(SmoothAttentionPredictor(model_cfg))
    compile_graph_step(models[1])
    return models, train_cfg


def test_compiled_step_has_the_eager_losses_and_gradients(batch):
    (eager, compiled), train_cfg = twin_models()
    # outside training the compiled model runs its eager graph step: bit for bit the same
    compiled.eval()
    eager.eval()
    with torch.no_grad():
        a, b = (
            model(batch.positions, batch.valid, OBSERVED, batch.attention, sample=False)
            for model in (eager, compiled)
        )
    assert torch.equal(a.one_step.mean, b.one_step.mean)
    assert torch.equal(a.attention, b.attention)
    eager.train()
    compiled.train()
    for step in range(2):  # the first step compiles; the second reuses it
        terms = []
        for model in (eager, compiled):
            optimizer = torch.optim.Adam(model.parameters(), lr=train_cfg.lr)
            torch.manual_seed(step)  # the same rollout samples
            terms.append(train_step(model, optimizer, batch, OBSERVED, train_cfg))
        for name, value in terms[0].items():
            assert terms[1][name] == pytest.approx(value, rel=1e-4, abs=1e-6), name
        for (name, p), q in zip(eager.named_parameters(), compiled.parameters(), strict=True):
            assert p.grad is not None and q.grad is not None, name
            scale = p.grad.abs().max().item()
            assert (p.grad - q.grad).abs().max().item() <= 1e-4 * scale + 1e-7, name
            with torch.no_grad():  # keep the twins on the same weights for the next step
                q.copy_(p)


def test_each_compiled_model_starts_from_an_empty_dynamo_cache(batch):
    """Models trained one after another in a process (a reproduction worker) share the graph
    step's code object; its cache entries must not pile up towards Dynamo's recompile limit (8).
    Without the reset, Ours then Ours-Average here hold 4 and then 8 entries."""
    from torch._dynamo.eval_frame import _debug_get_cache_entry_list

    code = SmoothAttentionPredictor._run.__code__
    counts = []
    for variant in ("ours", "average"):  # different graphs: each variant compiles its own
        model_cfg, train_cfg = make_configs(variant, TINY_MODEL, preset="paper")
        torch.manual_seed(0)
        model = SmoothAttentionPredictor(model_cfg)
        compile_graph_step(model)
        model.train()
        optimizer = torch.optim.Adam(model.parameters(), lr=train_cfg.lr)
        train_step(model, optimizer, batch, OBSERVED, train_cfg)
        counts.append(len(_debug_get_cache_entry_list(code)))
    assert counts[0] >= 1  # the first model's step was compiled
    assert counts[1] == counts[0]  # the second's replaced the first's instead of adding to them


def test_every_batch_size_of_a_run_is_compiled_past_dynamos_default_limit(
    tmp_path: Path, monkeypatch
):
    """Three batch sizes (a small training set's full and last batches) of four shapes each: 12
    compiled entries of the graph step, more than Dynamo's default limit of 8, none left eager.
    The entries and their limit are Dynamo's, whatever backend turns a traced graph into
    kernels, so this test traces with the "eager" backend (seconds; inductor's C++ kernels for
    12 shapes took 4 minutes here); the tests above compile with inductor."""
    from functools import partial

    from torch._dynamo.eval_frame import _debug_get_cache_entry_list

    monkeypatch.setattr(torch, "compile", partial(torch.compile, backend="eager"))

    dataset = TrajectoryDataset(write_braking_dataset(tmp_path / "braking.h5"), "train")
    model_cfg, train_cfg = make_configs("ours", TINY_MODEL, preset="paper")
    torch.manual_seed(0)
    model = SmoothAttentionPredictor(model_cfg)
    compile_graph_step(model)
    model.train()
    optimizer = torch.optim.Adam(model.parameters(), lr=train_cfg.lr)
    counts = []
    for size in (1, 2, 3):
        batch = collate_batch([dataset[i] for i in range(size)])
        train_step(model, optimizer, batch, OBSERVED, train_cfg)
        counts.append(len(_debug_get_cache_entry_list(SmoothAttentionPredictor._run.__code__)))
    assert counts == [counts[0], 2 * counts[0], 3 * counts[0]]
    assert counts[-1] > 8


def test_a_compiled_run_trains_deterministically_and_its_checkpoint_loads_eager(tmp_path: Path):
    path = write_braking_dataset(tmp_path / "braking.h5")
    model_cfg, train_cfg = make_configs(
        "ours", TINY_MODEL, epochs=1, compile_graph_step=True, preset="paper"
    )
    for name in ("run", "again"):  # the same seed and arguments: the same training
        result = train(path, model_cfg, train_cfg, tmp_path / name, progress=False)
        assert result.epochs == 1
    stored, again = (
        torch.load(tmp_path / name / "last.pt", weights_only=True) for name in ("run", "again")
    )
    assert stored["train_config"]["compile_graph_step"] is True
    assert stored["model_state"].keys() == again["model_state"].keys()
    for name, weights in stored["model_state"].items():
        assert torch.equal(weights, again["model_state"][name]), name
    model = SmoothAttentionPredictor(model_cfg)
    model.load_state_dict(model.fill_unclamped_range(stored["model_state"]))


def test_no_compiler_is_refused_before_anything_is_written(tmp_path: Path, monkeypatch):
    path = write_braking_dataset(tmp_path / "braking.h5")
    monkeypatch.setenv("CXX", "no-such-compiler-here")
    model_cfg, train_cfg = make_configs(
        "ours", TINY_MODEL, epochs=1, compile_graph_step=True, preset="paper"
    )
    with pytest.raises(RunError, match="needs a C.. compiler"):
        train(path, model_cfg, train_cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_the_switch_is_not_part_of_a_run_key():
    """How the graph step is computed, not what: a compiled run has the eager run's key."""
    _, eager = make_configs("ours", TINY_MODEL, preset="paper")
    _, compiled = make_configs("ours", TINY_MODEL, compile_graph_step=True, preset="paper")
    assert "compile_graph_step" not in config_key(eager)
    assert config_key(compiled) == config_key(eager)
