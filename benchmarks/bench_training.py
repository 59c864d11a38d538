"""Training throughput of the smooth-attention predictor on CPU (synthetic data, default shape).

Usage: python benchmarks/bench_training.py [--threads 1] [--repeats 3] [--variant ours]
[--presets paper,agent,agent_edge_relations,agent_own_highway]
(`--threads 1,2` compares thread counts; only meaningful on an otherwise idle machine: with
the other core busy, 2 threads oversubscribe and one epoch took 146 s instead of 2.2 s.)

Times whole training epochs (optimiser steps included) and the per-epoch validation pass on
synthetic scenes of the default Double Merge shape (52 train + 13 val scenes, T = 60 steps,
15 observed, 22 agents = 462 edges per scene, the preset's batch size: 8 for `paper`, 4 for
`agent`), for each preset (and `agent_own_highway`, the agent preset without its attended
highway, and `agent_edge_relations`, without its role balance and head groups) and torch
thread count. Reports, per preset and thread count, the
median over repeats of:

- epoch_s / val_s: one training epoch (with the attended highway's refit at its start where
  the preset has one) / one validation pass (fed-back means, no_grad) [s]
  (wall clock; epoch_cpu_s is the process CPU time of the epoch, less sensitive to other load)
- full_run_s: projected run of the preset's length (paper 200, agent 90 epochs),
  epochs x (epoch_s + val_s) [s] (target: < 600 s)
- scene_steps_per_s: training throughput, scenes x (T - 1) steps per second of training
- model_gflops / matmul_gflops / fraction_of_matmul: achieved rate from an analytic count of
  the model's multiply-adds (forward + backward ~ 3 x forward) vs. a dense 1024^2 sgemm measured
  in the same process

The last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from predictor.config import ModelConfig, resolve_roles  # noqa: E402
from predictor.forecasting import predict_model  # noqa: E402
from predictor.model import SmoothAttentionPredictor  # noqa: E402
from predictor.presets import make_configs  # noqa: E402
from predictor.run_state import make_optimizer  # noqa: E402
from predictor.training import train_step  # noqa: E402
from trajectory_data.torch_dataset import Batch  # noqa: E402

ROLE_NAMES = ("main_green", "main_brown", "distractor")  # the scenarios' roles (agent preset)
# Settings timed besides the presets, to show what each addition costs: the agent preset before
# its attended highway (own-history highway only; the preset until 2026-11-26), and before its
# role balance and head groups (changed later on 2026-11-26).
SETTINGS: dict[str, tuple[str, dict]] = {
    "agent_own_highway": (
        "agent",
        {
            "highway_attended": False,
            "attended_refit": False,
            "highway_relation": False,
            "attended_fit": "mean",
            "role_attention_bias": False,
            "role_balanced_attention": False,
            "highway_head_groups": False,
        },
    ),
    "agent_edge_relations": (
        "agent",
        {"role_balanced_attention": False, "highway_head_groups": False},
    ),
}


def synthetic_batch(scenes: int, steps: int, agents: int, seed: int) -> Batch:
    """Cars on 4 lanes at constant speed, one car per scene braking halfway."""
    gen = torch.Generator().manual_seed(seed)
    dt = 0.2
    speed = 8 + 4 * torch.rand(scenes, 1, agents, generator=gen)  # (B, 1, N) [m/s]
    speed = speed.repeat(1, steps, 1)  # (B, T, N)
    speed[:, steps // 2 :, 0] *= torch.linspace(1, 0.3, steps - steps // 2).unsqueeze(0)
    x = torch.cumsum(speed * dt, 1) + 200 * torch.rand(scenes, 1, agents, generator=gen)
    y = (3.5 * (torch.arange(agents) % 4)).expand(scenes, steps, agents).float()
    states = torch.stack([x, y, torch.zeros_like(x), speed], -1)  # (B, T, N, 4)
    labels = torch.full((scenes, steps, agents), -1, dtype=torch.long)
    return Batch(
        states=states,
        valid=torch.ones(scenes, steps, agents, dtype=torch.bool),
        attention=labels,
        interaction=torch.zeros(scenes, steps, dtype=torch.bool),
        case=torch.zeros(scenes, dtype=torch.long),
        seed=torch.arange(scenes),
        roles=torch.zeros(scenes, agents, dtype=torch.long),
        focal=torch.arange(agents).expand(scenes, agents) < 2,  # two scored cars, as the scenarios
    )


def forward_macs(cfg: ModelConfig, agents: int, steps: int, observed: int, rollout: bool) -> int:
    """Multiply-adds of one forward training pass over one scene."""
    e, h, hn, a = cfg.embed_dim, cfg.edge_hidden, cfg.node_hidden, cfg.attn_dim
    edges = agents * (agents - 1)
    per_agent = (
        4 * e
        + 2 * 2 * e  # F_self; F_interact split into a tail and a head part
        + 4 * h * (e + h)  # G_self
        + 2 * h * a  # F_attn(o_ii) and its query W^T F_attn(o_ii)
        + 2 * e  # F_embed
        + 4 * hn * (e + 2 * h + hn)  # G_pred
        + 5 * hn  # F_pred
    )
    per_edge = 4 * h * (e + h) + 2 * h  # G_interact; attention score and attended sum
    per_step = agents * per_agent + edges * per_edge
    step_count = (steps - 1) + ((steps - observed - 1) if rollout else 0)
    return per_step * step_count


def matmul_gflops(repeats: int = 20, size: int = 1024) -> float:
    """Dense float32 matmul rate at the current thread count [GFLOP/s], median of repeats."""
    a, b = torch.randn(size, size), torch.randn(size, size)
    a @ b  # warm-up
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        a @ b
        times.append(time.perf_counter() - start)
    return 2 * size**3 / statistics.median(times) / 1e9


def time_epoch(
    model, optimizer, train: Batch, batches: list[Batch], observed: int, train_cfg
) -> tuple[float, float]:
    """(wall, process CPU) seconds of one training epoch, with the closed-form refit of the
    attended highway at its start where the model has one (as `predictor.training` does)."""
    start, cpu = time.perf_counter(), time.process_time()
    if model.config.attended_refit:
        model.refit_attended(train.positions, train.valid, observed, train.attention, train.roles)
    for batch in batches:
        train_step(model, optimizer, batch, observed, train_cfg)
    return time.perf_counter() - start, time.process_time() - cpu


def bench_threads(preset: str, threads: int, args) -> dict:
    torch.set_num_threads(threads)
    base, overrides = SETTINGS.get(preset, (preset, {}))
    model_cfg, train_cfg = make_configs(args.variant, overrides, preset=base)
    model_cfg = resolve_roles(model_cfg, ROLE_NAMES)
    torch.manual_seed(0)
    model = SmoothAttentionPredictor(model_cfg)
    optimizer = make_optimizer(model, train_cfg)
    train = synthetic_batch(args.scenes, args.steps, args.agents, seed=1)
    val = synthetic_batch(args.val_scenes, args.steps, args.agents, seed=2)
    if model_cfg.frame == "agent":
        model.fit_normalisation(train.positions, train.valid, args.observed, train.roles)
    size = train_cfg.batch_size
    batches = [
        Batch(**{k: None if v is None else v[i : i + size] for k, v in vars(train).items()})
        for i in range(0, args.scenes, size)
    ]
    train_step(model, optimizer, batches[0], args.observed, train_cfg)  # warm-up
    epochs, cpus, vals, rates = [], [], [], []
    for _ in range(args.repeats):
        rates.append(matmul_gflops())
        wall, cpu = time_epoch(model, optimizer, train, batches, args.observed, train_cfg)
        epochs.append(wall)
        cpus.append(cpu)
        start = time.perf_counter()
        predict_model(model, val, args.observed)
        vals.append(time.perf_counter() - start)
    epoch_s, val_s, rate = (statistics.median(v) for v in (epochs, vals, rates))
    macs = (
        forward_macs(model_cfg, args.agents, args.steps, args.observed, train_cfg.sequence_loss)
        * args.scenes
    )
    model_gflops = 3 * 2 * macs / epoch_s / 1e9
    return {
        "preset": preset,
        "threads": threads,
        "batch_size": size,
        "epochs": train_cfg.epochs,
        "epoch_s": round(epoch_s, 3),
        "epoch_cpu_s": round(statistics.median(cpus), 3),
        "val_s": round(val_s, 3),
        "full_run_s": round(train_cfg.epochs * (epoch_s + val_s), 1),
        "scene_steps_per_s": round(args.scenes * (args.steps - 1) / epoch_s, 1),
        "model_gflops": round(model_gflops, 2),
        "matmul_gflops": round(rate, 1),
        "fraction_of_matmul": round(model_gflops / rate, 4),
        "epoch_s_all": [round(v, 3) for v in epochs],
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--threads", default="1", help="comma-separated torch thread counts (default 1)"
    )
    parser.add_argument("--repeats", type=int, default=3, help="timed epochs per thread count")
    parser.add_argument("--variant", default="ours", help="model variant")
    parser.add_argument(
        "--presets",
        default="paper,agent,agent_edge_relations,agent_own_highway",
        help="comma-separated presets or SETTINGS (default paper,agent,"
        "agent_edge_relations,agent_own_highway)",
    )
    parser.add_argument("--scenes", type=int, default=52, help="training scenes")
    parser.add_argument("--val-scenes", type=int, default=13, help="validation scenes")
    parser.add_argument("--steps", type=int, default=60, help="recorded steps T")
    parser.add_argument("--observed", type=int, default=15, help="observed steps")
    parser.add_argument("--agents", type=int, default=22, help="agents per scene")
    args = parser.parse_args()
    results = []
    runs = [(p, int(t)) for p in args.presets.split(",") for t in args.threads.split(",")]
    for preset, threads in runs:
        result = bench_threads(preset, threads, args)
        results.append(result)
        print(
            f"preset={preset} threads={threads}: epoch {result['epoch_s']} s, "
            f"val {result['val_s']} s, "
            f"projected {result['epochs']}-epoch run {result['full_run_s']} s, "
            f"{result['scene_steps_per_s']} scene-steps/s, "
            f"{result['fraction_of_matmul']:.1%} of dense matmul",
            file=sys.stderr,
        )
    print(
        json.dumps(
            {
                "benchmark": "training",
                "variant": args.variant,
                "scenes": args.scenes,
                "val_scenes": args.val_scenes,
                "steps": args.steps,
                "observed": args.observed,
                "agents": args.agents,
                "results": results,
            }
        )
    )


if __name__ == "__main__":
    main()
