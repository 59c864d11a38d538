"""Training: the loss falls on a tiny set, runs are reproducible, resume is exact."""

from __future__ import annotations

import errno
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from predictor.model import SmoothAttentionPredictor
from predictor.presets import make_configs
from predictor.run_files import RunError
from predictor.run_state import resume_configs
from predictor.training import train, train_step
from trajectory_data.format import DatasetMeta, TrajectorySet, write_dataset
from trajectory_data.torch_dataset import TrajectoryDataset, collate_batch

torch.set_num_threads(1)

TINY_MODEL = {"embed_dim": 8, "edge_hidden": 8, "node_hidden": 12, "attn_dim": 4}


def braking_scenes(n: int, steps: int, agents: int, num_observed: int, seed: int) -> TrajectorySet:
    """Agents at constant speed in lanes; the leader (agent 0) brakes at a random step and the
    follower (agent 1, same lane, behind) brakes two steps later. Agent 1 attends agent 0 from
    the leader's braking on (the interaction period). Case 1 scenes brake later than case 0."""
    rng = np.random.default_rng(seed)
    dt = 0.2
    case = (np.arange(n) % 2).astype(np.int8)
    speed = np.repeat(rng.uniform(8.0, 12.0, (n, 1, agents)), steps, axis=1)  # (n, T, N)
    brake = num_observed - 2 + rng.integers(0, 4, n) + 3 * case  # (n,) leader's braking step
    t = np.arange(steps)[None, :]  # (1, T)
    for agent, delay in ((0, 0), (1, 2)):
        slow = np.clip(t - (brake[:, None] + delay), 0, None)  # (n, T) steps since braking
        speed[:, :, agent] = np.maximum(speed[:, :1, 0] - 1.5 * slow, 2.0)
    x = np.cumsum(speed * dt, axis=1) + rng.uniform(0, 30, (n, 1, agents))  # (n, T, N)
    x[:, :, 1] = x[:, :, 0] - rng.uniform(8, 12, (n, 1))  # follower behind the leader
    y = np.broadcast_to(3.5 * (np.arange(agents) // 2 + (np.arange(agents) > 1)), x.shape)
    states = np.stack([x, y, np.zeros_like(x), speed], -1).astype(np.float32)  # (n, T, N, 4)
    valid = np.ones((n, steps, agents), dtype=bool)
    if agents > 3:
        valid[:, : num_observed // 2, agents - 1] = False  # a distractor enters late
        states[~valid] = 0.0
    interaction = t >= brake[:, None]  # (n, T)
    attention = np.full((n, steps, agents), -1, dtype=np.int16)
    attention[:, :, 1] = np.where(interaction, 0, -1)
    roles = np.full((n, agents), 2, dtype=np.int8)
    roles[:, :2] = [0, 1]
    return TrajectorySet(
        states=states,
        actions=np.zeros((n, steps, agents, 2), np.float32),
        valid=valid,
        attention=attention,
        interaction=interaction,
        case=case,
        seed=np.arange(n, dtype=np.int64) + 1000 * seed,
        roles=roles,
    )


def write_braking_dataset(
    path: Path, counts=(8, 4, 4), steps: int = 12, agents: int = 4, num_observed: int = 5
) -> Path:
    """A small dataset file of `braking_scenes` (train, val, test)."""
    meta = DatasetMeta(
        scenario="braking_test",
        dt=0.2,
        num_observed=num_observed,
        num_predicted=steps - num_observed,
        case_names=("early", "late"),
        major_case="early",
        role_names=("leader", "follower", "distractor"),
        config={"made_by": "tests"},
    )
    splits = {
        name: braking_scenes(count, steps, agents, num_observed, seed=k)
        for k, (name, count) in enumerate(zip(("train", "val", "test"), counts, strict=True))
    }
    write_dataset(path, meta, splits)
    return path


@pytest.fixture
def braking_file(tmp_path: Path) -> Path:
    return write_braking_dataset(tmp_path / "braking.h5")


def test_loss_falls_on_a_tiny_set(braking_file: Path):
    dataset = TrajectoryDataset(braking_file, "train")
    batch = collate_batch([dataset[i] for i in range(len(dataset))])
    model_cfg, train_cfg = make_configs("ours", TINY_MODEL, lr=1e-2, preset="paper")
    torch.manual_seed(0)
    model = SmoothAttentionPredictor(model_cfg)
    optimizer = torch.optim.Adam(model.parameters(), lr=train_cfg.lr)
    losses = [train_step(model, optimizer, batch, 5, train_cfg)["loss"] for _ in range(40)]
    assert all(np.isfinite(losses))
    # the untrained model extrapolates constant velocity with 0.1 m stds, so braking costs a lot
    assert losses[0] > 50 and np.mean(losses[-5:]) < 0.25 * losses[0], losses


def tiny_configs(variant: str = "ours", epochs: int = 3, seed: int = 0):
    return make_configs(
        variant, TINY_MODEL, epochs=epochs, batch_size=3, seed=seed, lr=3e-3, preset="paper"
    )


def weights(run: Path, name: str = "last.pt") -> dict:
    return torch.load(run / name, weights_only=True)["model_state"]


def assert_same_weights(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for key in a:
        assert torch.equal(a[key], b[key]), key


def test_no_silent_phase_in_training(braking_file: Path, tmp_path: Path, capsys):
    """What takes seconds before and between the epoch bar's updates says so on stderr: building
    the model and optimiser (a line), the highway refit and the validation (the bar's note)."""
    model_cfg, train_cfg = make_configs(
        "ours", TINY_MODEL, preset="agent", epochs=1, batch_size=3, seed=0
    )
    train(braking_file, model_cfg, train_cfg, tmp_path / "run", progress=True)
    err = capsys.readouterr().err
    assert "train ours: building the model and optimiser on 8 training scenes\n" in err
    assert "epoch 1: refitting the highway" in err and "epoch 1: validating" in err


def test_same_seed_same_run_and_files(braking_file: Path, tmp_path: Path):
    model_cfg, train_cfg = tiny_configs(epochs=2)
    first = train(braking_file, model_cfg, train_cfg, tmp_path / "a", progress=False)
    train(braking_file, model_cfg, train_cfg, tmp_path / "b", progress=False)
    assert_same_weights(weights(tmp_path / "a"), weights(tmp_path / "b"))
    other_cfg = tiny_configs(epochs=2, seed=1)
    train(braking_file, other_cfg[0], other_cfg[1], tmp_path / "c", progress=False)
    assert not torch.equal(
        weights(tmp_path / "a")["f_pred.weight"], weights(tmp_path / "c")["f_pred.weight"]
    )
    assert first.epochs == 2 and first.best_epoch in (1, 2) and first.best_score > 0
    records = [
        json.loads(line) for line in (tmp_path / "a/metrics.jsonl").read_text().split("\n") if line
    ]
    assert [r["epoch"] for r in records] == [1, 2]
    assert (
        records[-1]["val"]["ade_main"] == pytest.approx(first.best_score) or not records[-1]["best"]
    )
    config = json.loads((tmp_path / "a/config.json").read_text())
    assert config["train"]["variant"] == "ours" and config["model"]["edge_hidden"] == 8
    assert set(weights(tmp_path / "a", "best.pt")) == set(weights(tmp_path / "a"))


REFIT_AGENT = {
    **TINY_MODEL,
    "highway_attended": True,
    "attended_refit": True,
    "highway_relation": True,
}


@pytest.mark.parametrize(
    "refit",
    [
        None,
        REFIT_AGENT,
        {
            **REFIT_AGENT,
            "role_attention_bias": True,
            "attended_fit": "edges",
            "highway_head_groups": False,
        },
        {**REFIT_AGENT, "attended_fit": "edge_relations"},
    ],
    ids=["paper", "agent_refit", "agent_role_bias_edges", "agent_edge_relations"],
)
def test_resume_after_interruption_equals_uninterrupted(
    braking_file: Path, tmp_path: Path, refit: dict | None
):
    model_cfg, train_cfg = tiny_configs(epochs=3)
    if refit:  # the highway refitted at every epoch start (ModelConfig.attended_refit)
        model_cfg, train_cfg = make_configs(
            "ours", refit, preset="agent", epochs=3, batch_size=3, seed=0, lr=3e-3
        )
    train(braking_file, model_cfg, train_cfg, tmp_path / "full", progress=False)

    def interrupt(step: int) -> None:
        if step == 4:  # inside epoch 2 (3 steps per epoch of 8 scenes in batches of 3)
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        train(
            braking_file,
            model_cfg,
            train_cfg,
            tmp_path / "cut",
            progress=False,
            step_callback=interrupt,
        )
    assert torch.load(tmp_path / "cut/last.pt", weights_only=True)["epoch"] == 1
    result = train(
        braking_file, model_cfg, train_cfg, tmp_path / "cut", resume=True, progress=False
    )
    assert result.epochs == 3
    assert_same_weights(weights(tmp_path / "full"), weights(tmp_path / "cut"))
    if refit:  # the refit ran: fitted maps in the checkpoint
        assert weights(tmp_path / "full")["attended_weight"].abs().sum() > 0
    assert_same_weights(weights(tmp_path / "full", "best.pt"), weights(tmp_path / "cut", "best.pt"))

    def losses(run: str) -> list:
        lines = (tmp_path / run / "metrics.jsonl").read_text().splitlines()
        return [(r["epoch"], r["train"], r["val"]) for r in map(json.loads, lines)]

    assert losses("full") == losses("cut")


def test_run_directory_rules(braking_file: Path, tmp_path: Path):
    model_cfg, train_cfg = tiny_configs(epochs=1)
    run = tmp_path / "run"
    train(braking_file, model_cfg, train_cfg, run, progress=False)
    with pytest.raises(RunError, match="not empty"):
        train(braking_file, model_cfg, train_cfg, run, progress=False)
    train(braking_file, model_cfg, train_cfg, run, overwrite=True, progress=False)
    with pytest.raises(RunError, match="nothing to resume: .* does not exist"):
        train(braking_file, model_cfg, train_cfg, tmp_path / "new", resume=True, progress=False)
    (tmp_path / "empty").mkdir()
    with pytest.raises(RunError, match="nothing to resume in .*empty: it has no last.pt"):
        train(braking_file, model_cfg, train_cfg, tmp_path / "empty", resume=True, progress=False)
    changed = make_configs(
        "ours", TINY_MODEL, epochs=1, batch_size=3, seed=0, lr=1e-2, preset="paper"
    )
    with pytest.raises(RunError, match="lr"):
        train(braking_file, changed[0], changed[1], run, resume=True, progress=False)


def test_zero_epochs_is_refused():
    with pytest.raises(ValueError, match="TrainConfig.epochs must be >= 1, got 0"):
        tiny_configs(epochs=0)


@pytest.mark.parametrize("value", [math.inf, -math.inf, math.nan])
def test_non_finite_settings_are_refused_before_training(value):
    with pytest.raises(ValueError, match=r"TrainConfig.lr must be finite"):
        make_configs("ours", TINY_MODEL, lr=value, preset="paper")
    with pytest.raises(ValueError, match=r"ModelConfig.attention_gain must be finite"):
        make_configs("ours", {**TINY_MODEL, "attention_gain": value}, preset="paper")


def test_seeds_outside_int64_are_refused():
    with pytest.raises(
        ValueError, match=r"TrainConfig.seed must be in \[0, 9223372036854775807\], got -1"
    ):
        tiny_configs(seed=-1)
    with pytest.raises(ValueError, match="TrainConfig.seed must be in"):
        tiny_configs(seed=2**63)
    assert tiny_configs(seed=2**63 - 1)[1].seed == 2**63 - 1


def test_resume_configs_apply_only_the_allowed_changes(braking_file: Path, tmp_path: Path):
    model_cfg, train_cfg = tiny_configs(epochs=1)
    run = tmp_path / "run"
    train(braking_file, model_cfg, train_cfg, run, progress=False)
    assert resume_configs(run) == (model_cfg, train_cfg)
    same = {"lr": train_cfg.lr, "embed_dim": 8, "variant": "ours", "seed": 0}
    resumed_model, resumed_train = resume_configs(run, {"epochs": 4, "eval_every": 2, **same})
    assert resumed_model == model_cfg
    assert (resumed_train.epochs, resumed_train.eval_every, resumed_train.lr) == (4, 2, 3e-3)
    with pytest.raises(RunError, match="lr is 0.003 there, 0.1 asked .only epochs, threads, eval"):
        resume_configs(run, {"lr": 0.1})
    with pytest.raises(RunError, match="embed_dim is 8 there, 16 asked"):
        resume_configs(run, {"embed_dim": 16})
    with pytest.raises(RunError, match="unknown setting 'colour'"):
        resume_configs(run, {"colour": 1})
    with pytest.raises(ValueError, match="epochs must be >= 1"):
        resume_configs(run, {"epochs": 0})
    with pytest.raises(RunError, match="nothing to resume"):
        resume_configs(tmp_path / "absent", {})


def _interrupt_first_step(step: int) -> None:
    raise KeyboardInterrupt


def _train_interrupted_at_first_step(data: Path, configs: tuple, run: Path, **options) -> None:
    """Train into `run`, interrupted (Ctrl-C) before the first optimiser step."""
    with pytest.raises(KeyboardInterrupt):
        train(data, *configs, run, progress=False, step_callback=_interrupt_first_step, **options)


def test_interrupted_start_leaves_nothing(braking_file: Path, tmp_path: Path):
    """Interrupted before the first checkpoint: the files and directories the run created are
    removed, a directory that existed before is kept (empty), and a plain re-run works."""
    model_cfg, train_cfg = tiny_configs(epochs=1)
    nested = tmp_path / "a" / "b" / "run"
    _train_interrupted_at_first_step(braking_file, (model_cfg, train_cfg), nested)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["braking.h5"]
    existing = tmp_path / "existing"
    existing.mkdir()
    _train_interrupted_at_first_step(braking_file, (model_cfg, train_cfg), existing)
    assert existing.is_dir() and not list(existing.iterdir())
    assert train(braking_file, model_cfg, train_cfg, existing, progress=False).epochs == 1


def test_overwrite_keeps_the_old_run_until_the_new_one_has_a_checkpoint(
    braking_file: Path, tmp_path: Path
):
    model_cfg, train_cfg = tiny_configs(epochs=1)
    run = tmp_path / "run"
    train(braking_file, model_cfg, train_cfg, run, progress=False)
    (run / "eval.json").write_text("{}")
    (run / "notes.txt").write_text("the user's")
    old = {p.name: p.read_bytes() for p in run.iterdir()}
    # fails before its first checkpoint
    _train_interrupted_at_first_step(braking_file, (model_cfg, train_cfg), run, overwrite=True)
    assert {p.name: p.read_bytes() for p in run.iterdir()} == old  # put back, byte for byte
    other_cfg = tiny_configs(epochs=1, seed=1)
    train(braking_file, *other_cfg, run, overwrite=True, progress=False)
    names = sorted(p.name for p in run.iterdir())
    assert names == ["best.pt", "config.json", "last.pt", "metrics.jsonl", "notes.txt"]
    assert (run / "last.pt").read_bytes() != old["last.pt"]  # the new run, seed 1


def test_an_overwrite_killed_before_its_checkpoint_loses_nothing_on_the_next_try(
    braking_file: Path, tmp_path: Path
):
    """A SIGKILL runs no cleanup: the old run stays set aside as .replaced-* beside the killed
    attempt's files. Resuming says so; the next overwrite keeps the set-aside run, not the
    killed attempt's files, and puts it back if it fails too."""
    from predictor.run_files import claim_out_dir

    model_cfg, train_cfg = tiny_configs(epochs=1)
    run = tmp_path / "run"
    train(braking_file, model_cfg, train_cfg, run, progress=False)
    old = {p.name: p.read_bytes() for p in run.iterdir()}
    claim_out_dir(run, overwrite=True)  # the killed attempt: set aside, never committed
    (run / "config.json").write_text("{}")
    (run / "metrics.jsonl").write_text("")
    with pytest.raises(RunError, match=r"interrupted before its first checkpoint .*\.replaced-"):
        train(braking_file, model_cfg, train_cfg, run, resume=True, progress=False)
    _train_interrupted_at_first_step(braking_file, (model_cfg, train_cfg), run, overwrite=True)
    assert {p.name: p.read_bytes() for p in run.iterdir()} == old
    train(braking_file, model_cfg, train_cfg, run, overwrite=True, progress=False)
    assert sorted(p.name for p in run.iterdir()) == sorted(old)


def test_resume_from_a_checkpoint_without_its_state_is_one_clear_error(
    braking_file: Path, tmp_path: Path
):
    from predictor.checkpoints import CheckpointError

    model_cfg, train_cfg = tiny_configs(epochs=1)
    run = tmp_path / "run"
    train(braking_file, model_cfg, train_cfg, run, progress=False)
    checkpoint = torch.load(run / "last.pt", weights_only=True)
    del checkpoint["optimizer_state"]
    torch.save(checkpoint, run / "last.pt")
    more = tiny_configs(epochs=2)
    with pytest.raises(CheckpointError, match=r"last.pt: cannot resume from it \('optimizer"):
        train(braking_file, *more, run, resume=True, progress=False)


def test_bad_data_touches_no_directory(tmp_path: Path):
    data = write_braking_dataset(tmp_path / "no_train.h5", counts=(0, 2, 2))
    model_cfg, train_cfg = tiny_configs(epochs=1)
    with pytest.raises(RunError, match="the train split is empty"):
        train(data, model_cfg, train_cfg, tmp_path / "run", progress=False)
    assert not (tmp_path / "run").exists()


def test_unwritable_run_directory_is_one_clear_error(
    braking_file: Path, tmp_path: Path, monkeypatch
):
    """Simulated read-only directory (root ignores permission bits): renaming a finished
    temporary file raises EACCES. A RunError names the file; the run leaves nothing."""

    def refuse(src, dst) -> None:
        raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(dst))

    monkeypatch.setattr(os, "replace", refuse)
    model_cfg, train_cfg = tiny_configs(epochs=1)
    run = tmp_path / "run"
    with pytest.raises(RunError) as info:
        train(braking_file, model_cfg, train_cfg, run, progress=False)
    assert str(info.value) == f"cannot write {run / 'config.json'}: Permission denied"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["braking.h5"]


def test_bucketing_changes_nothing_where_every_scene_has_the_same_agent_count(
    braking_file: Path, tmp_path: Path
):
    model_cfg, train_cfg = tiny_configs(epochs=2)
    assert train_cfg.bucket_batches  # the default
    plain = make_configs(
        "ours",
        TINY_MODEL,
        epochs=2,
        batch_size=3,
        seed=0,
        lr=3e-3,
        bucket_batches=False,
        preset="paper",
    )
    train(braking_file, model_cfg, train_cfg, tmp_path / "bucketed", progress=False)
    train(braking_file, plain[0], plain[1], tmp_path / "plain", progress=False)
    assert_same_weights(weights(tmp_path / "bucketed"), weights(tmp_path / "plain"))


def test_a_run_without_validation_scenes_says_so(tmp_path: Path, capsys):
    """No val split: one line on stderr at the start, best.pt is the last epoch's weights, and
    the summaries (the run's and a finished run's status) say "no validation split"."""
    from predictor.run_state import run_status

    data = write_braking_dataset(tmp_path / "no_val.h5", counts=(6, 0, 2))
    model_cfg, train_cfg = tiny_configs(epochs=2)
    result = train(data, model_cfg, train_cfg, tmp_path / "run", progress=False)
    err = capsys.readouterr().err.splitlines()
    said = [line for line in err if "no validation split" in line]
    assert len(said) == 1 and "best.pt is the last epoch" in said[0] and str(data) in said[0]
    summary = result.summary("ours")
    assert "no validation split (best.pt is the last epoch, 2)" in summary
    assert "n/a" not in summary
    best = torch.load(tmp_path / "run" / "best.pt", weights_only=True)
    last = torch.load(tmp_path / "run" / "last.pt", weights_only=True)
    assert best["epoch"] == last["epoch"] == 2 and best["best_score"] is None
    for name, tensor in last["model_state"].items():
        assert torch.equal(best["model_state"][name], tensor), name
    status = run_status(tmp_path / "run").summary()
    assert "no validation split" in status and "n/a" not in status


def test_a_run_with_validation_scenes_reports_its_best_ade(
    braking_file: Path, tmp_path: Path, capsys
):
    model_cfg, train_cfg = tiny_configs(epochs=1)
    result = train(braking_file, model_cfg, train_cfg, tmp_path / "run", progress=False)
    assert "no validation split" not in capsys.readouterr().err
    assert f"best val ADE (main agents) {result.best_score:.3f} m at epoch 1" in result.summary("x")
