"""Evaluation throughput: test scenes scored per second, the path `tools/evaluate.py` takes.

Usage: python benchmarks/bench_evaluate.py [--repeats 5] [--threads 1]
Generates the default Double Merge test set (50 major + 50 minor scenes, 60 steps, 22 agents),
then times, median of --repeats: the predictor (untrained default `ours` model; the cost does
not depend on the weights) predicting every test scene from its 15 observed steps with
fed-back means plus scoring (ADE/FDE per case and group, attention accuracy), and the
constant-velocity baseline with the same scoring, and the ridge baseline fitted on the training
split (cross-validated) and scored. Reading the file is timed separately.
The last line of stdout is one JSON object {"benchmark": "evaluate", ...}.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import torch

from pipeline.generation import GenerateConfig, generate_dataset
from predictor.forecasting import predict_baseline, predict_model, score
from predictor.model import SmoothAttentionPredictor
from predictor.predictions import Predictions
from predictor.presets import make_configs
from trajectory_data.torch_dataset import TrajectoryDataset


def median_seconds(function, repeats: int) -> float:
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5, help="timed passes (default 5)")
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default 1)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "dm.h5"
        generate_dataset(GenerateConfig.for_scenario("double_merge_v0"), path, progress=False)
        load_s = median_seconds(lambda: TrajectoryDataset(path, "test").all(), args.repeats)
        dataset = TrajectoryDataset(path, "test")
        train = TrajectoryDataset(path, "train").data
    meta, batch = dataset.meta, dataset.all()
    torch.manual_seed(0)
    model = SmoothAttentionPredictor(make_configs("ours")[0])

    def scored(name: str, pred_mean, attention) -> None:
        score(Predictions.from_split(dataset.data, meta, "test", name, pred_mean, attention))

    def run_model() -> None:
        scored("ours", *predict_model(model, batch, meta.num_observed))

    def run_const_vel() -> None:
        scored("const_vel", *predict_baseline("const_vel", dataset.data, meta)[:2])

    def run_ridge() -> None:  # fitted on the training split (cross-validated), then scored
        scored("ridge", *predict_baseline("ridge", dataset.data, meta, train)[:2])

    with torch.inference_mode():
        run_model()  # warm-up
        model_s = median_seconds(run_model, args.repeats)
    const_vel_s = median_seconds(run_const_vel, args.repeats)
    ridge_s = median_seconds(run_ridge, args.repeats)
    scenes = batch.batch_size
    record = {
        "benchmark": "evaluate",
        "threads": args.threads,
        "scenes": scenes,
        "steps": batch.num_steps,
        "observed": meta.num_observed,
        "agents": batch.num_agents,
        "load_s": round(load_s, 3),
        "model_s": round(model_s, 3),
        "model_scenes_per_s": round(scenes / model_s, 1),
        "const_vel_s": round(const_vel_s, 4),
        "const_vel_scenes_per_s": round(scenes / const_vel_s, 1),
        "ridge_fit_and_score_s": round(ridge_s, 3),
        "ridge_train_scenes": train.n,
    }
    print(
        f"evaluate double_merge test set ({scenes} scenes): model {model_s:.2f} s = "
        f"{scenes / model_s:.1f} scenes/s, constant velocity {scenes / const_vel_s:,.0f} "
        f"scenes/s, ridge fit on {train.n} training scenes and scored in {ridge_s:.2f} s, "
        f"loading {load_s:.3f} s"
    )
    print(json.dumps(record))


if __name__ == "__main__":
    main()
