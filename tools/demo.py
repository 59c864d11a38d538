"""The README's main job: the whole pipeline on a built-in default, in a few minutes.

1. simulate a Double Merge episode and write a picture and a GIF of it;
2. generate a small Double Merge dataset (20 major + 6 minor training/validation trajectories,
   10 test trajectories per case);
3. train the smooth-attention predictor (`ours`, the default preset `agent`) briefly
   (20 epochs; the paper trains 200);
4. evaluate it and the constant-velocity baseline on the test split;
5. plot sample trajectories, predicted against true trajectories, and the attention of one main
   car on the other over time;
6. write view.html, the viewer of the test split with the predictor's predictions and attention
   (one HTML file: open it in a browser, no server or network needed; docs/VIEWER.md).

Usage: python tools/demo.py [--out outputs/demo] [--epochs 20] [--seed 0] [--overwrite]
Everything goes under --out, which a rerun replaces; the last line says where. A folder that
holds other files than the demo's and no `.demo-output` marker (the demo writes one) is
replaced only with --overwrite.
"""

from __future__ import annotations

import gc
import json
import shutil
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
from tqdm import tqdm

from pipeline.cli import (
    FAILED,
    INTERRUPTED,
    ArgumentParser,
    fail,
    run_main,
    status,
    write_failure_code,
    writing,
)
from pipeline.frames import annotate, legend_entries
from pipeline.generation import (
    DEFAULT_SCENARIO,
    GenerateConfig,
    UnsafeExpertError,
    generate_dataset,
)
from pipeline.signals import DeferredSignals
from pipeline.viewer import ViewerError, write_viewer
from predictor.evaluation import evaluate_baseline, evaluate_run
from predictor.forecasting import EvaluationError
from predictor.plots import plot_attention, plot_predictions, plot_samples, save_figure
from predictor.presets import DEFAULT_PRESET, make_configs
from predictor.run_files import RunError, RunWriteError
from predictor.training import train
from scenarios import env_module
from scenarios.frames import render_scene
from trajectory_data.reader import read_meta, read_split

DEMO_SCENARIO = DEFAULT_SCENARIO  # the generator's default (Double Merge v1)
DEMO_DATA = {"num_major": 20, "minor_ratio": 0.3, "num_test": 10}  # small: trains in minutes
DEMO_MARKER = ".demo-output"  # marks a folder the demo wrote, which a rerun may replace
# what the demo writes (a folder holding nothing else is a demo's, also from before the marker)
DEMO_FILES = frozenset(
    {
        DEMO_MARKER,
        "episode.png",
        "episode.gif",
        f"{DEMO_SCENARIO}.h5",
        "run_ours",
        "predictions.npz",
        "eval_const_vel.json",
        "samples.png",
        "predictions.png",
        "attention.png",
        "view.html",
    }
)


