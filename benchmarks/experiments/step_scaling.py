"""How a training step's time grows with the batch (issue 13: is the step's cost arithmetic or
per-op overhead?), and optionally what `torch.compile` makes of it.

Usage: python benchmarks/experiments/step_scaling.py [--scenes 1,2,4,8] [--presets agent,paper]
[--repeats 9] [--compile]

Per preset, builds the same Ours model (same seed) on `bench_training.synthetic_batch` batches of
each size (22 agents, T = 60, 15 observed, 45 fed back; the code of this checkout, through
`step_trees.build`) and times `train_step` one size after the other in a rotating order, after
two warm-ups, one torch thread, so that all sizes see the same load. If one scene costs nearly
as much as eight, the step is paid per op (Python, dispatcher, autograd), not per flop, and
only fewer ops can make it faster.

`--compile` times, per preset at the largest size, an eager model against one whose graph step
(`SmoothAttentionPredictor._run`) is wrapped in `torch.compile(dynamic=False)` with
`torch._dynamo.config.allow_rnn` set (without it Dynamo breaks the graph at each of the three
LSTMs and the compiled step is no faster), alternating. Both first take one step on the same
seed and batch from the same weights, and the largest differences of their losses and of
their gradients are reported (the same mathematics to float rounding); the compiled
model's first step (compilation included; inductor caches its kernels on disk, so a second
process compiles faster) is reported apart. The last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import step_trees  # noqa: E402  (this folder's helper: one tree's predictor, one Ours model)

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def timed_step(code, run, step: int) -> float:
    return stepped(code, run, step)[0]


def stepped(code, run, step: int) -> tuple[float, float]:
    """Seconds and loss of one training step with the rollout samples of `step`."""
    model, optimizer, batch, cfg = run
    torch.manual_seed(step)
    start = time.perf_counter()
    terms = code.train_step(model, optimizer, batch, step_trees.OBSERVED, cfg)
    return time.perf_counter() - start, float(terms["loss"])


def scaling(code, preset: str, sizes: list[int], repeats: int) -> dict:
    """Median seconds per step at each batch size, sizes timed in a rotating order."""
    runs = {size: step_trees.build(code, preset, size) for size in sizes}
    times: dict[int, list[float]] = {size: [] for size in sizes}
    for step in range(repeats + 2):
        order = sizes[step % len(sizes) :] + sizes[: step % len(sizes)]
        for size in order:
            seconds = timed_step(code, runs[size], step)
            if step >= 2:
                times[size].append(seconds)
    medians = {size: statistics.median(values) for size, values in times.items()}
    largest = max(sizes)
    return {
        "preset": preset,
        "median_s": {str(size): round(value, 4) for size, value in medians.items()},
        # the smallest batch's cost as a share of the largest's
        "smallest_over_largest": round(medians[min(sizes)] / medians[largest], 3),
    }


def compiled(code, preset: str, scenes: int, repeats: int) -> dict:
    """Eager against `torch.compile`d graph steps, alternating, same seed and batch."""
    torch._dynamo.config.allow_rnn = True  # trace the LSTMs instead of breaking the graph
    eager = step_trees.build(code, preset, scenes)
    fast = step_trees.build(code, preset, scenes)
    model = fast[0]
    model._run = torch.compile(model._run, dynamic=False)
    _, eager_loss = stepped(code, eager, 0)
    first, fast_loss = stepped(code, fast, 0)  # compilation happens here
    # train_step leaves each parameter's gradient (clipped by its group's norm) in .grad; the
    # largest difference is read against the largest gradient (a parameter whose gradient is
    # float noise around zero, ~1e-9, would make a per-parameter ratio meaningless)
    pairs = [
        (a.grad, b.grad)
        for a, b in zip(eager[0].parameters(), model.parameters(), strict=True)
        if a.grad is not None
    ]
    scale = max(a.abs().max().item() for a, _ in pairs)
    gradient_diff = max((a - b).abs().max().item() for a, b in pairs) / scale
    times: dict[str, list[float]] = {"eager": [], "compiled": []}
    for step in range(1, repeats + 3):
        pair = (("eager", eager), ("compiled", fast))
        for name, run in pair if step % 2 else pair[::-1]:
            seconds = timed_step(code, run, step)
            if step >= 3:  # the compiled model's second and third steps may still recompile
                times[name].append(seconds)
    eager_s, compiled_s = (statistics.median(times[name]) for name in ("eager", "compiled"))
    return {
        "preset": preset,
        "scenes": scenes,
        "first_compiled_step_s": round(first, 1),
        "first_losses": [eager_loss, fast_loss],
        # max |eager - compiled| over the first step's gradients / their largest magnitude
        "max_relative_gradient_diff": gradient_diff,
        "eager_s": round(eager_s, 4),
        "compiled_s": round(compiled_s, 4),
        "speedup": round(eager_s / compiled_s, 3),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", default="1,2,4,8", help="batch sizes to time (1,2,4,8)")
    parser.add_argument("--presets", default="agent,paper", help="comma-separated (agent,paper)")
    parser.add_argument("--repeats", type=int, default=9, help="timed steps per size (9)")
    parser.add_argument("--compile", action="store_true", help="also time torch.compile")
    args = parser.parse_args()
    try:
        sizes = sorted({int(size) for size in args.scenes.split(",")})
    except ValueError:
        parser.error("--scenes takes comma-separated positive integers")
    if not sizes or sizes[0] < 1 or args.repeats < 1:
        parser.error("--scenes takes positive integers and --repeats must be at least 1")
    torch.set_num_threads(1)
    code = step_trees.load_tree(ROOT)
    results = []
    for preset in args.presets.split(","):
        result = scaling(code, preset, sizes, args.repeats)
        if args.compile:
            result["compile"] = compiled(code, preset, sizes[-1], args.repeats)
        results.append(result)
        print(f"{preset}: {json.dumps(result)}", file=sys.stderr)
    print(json.dumps({"benchmark": "step_scaling", "results": results}))


if __name__ == "__main__":
    main()
