"""Shared test fixtures: small random-but-valid trajectory sets, dataset files, prediction files.

Plain functions (`make_meta`, `make_trajectory_set`, `make_predictions`, `write_predictions_npz`)
build the data; the fixtures `make_dataset_file` and `dataset_file` wrap them for use with
`tmp_path`. Everything is seeded, so a test sees the same arrays every run.
"""

from __future__ import annotations

import errno
import importlib.util
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import h5py
import numpy as np
import pytest
import torch

# pygame greets on stdout at its first import, which may happen inside a test's capture
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

REPO_ROOT = Path(__file__).resolve().parents[1]
if str(REPO_ROOT) not in sys.path:  # make the packages importable without installation
    sys.path.insert(0, str(REPO_ROOT))

from predictor.predictions import Predictions  # noqa: E402
from trajectory_data.format import (  # noqa: E402
    SPLITS,
    DatasetMeta,
    TrajectorySet,
    write_dataset,
)

# one torch thread for every test, whichever files are collected (the tools run with one too)
torch.set_num_threads(1)

# A test run started in the background by a non-interactive shell (`cmd &`) inherits SIGINT
# ignored, and so would every program it starts: the Ctrl-C tests would then see no
# KeyboardInterrupt. Python's own handler here gives this process and, through exec, its
# children the usual Ctrl-C.
if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

# set by a user's shell or CI, these would reach into the tests' own runs: a Ray cluster the
# tests' temporary folders are not on, warnings or dev-mode lines in a tool's one-line stderr
FOREIGN_ENV = ("RAY_ADDRESS", "PYTHONWARNINGS", "PYTHONDEVMODE")


@pytest.fixture(autouse=True)
def _seeded_global_rngs():
    """Each test starts from the same global torch RNG state, whatever ran before it."""
    torch.manual_seed(0)


@pytest.fixture(autouse=True)
def _no_foreign_env(monkeypatch):
    for name in FOREIGN_ENV:
        monkeypatch.delenv(name, raising=False)


CASE_NAMES = ("major", "minor")
ROLE_NAMES = ("main_green", "main_brown", "distractor")


def make_meta(num_observed: int = 4, num_predicted: int = 6, dt: float = 0.1) -> DatasetMeta:
    """Metadata of a small two-case, three-role dataset."""
    return DatasetMeta(
        scenario="unit_test",
        dt=dt,
        num_observed=num_observed,
        num_predicted=num_predicted,
        case_names=CASE_NAMES,
        major_case="major",
        role_names=ROLE_NAMES,
        config={"generator": {"seed": 7, "note": "made by tests/conftest.py"}, "lanes": [1, 2]},
    )


def make_trajectory_set(
    n: int, num_steps: int = 10, num_agents: int = 4, seed: int = 0
) -> TrajectorySet:
    """n valid random trajectories: two main agents first, then distractors.

    Agents move forward along x in lanes 3.5 m apart; some distractors are absent at some steps
    (zero-filled and invalid); the main agents attend to each other inside a random interaction
    window; cases alternate 0, 1, 0, ...
    """
    rng = np.random.default_rng(seed)
    shape = (n, num_steps, num_agents)
    time = np.arange(num_steps) * 0.1  # (T,) [s]
    speed = rng.uniform(5.0, 15.0, size=(n, 1, num_agents))  # (n, 1, N) [m/s]
    states = np.zeros((*shape, 4), dtype=np.float32)
    states[..., 0] = rng.uniform(0, 20, size=(n, 1, num_agents)) + speed * time[:, None]
    states[..., 1] = 3.5 * (np.arange(num_agents) % 4)  # lane centre [m]
    states[..., 2] = rng.normal(0.0, 0.05, size=shape)
    states[..., 3] = speed
    valid = np.ones(shape, dtype=bool)
    valid[:, :, 2:] = rng.random((n, num_steps, max(num_agents - 2, 0))) > 0.2
    states[~valid] = 0.0
    actions = rng.normal(0.0, 0.3, size=(*shape, 2)).astype(np.float32)
    actions[~valid] = 0.0
    start = rng.integers(0, num_steps, size=n)
    interaction = (np.arange(num_steps)[None, :] >= start[:, None]) & (
        np.arange(num_steps)[None, :] < start[:, None] + num_steps // 2
    )
    attention = np.full(shape, -1, dtype=np.int16)
    if num_agents >= 2:
        attention[:, :, 0] = np.where(interaction, 1, -1)
        attention[:, :, 1] = np.where(interaction, 0, -1)
    roles = np.full((n, num_agents), 2, dtype=np.int8)
    roles[:, :2] = [0, 1][:num_agents]
    return TrajectorySet(
        states=states,
        actions=actions,
        valid=valid,
        attention=attention,
        interaction=interaction,
        case=(np.arange(n) % 2).astype(np.int8),
        seed=np.arange(seed * 1000, seed * 1000 + n, dtype=np.int64),
        roles=roles,
    )


def assert_sets_equal(actual: TrajectorySet, expected: TrajectorySet) -> None:
    """Every array equal, with the same dtype and shape."""
    for name, want in expected.arrays().items():
        got = getattr(actual, name)
        assert got.dtype == want.dtype, name
        assert got.shape == want.shape, name
        np.testing.assert_array_equal(got, want, err_msg=name)