def simulate_episode(out: Path, seed: int) -> Path:
    """Run one expert episode of the minor case and write its middle frame and a GIF, each
    frame titled (scenario, case, time) with a legend of the car colours."""
    env = env_module(DEMO_SCENARIO).parallel_env()
    env.reset(seed=seed, options={"case": "minor"})
    world = env.unwrapped.world
    legend = legend_entries(DEMO_SCENARIO, list(world.roles))
    dt = env.unwrapped.config.recorded_dt
    frames = []
    steps = env.unwrapped.max_cycles
    for step in tqdm(range(steps), desc="simulate an episode", unit="step", file=sys.stderr):
        env.step(env.unwrapped.expert_actions())
        title = f"{DEMO_SCENARIO}, minor case, expert drivers: t = {(step + 1) * dt:.1f} s"
        frame = render_scene(env.unwrapped.scenario, world, 640, 160)
        frames.append(annotate(frame, title, legend))
    status("simulate: writing episode.png and episode.gif")
    iio.imwrite(out / "episode.png", frames[len(frames) // 2])
    iio.imwrite(out / "episode.gif", np.stack(frames[::2]), duration=200, loop=0)
    return out / "episode.gif"


def write_json(path: Path, value: dict) -> None:
    with writing(path) as temp:
        temp.write_text(json.dumps(value, indent=2, allow_nan=False) + "\n")


def write_figure(path: Path, fig) -> None:
    with writing(path) as temp:
        save_figure(fig, temp)


def replace_output_folder(out: Path, overwrite: bool) -> None:
    """Empty `out` for a new demo, creating it: exits 2 if it is a file, or if it holds files
    and no demo marker (a folder of the user's) and `overwrite` is not given."""
    if out.exists() and not out.is_dir():
        fail(f"--out {out} is a file, not a folder")
    if out.is_dir() and not overwrite and not (out / DEMO_MARKER).exists():
        if any(entry.name not in DEMO_FILES for entry in out.iterdir()):
            fail(f"--out {out} holds files the demo did not write; pass --overwrite to replace it")
    try:
        if out.exists():
            shutil.rmtree(out)
        out.mkdir(parents=True)
        (out / DEMO_MARKER).write_text("written by tools/demo.py; a rerun replaces this folder\n")
    except OSError as err:
        fail(f"cannot write --out {out}: {err.strerror or err}")


def main(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(
        prog="demo.py", description="Run the whole pipeline on a small default."
    )
    parser.add_argument(
        "--out", default="outputs/demo", help="output folder (default outputs/demo)"
    )
    parser.add_argument("--epochs", type=int, default=20, help="training epochs (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="data and training seed (default 0)")
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace --out even if it holds files the demo did not write",
    )
    args = parser.parse_args(argv)
    if args.epochs < 1:
        fail(f"--epochs must be at least 1, got {args.epochs}")
    try:  # every setting checked before anything is written
        config = GenerateConfig.for_scenario(DEMO_SCENARIO, **DEMO_DATA, seed=args.seed)
        model_cfg, train_cfg = make_configs(
            "ours", preset=DEFAULT_PRESET, epochs=args.epochs, seed=args.seed
        )
    except ValueError as err:
        fail(f"--seed: {err}")
    out = Path(args.out)
    replace_output_folder(out, args.overwrite)
    try:
        run_demo(out, config, model_cfg, train_cfg)
    except KeyboardInterrupt:
        fail(
            f"interrupted; {out} holds what was done so far; run the demo again to start over",
            INTERRUPTED,
        )
    except FloatingPointError as err:
        fail(f"training diverged: {err}", FAILED)
    except RunWriteError as err:
        fail(str(err), write_failure_code(err.errno))
    except OSError as err:
        fail(f"cannot write in {out}: {err.strerror or err}", write_failure_code(err.errno))
    except (UnsafeExpertError, RunError, EvaluationError, ViewerError) as err:  # defaults failed
        fail(str(err), FAILED)


def run_demo(out: Path, config: GenerateConfig, model_cfg, train_cfg) -> None:
    """The demo's six steps into the emptied folder `out`: a line on stdout as each starts and
    the results on its last line; bars and status lines on stderr."""
    started = time.perf_counter()
    print(f"== simulate: wrote {simulate_episode(out, config.seed)}", flush=True)
    # the episode's pymunk space is freed by the cyclic garbage collector through cffi callbacks,
    # where a Ctrl-C is printed and lost (pipeline.signals): free it now, with signals deferred,
    # not at some moment of the training (a Ctrl-C there was lost in two loaded full-suite runs)
    with DeferredSignals():
        gc.collect()
    data = out / f"{DEMO_SCENARIO}.h5"
    print("== generate", flush=True)
    print(generate_dataset(config, data).summary(), flush=True)
    print("== train", flush=True)
    run = out / "run_ours"
    print(train(data, model_cfg, train_cfg, run, preset=DEFAULT_PRESET).summary("ours"), flush=True)
    print("== evaluate", flush=True)
    ours = evaluate_run(run, data, "test", progress=True)
    const_vel = evaluate_baseline("const_vel", data, "test", progress=True)
    write_json(run / "eval.json", ours.to_dict())
    write_json(out / "eval_const_vel.json", const_vel.to_dict())
    with writing(out / "predictions.npz") as temp:
        ours.save_predictions(temp)
    for evaluation in (ours, const_vel):
        print(f"{evaluation.predictor}: {evaluation.headline()}", flush=True)
    print("== plot", flush=True)
    status("plot: samples.png, predictions.png, attention.png")
    write_figure(out / "samples.png", plot_samples(read_split(data, "train"), read_meta(data)))
    write_figure(out / "predictions.png", plot_predictions(ours.predictions, 0))
    write_figure(out / "attention.png", plot_attention(ours.predictions, 0, 0, 1))
    print("== view", flush=True)
    page = out / "view.html"
    viewer = write_viewer(data, page, predictions=out / "predictions.npz", run=run)
    print(f"{viewer.summary(page)}: open it in a browser", flush=True)
    scores = [e.to_dict() for e in (ours, const_vel)]
    main, every = (
        [s[key]["overall"]["ade"] for s in scores] for key in ("main_agents", "all_agents")
    )
    accuracy = scores[0]["attention_accuracy"]["overall"]["accuracy"]
    print(
        f"demo done in {time.perf_counter() - started:.0f} s: test ADE of the main cars "
        f"{main[0]:.2f} m (ours, {train_cfg.epochs} epochs) vs {main[1]:.2f} m (constant "
        f"velocity), of all cars {every[0]:.2f} vs {every[1]:.2f} m; attention accuracy "
        f"{accuracy:.2f}; results in {out}/"
    )


if __name__ == "__main__":
    run_main(main)
