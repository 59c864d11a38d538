"""Does the compiled graph step gain from LSTMs written as plain ops? (issue 13; negative)

Usage: python benchmarks/experiments/compiled_lstm.py [--preset agent] [--scenes 4] [--repeats 7]

`TrainConfig.compile_graph_step` compiles the graph step with the three LSTMs as `torch.lstm`
(mkldnn's fused layer). Here a third model's LSTMs are unrolled into one input product for all
steps, then per step `h W_hh^T`, the four gates (PyTorch's i, f, g, o order) and the state
update, so that inductor can fuse each step's elementwise work (and its backward) around plain
matrix products. Eager, compiled and compiled-unrolled models (same seed and batch, the code of
this checkout) take one step each (losses and largest relative gradient differences against
eager reported), then alternate in a rotating order, one torch thread. All three models share
the code object of `SmoothAttentionPredictor._run`, so Dynamo's recompile limits are raised:
at the default (8) the unrolled model's later chunk shapes fell back to eager and it read as
slower than it is. The last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import step_trees  # noqa: E402  (this folder's helper: one tree's predictor, one Ours model)
from step_scaling import ROOT, stepped  # noqa: E402

MODES = ("eager", "compiled", "unrolled")


def unrolled_lstm(lstm: torch.nn.LSTM, inputs: torch.Tensor, state):
    """The model's one-layer, time-first LSTM as plain ops (same outputs as `torch.lstm`)."""
    if state is None:
        h = c = inputs.new_zeros(inputs.shape[1], lstm.hidden_size)
    else:
        h, c = state[0][0], state[1][0]
    bias = lstm.bias_ih_l0 + lstm.bias_hh_l0
    projected = torch.nn.functional.linear(inputs, lstm.weight_ih_l0, bias)
    outputs = []
    for step in range(inputs.shape[0]):
        gates = projected[step] + h @ lstm.weight_hh_l0.t()
        i, f, g, o = gates.chunk(4, -1)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        h = torch.sigmoid(o) * torch.tanh(c)
        outputs.append(h)
    return torch.stack(outputs), (h[None], c[None])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="agent", help="model preset (agent)")
    parser.add_argument("--scenes", type=int, default=4, help="scenes per batch (4)")
    parser.add_argument("--repeats", type=int, default=7, help="timed steps per model (7)")
    args = parser.parse_args()
    if args.scenes < 1 or args.repeats < 1:
        parser.error("--scenes and --repeats must be at least 1")
    torch.set_num_threads(1)
    torch._dynamo.config.allow_rnn = True
    torch._dynamo.config.recompile_limit = 64
    torch._dynamo.config.accumulated_recompile_limit = 256
    code = step_trees.load_tree(ROOT)
    module_globals = code.Model._run.__globals__  # predictor.model's, kept by the class
    fused = module_globals["run_lstm"]

    def run_lstm(lstm, inputs, state):
        if getattr(lstm, "unrolled", False):
            return unrolled_lstm(lstm, inputs, state)
        return fused(lstm, inputs, state)

    module_globals["run_lstm"] = run_lstm
    runs = {}
    for mode in MODES:
        run = step_trees.build(code, args.preset, args.scenes)
        if mode != "eager":
            run[0]._run = torch.compile(run[0]._run, dynamic=False)
        for module in run[0].modules():
            if isinstance(module, torch.nn.LSTM):
                module.unrolled = mode == "unrolled"
        runs[mode] = run
    first = {mode: stepped(code, run, 0) for mode, run in runs.items()}  # compiles
    reference = [p.grad for p in runs["eager"][0].parameters()]
    scale = max(g.abs().max().item() for g in reference if g is not None)
    gradient_diff = {
        mode: max(
            (a - b.grad).abs().max().item()
            for a, b in zip(reference, runs[mode][0].parameters(), strict=True)
            if a is not None
        )
        / scale
        for mode in MODES[1:]
    }
    times: dict[str, list[float]] = {mode: [] for mode in MODES}
    for step in range(1, args.repeats + 3):
        for mode in MODES[step % 3 :] + MODES[: step % 3]:
            seconds, _ = stepped(code, runs[mode], step)
            if step >= 3:  # the compiled models' second and third steps may still recompile
                times[mode].append(seconds)
    median = {mode: round(statistics.median(values), 4) for mode, values in times.items()}
    print(
        json.dumps(
            {
                "benchmark": "compiled_lstm",
                "preset": args.preset,
                "scenes": args.scenes,
                "median_s": median,
                "speedup_over_eager": {m: round(median["eager"] / median[m], 3) for m in MODES},
                "first_step": {m: [round(s, 1), loss] for m, (s, loss) in first.items()},
                "max_relative_gradient_diff": gradient_diff,
            }
        )
    )


if __name__ == "__main__":
    main()
