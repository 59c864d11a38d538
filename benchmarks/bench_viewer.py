"""The viewer page: how large it is and how fast it opens, for a 100-scene test split of 22 cars.

Usage: python benchmarks/bench_viewer.py [--loads 5]
Generates the default Halting Car test set (50 + 50 scenes, 60 steps, 22 cars), predicts it
with the untrained default `ours` model (its attention is as large as a trained one's), writes
the viewer page (timed, median of 3) and opens it --loads times from disk in headless Chromium
(tests/browser.py's launcher, a fresh page each time). A load is the page's own figure,
`window.viewerLoadMs`: from the start of the navigation to the end of its first drawing
(parsing the HTML, inflating the data, building the scene list, drawing the scene). The goal
is under 2 s. Needs chromium and chromedriver on PATH (exits 1 naming what is missing).
The last line of stdout is one JSON object {"benchmark": "viewer", ...}.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from browser import find_chromium, launch, open_page  # noqa: E402

from pipeline.generation import GenerateConfig, generate_dataset  # noqa: E402
from pipeline.viewer import make_viewer  # noqa: E402
from predictor.forecasting import predict_model  # noqa: E402
from predictor.model import SmoothAttentionPredictor  # noqa: E402
from predictor.predictions import Predictions  # noqa: E402
from predictor.presets import make_configs  # noqa: E402
from trajectory_data.torch_dataset import TrajectoryDataset  # noqa: E402

GOAL_S = 2.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loads", type=int, default=5, help="page loads timed (default 5)")
    args = parser.parse_args()
    browser, driver_path, reason = find_chromium()
    if reason:
        print(f"bench_viewer.py: error: {reason}", file=sys.stderr)
        raise SystemExit(1)
    torch.set_num_threads(1)
    with tempfile.TemporaryDirectory() as folder:
        data = Path(folder) / "hc.h5"
        config = GenerateConfig.for_scenario("halting_car_v3", num_test=50, seed=0)
        generate_dataset(config, data, progress=False)
        dataset = TrajectoryDataset(data, "test")
        torch.manual_seed(0)
        model = SmoothAttentionPredictor(make_configs("ours")[0])
        with torch.inference_mode():
            mean, attention = predict_model(model, dataset.all(), dataset.meta.num_observed)
        pred = Predictions.from_split(dataset.data, dataset.meta, "test", "ours", mean, attention)
        pred.save(Path(folder) / "ours.npz")
        write_s = []
        for _ in range(3):
            started = time.perf_counter()
            viewer = make_viewer(data, predictions=Path(folder) / "ours.npz")
            write_s.append(time.perf_counter() - started)
        page = Path(folder) / "view.html"
        page.write_text(viewer.text, encoding="utf-8")
        size = page.stat().st_size
        loads = []
        with launch(browser, driver_path) as driver:
            for _ in range(args.loads):
                open_page(driver, page)
                loads.append(driver.execute_script("return window.viewerLoadMs") / 1000.0)
                driver.get("about:blank")
    record = {
        "benchmark": "viewer",
        "scenes": viewer.shown,
        "agents": dataset.data.num_agents,
        "steps": dataset.data.num_steps,
        "page_mb": round(size / 1e6, 2),
        "write_s": round(statistics.median(write_s), 2),
        "load_median_s": round(statistics.median(loads), 3),
        "load_max_s": round(max(loads), 3),
        "loads": len(loads),
        "goal_s": GOAL_S,
    }
    print(
        f"viewer: {viewer.shown} scenes x {dataset.data.num_agents} cars, page "
        f"{size / 1e6:.1f} MB written in {record['write_s']:.2f} s; opens in "
        f"{record['load_median_s']:.2f} s (median of {len(loads)}, slowest "
        f"{record['load_max_s']:.2f} s; goal under {GOAL_S:.0f} s)"
    )
    print(json.dumps(record))


if __name__ == "__main__":
    main()
