"""What best-of-K costs: one prediction of a test split against the same plus K sampled futures
and their scores (minADE_K, minFDE_K, miss rate, NLL), for a model with one Gaussian per step
(both samplers) and one with trajectory modes.

Usage: python benchmarks/bench_sampling.py [--data FILE.h5] [--samples 20] [--repeats 3]
Default data: the default Double Merge test set (100 scenes, 60 steps, 22 agents), generated;
--data takes any dataset file (e.g. an ETH/UCY scene). Untrained `crowd` and `crowd_modes`
models (the cost does not depend on the weights), one torch thread, the median of --repeats.
The goal (issue 69): K = 20 at most 3x one prediction. The last line of stdout is one JSON
object {"benchmark": "sampling", ...}.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import torch
from bench_evaluate import median_seconds  # a script beside this one

from pipeline.generation import GenerateConfig, generate_dataset
from predictor.config import resolve_roles
from predictor.forecasting import forecast_model, score
from predictor.model import SmoothAttentionPredictor
from predictor.predictions import Predictions
from predictor.presets import make_configs
from trajectory_data.torch_dataset import TrajectoryDataset


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=None, help="dataset file (default: generated DM)")
    parser.add_argument("--samples", type=int, default=20, help="K (default 20)")
    parser.add_argument("--repeats", type=int, default=3, help="timed passes (default 3)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(args.data) if args.data else Path(folder) / "dm.h5"
        if args.data is None:
            generate_dataset(GenerateConfig.for_scenario("double_merge_v1"), path, progress=False)
        dataset, train = TrajectoryDataset(path, "test"), TrajectoryDataset(path, "train")
        meta, batch, fit = dataset.meta, dataset.all(), train.all()
    record = {"benchmark": "sampling", "scenes": batch.batch_size, "k": args.samples}

    def timed(model: SmoothAttentionPredictor, k: int, method: str) -> float:
        def once() -> None:
            forecast = forecast_model(
                model, batch, meta.num_observed, k, 0, nll=k > 0, method=method
            )
            predictions = Predictions.from_split(
                dataset.data,
                meta,
                "test",
                "ours",
                forecast.pred_mean,
                forecast.attention,
                forecast.samples,
            )
            score(predictions, forecast.nll)

        once()  # warm-up
        return median_seconds(once, args.repeats)

    lines = []
    for preset, methods in (("crowd", ("marginal", "rollout")), ("crowd_modes", ("marginal",))):
        torch.manual_seed(0)
        config = resolve_roles(make_configs("ours", preset=preset)[0], meta.role_names)
        model = SmoothAttentionPredictor(config)
        model.fit_normalisation(fit.positions, fit.valid, meta.num_observed, fit.roles)
        one = timed(model, 0, "marginal")
        record[f"{preset}_one_s"] = round(one, 3)
        for method in methods:
            sampled = timed(model, args.samples, method)
            key = f"{preset}_{method}"
            record[f"{key}_s"] = round(sampled, 3)
            record[f"{key}_ratio"] = round(sampled / one, 2)
            lines.append(f"{key} {sampled:.2f} s = {sampled / one:.2f}x")
        lines.insert(len(lines) - len(methods), f"{preset} one prediction {one:.2f} s")
    print(
        f"{path.name} test split ({batch.batch_size} scenes), K = {args.samples}: "
        + "; ".join(lines)
    )
    print(json.dumps(record))


if __name__ == "__main__":
    main()
