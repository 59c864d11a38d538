"""The README's main job: the whole pipeline on a built-in default, in a few minutes.

1. simulate a Double Merge episode and write a picture and a GIF of it;
2. generate a small Double Merge dataset (20 major + 6 minor training/validation trajectories,
   10 test trajectories per case);
3. train the smooth-attention predictor (`ours`) briefly (20 epochs; the paper trains 200);
4. evaluate it and the constant-velocity baseline on the test split;
5. plot sample trajectories, predicted against true trajectories, and the attention of one main
   car on the other over time.

Usage: python tools/demo.py [--out outputs/demo] [--epochs 20] [--seed 0]
Everything goes under --out (replaced on every run); the last line says where.
"""

from __future__ import annotations

import json
import shutil
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np

from carlo_lite import render_rgb
from pipeline.cli import ArgumentParser, fail
from scenarios import SCENARIOS
from scenarios.rollout import advance

DEMO_SCENARIO = "double_merge"
DEMO_DATA_ARGS = ["--num-major", "20", "--minor-ratio", "0.3", "--num-test", "10"]


def simulate_episode(out: Path, seed: int) -> Path:
    """Run one expert episode of the minor case and write its last frame and a GIF."""
    scenario = SCENARIOS[DEMO_SCENARIO]()
    world = scenario.reset(seed, "minor")
    frames = []
    for _ in range(scenario.config.num_steps):
        scenario.update(world)
        advance(world, scenario.expert_actions(world), scenario.config.record_every)
        center = (float(world.xy[:2, 0].mean()), world.road.width_m / 2)
        frames.append(render_rgb(world, 640, 160, center_xy=center))
    iio.imwrite(out / "episode.png", frames[len(frames) // 2])
    iio.imwrite(out / "episode.gif", np.stack(frames[::2]), duration=200, loop=0)
    return out / "episode.gif"


def run_step(title: str, argv: list[str], main) -> None:
    """Run one tool's main() in-process, with a heading; its own summary line follows."""
    print(f"== {title}", flush=True)
    main(argv)


def main(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(
        prog="demo.py", description="Run the whole pipeline on a small default."
    )
    parser.add_argument(
        "--out", default="outputs/demo", help="output folder (default outputs/demo)"
    )
    parser.add_argument("--epochs", type=int, default=20, help="training epochs (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="data and training seed (default 0)")
    args = parser.parse_args(argv)
    if args.epochs < 1:
        fail(f"--epochs must be at least 1, got {args.epochs}")
    started = time.perf_counter()
    out = Path(args.out)
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)

    import evaluate
    import generate
    import plot
    import train

    print(f"== simulate: wrote {simulate_episode(out, args.seed)}", flush=True)
    data = out / "double_merge.h5"
    run = out / "run_ours"
    seed = ["--seed", str(args.seed)]
    run_step(
        "generate",
        ["--scenario", DEMO_SCENARIO, *DEMO_DATA_ARGS, *seed, "--out", str(data)],
        generate.main,
    )
    run_step(
        "train",
        [
            "--data",
            str(data),
            "--variant",
            "ours",
            "--epochs",
            str(args.epochs),
            *seed,
            "--out",
            str(run),
        ],
        train.main,
    )
    run_step(
        "evaluate ours",
        [
            "--run",
            str(run),
            "--data",
            str(data),
            "--save-predictions",
            str(out / "predictions.npz"),
        ],
        evaluate.main,
    )
    run_step(
        "evaluate const_vel",
        ["--baseline", "const_vel", "--data", str(data), "--out", str(out / "eval_const_vel.json")],
        evaluate.main,
    )
    print("== plot", flush=True)
    plot.main(["samples", str(data), "--out", str(out / "samples.png")])
    plot.main(["predictions", str(out / "predictions.npz"), "--out", str(out / "predictions.png")])
    plot.main(
        [
            "attention",
            str(out / "predictions.npz"),
            "--agent",
            "0",
            "--target",
            "1",
            "--out",
            str(out / "attention.png"),
        ]
    )
    ours = json.loads((run / "eval.json").read_text())
    const_vel = json.loads((out / "eval_const_vel.json").read_text())
    ade = [m["main_agents"]["overall"]["ade"] for m in (ours, const_vel)]
    print(
        f"demo done in {time.perf_counter() - started:.0f} s: test ADE of the main cars "
        f"{ade[0]:.2f} m (ours, {args.epochs} epochs) vs {ade[1]:.2f} m (constant velocity); "
        f"results in {out}/"
    )


if __name__ == "__main__":
    sys.exit(main())