def write_small_dataset(
    path: Path, counts: tuple[int, int, int] = (6, 3, 4), num_agents: int = 4, **meta_kwargs
) -> tuple[DatasetMeta, dict[str, TrajectorySet]]:
    """Write a small valid dataset with `counts` trajectories in train/val/test."""
    meta = make_meta(**meta_kwargs)
    splits = {
        name: make_trajectory_set(count, meta.num_steps, num_agents, seed=i + 1)
        for i, (name, count) in enumerate(zip(SPLITS, counts, strict=True))
    }
    write_dataset(path, meta, splits)
    return meta, splits


def downgrade_to_schema_1(path: Path) -> None:
    """Turn a file written with every optional dataset recorded into the schema-1 layout (which
    had no `focal` and no `recorded`), as files written before schema 2 are."""
    with h5py.File(path, "r+") as file:
        file.attrs["schema_version"] = np.int64(1)
        del file.attrs["recorded"]
        for split in SPLITS:
            del file[split]["focal"]


@pytest.fixture
def make_dataset_file(tmp_path: Path) -> Callable[..., Path]:
    """Factory: `make_dataset_file(name="data.h5", counts=(6, 3, 4), num_agents=4)` -> path."""

    def make(name: str = "data.h5", **kwargs) -> Path:
        path = tmp_path / name
        write_small_dataset(path, **kwargs)
        return path

    return make


@pytest.fixture
def dataset_file(make_dataset_file: Callable[..., Path]) -> Path:
    """A small valid dataset file (train 6, val 3, test 4 trajectories; T=10, N=4)."""
    return make_dataset_file()


def make_predictions(
    n: int = 3,
    num_observed: int = 4,
    num_predicted: int = 6,
    num_agents: int = 4,
    with_attention: bool = True,
    seed: int = 0,
) -> Predictions:
    """Predictions of n random test scenes: noisy true positions as the predicted means and a
    random softmax attention (NaN without attention, as for a baseline)."""
    rng = np.random.default_rng(seed)
    data = make_trajectory_set(n, num_observed + num_predicted, num_agents, seed=seed)
    meta = make_meta(num_observed, num_predicted)
    noise = rng.normal(0.0, 0.3, size=(n, num_predicted, num_agents, 2))
    pred_mean = data.states[:, num_observed:, :, :2] + noise
    shape = (n, data.num_steps - 1, num_agents, num_agents)
    if with_attention:
        logits = rng.normal(size=shape)
        attention = np.exp(logits) / np.exp(logits).sum(axis=-1, keepdims=True)
    else:
        attention = np.full(shape, np.nan)
    name = "ours" if with_attention else "const_vel"
    return Predictions.from_split(data, meta, "test", name, pred_mean, attention)


def write_predictions_npz(path: Path, **kwargs) -> Path:
    """A predictions file as tools/evaluate.py writes it (`make_predictions(**kwargs)`)."""
    make_predictions(**kwargs).save(path)
    return path


def load_tool(name: str) -> ModuleType:
    """tools/<name> (e.g. "plot.py") imported as a fresh module, for in-process runs where a
    failure must be simulated; the tools are scripts, not a package."""
    path = REPO_ROOT / "tools" / name
    spec = importlib.util.spec_from_file_location(f"tool_{path.stem}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def tool_env() -> dict[str, str]:
    """Environment for running tools/*.py in a subprocess: repo importable, one thread."""
    env = {k: v for k, v in os.environ.items() if k not in FOREIGN_ENV}
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO_ROOT), env.get("PYTHONPATH")]))
    env["OMP_NUM_THREADS"] = "1"
    env["MPLBACKEND"] = "Agg"
    return env


def run_tool(
    name: str, *args: object, timeout: float = 120, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess:
    """Run tools/<name> with `args` in a subprocess (`tool_env()` unless `env`), output captured."""
    return subprocess.run(
        [sys.executable, str(REPO_ROOT / "tools" / name), *map(str, args)],
        capture_output=True,
        text=True,
        env=tool_env() if env is None else env,
        timeout=timeout,
    )


def one_line(err: pytest.ExceptionInfo) -> str:
    """The raised exception's message, checked to be a single line (the CLI's error format)."""
    message = str(err.value)
    assert "\n" not in message
    return message


# ---- the command-line smoke run of tests/test_train_cli.py and test_evaluate_cli.py ----
# tiny network sizes, as train.py takes them
TINY = [
    *("--set", "model.embed_dim=8", "--set", "model.edge_hidden=8"),
    *("--set", "model.node_hidden=12", "--set", "model.attn_dim=4"),
]


@pytest.fixture(scope="module")
def smoke(tmp_path_factory) -> dict:
    """Train 2 epochs of the paper preset and evaluate once, in subprocesses."""
    from test_training import write_braking_dataset  # a test module: imported when used

    root = tmp_path_factory.mktemp("smoke")
    data = write_braking_dataset(root / "braking.h5", counts=(6, 3, 4))
    run = root / "run"
    trained = run_tool(
        "train.py",
        "--data",
        data,
        "--out",
        run,
        "--epochs",
        "2",
        "--seed",
        "0",
        "--set",
        "train.batch_size=4",
        "--preset",
        "paper",
        *TINY,
    )
    evaluated = run_tool(
        "evaluate.py", "--run", run, "--data", data, "--save-predictions", root / "pred.npz"
    )
    return {"root": root, "data": data, "run": run, "trained": trained, "evaluated": evaluated}


def refuse_writes_in(monkeypatch, directory: Path) -> None:
    """Simulate a read-only `directory` (root ignores permission bits): renaming a finished
    temporary file into it raises EACCES, as on a read-only mount."""
    real = os.replace

    def replace(src, dst) -> None:
        if Path(dst).parent == directory:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(dst))
        real(src, dst)

    monkeypatch.setattr(os, "replace", replace)
