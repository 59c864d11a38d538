"""Write the checkpoints, predictions and state layouts of tests/test_old_checkpoints.py.

Run once, with the code before the predictor was composed of parts (commit 5c0cc14, where
`SmoothAttentionPredictor` was a chain of mixins), from the repository root:

    OMP_NUM_THREADS=1 python tests/data/old_checkpoints/make_old_checkpoints.py

It keeps, in this folder: `paper.pt` and `agent.pt`, the last.pt of one epoch of the paper and
agent presets (tiny sizes; the agent's highway shortened to keep the file small) on a small
generated Double Merge v1 file; `predictions.pt`, a test scene of that file and what each
checkpoint predicts for them; `state_layout.json`, the state-dict names and shapes and the
parameter order (which the optimizer state and the gradient clipping follow) of a set of
configurations. Rerunning it with later code would describe that code, not the old one.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(ROOT))

from predictor.config import resolve_roles  # noqa: E402
from predictor.evaluation import load_model  # noqa: E402
from predictor.model import SmoothAttentionPredictor  # noqa: E402
from predictor.presets import make_configs  # noqa: E402
from trajectory_data.torch_dataset import TrajectoryDataset  # noqa: E402

TINY = {"embed_dim": 4, "edge_hidden": 4, "node_hidden": 6, "attn_dim": 2}
SHORT_HIGHWAY = {"highway_steps": 2, "highway_horizon": 3}
ROLE_NAMES = ("main_green", "main_brown", "distractor")
# name -> (variant, preset, model overrides): the layouts stored in state_layout.json
LAYOUTS = {
    "paper_ours": ("ours", "paper", {}),
    "paper_average": ("average", "paper", {}),
    "paper_correct": ("correct", "paper", {}),
    "paper_detached": ("ours", "paper", {"detach_covariance": True}),
    "agent_ours": ("ours", "agent", SHORT_HIGHWAY),
    "agent_correct": ("correct", "agent", SHORT_HIGHWAY),
    "agent_s_attn": ("s_attn", "agent", {}),
    "agent_learnt_attended": (
        "ours",
        "agent",
        {**SHORT_HIGHWAY, "attended_refit": False, "attended_fit": "mean"}
        | {"highway_relation": False, "highway_head_groups": False},
    ),
    "agent_zero_cv": ("ours", "agent_zero_cv", SHORT_HIGHWAY),
    "crowd": ("ours", "crowd", SHORT_HIGHWAY),
}


def settings(values: dict) -> list[str]:
    return [arg for name, value in values.items() for arg in ("--set", f"model.{name}={value}")]


def train(data: Path, preset: str, extra: dict, out: Path) -> None:
    command = [sys.executable, "tools/train.py", "--data", str(data), "--out", str(out)]
    command += ["--preset", preset, "--epochs", "1", *settings({**TINY, **extra})]
    subprocess.run(command, cwd=ROOT, check=True, capture_output=True)


def layout(variant: str, preset: str, overrides: dict) -> dict:
    model_cfg, _ = make_configs(variant, {**TINY, **overrides}, preset=preset)
    model = SmoothAttentionPredictor(resolve_roles(model_cfg, ROLE_NAMES))
    return {
        "variant": variant,
        "preset": preset,
        "overrides": overrides,
        "state": [[name, list(t.shape)] for name, t in model.state_dict().items()],
        "parameters": [name for name, _ in model.named_parameters()],
    }


def main() -> None:
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "dm.h5"
        generate = [sys.executable, "tools/generate.py", "--scenario", "double_merge_v1"]
        generate += ["--num-major", "4", "--minor-ratio", "0.5", "--num-test", "2"]
        subprocess.run([*generate, "--out", str(data)], cwd=ROOT, check=True, capture_output=True)
        for preset, extra in (("paper", {}), ("agent", SHORT_HIGHWAY)):
            train(data, preset, extra, Path(tmp) / preset)
            (HERE / f"{preset}.pt").write_bytes((Path(tmp) / preset / "last.pt").read_bytes())
        test = TrajectoryDataset(data, "test")
        scenes = test.all()
    fixed = {  # one scene, and of its attention the main agents' (small files)
        "positions": scenes.positions[:1].clone(),
        "valid": scenes.valid[:1].clone(),
        "roles": scenes.roles[:1].clone(),
        "num_observed": test.meta.num_observed,
    }
    for preset in ("paper", "agent"):
        model, _ = load_model(HERE / f"{preset}.pt")
        out = model.predict(
            fixed["positions"], fixed["valid"], fixed["num_observed"], roles=fixed["roles"]
        )
        fixed[preset] = {
            "rollout_mean": out.rollout.mean,
            "rollout_tril": out.rollout.tril,
            "one_step_mean": out.one_step.mean,
            "attention": out.attention[:, :, :2].clone(),
            "rollout_attention": out.rollout_attention[:, :, :2].clone(),
        }
    torch.save(fixed, HERE / "predictions.pt")
    layouts = {name: layout(*spec) for name, spec in LAYOUTS.items()}
    (HERE / "state_layout.json").write_text(json.dumps(layouts, indent=1) + "\n")


if __name__ == "__main__":
    main()
