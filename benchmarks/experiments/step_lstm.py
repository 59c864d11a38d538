"""Experiment (issue 13, not adopted): nn.LSTM's single-step calls replaced by an LSTM step with
a hand-derived backward, timed inside the model's training step against nn.LSTM.

Usage: python benchmarks/experiments/step_lstm.py [--repeats 8] [--floor]
(not run by `make bench`: the result was negative; benchmarks/README.md has the figures).

`--floor` times, beside the other two, a third model whose three LSTMs keep only their matrix
products (`MatmulFloorLSTM`: the same weights and shapes, no gate nonlinearities or cell): the
products, forward and backward, are what any implementation of the same LSTM must compute, so
its step time bounds what a faster LSTM alone could reach.

First checks in float64 that `StepLSTM` equals `nn.LSTM` (outputs, and gradients with respect
to inputs, states and weights; gradcheck of the recurrence), then times `train_step` on the
paper's batch (8 synthetic scenes, 22 agents, T = 60, 15 observed, 45 fed back) for the
`paper` and `agent` presets, one torch thread: the current model against the same model with
its three LSTMs replaced by `StepLSTM` loaded with the same weights, alternating steps in one
process; medians. The last line of stdout is one JSON object.

The LSTM, same mathematics and parameters as `nn.LSTM` (gate order i, f, g, o):

    gates = x_t W_ih^T + b_ih + b_hh + h_{t-1} W_hh^T           (n, 4H) pre-activation
    i, f, o = sigmoid(.), g = tanh(.)
    c_t = f * c_{t-1} + i * g,   h_t = o * tanh(c_t)

Backward, per step (dh, dc: the gradients reaching h_t and c_t; a' the activated gates):

    dc  += dh * o * (1 - tanh(c_t)^2)
    d[i f g o] = [dc * g, dc * c_{t-1}, dc * i, dh * tanh(c_t)]        (activated gates)
    dgates = d[i f g o] * [i(1-i), f(1-f), 1-g^2, o(1-o)]              (pre-activation)
    dh_{t-1} = dgates W_hh,  dc_{t-1} = dc * f,  dW_hh = sum_t dgates_t^T h_{t-1}
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch
from torch import Tensor, nn
from torch.autograd.function import FunctionCtx, once_differentiable

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from bench_training import ROLE_NAMES, synthetic_batch  # noqa: E402

from predictor.config import resolve_roles  # noqa: E402
from predictor.model import SmoothAttentionPredictor  # noqa: E402
from predictor.presets import make_configs  # noqa: E402
from predictor.run_state import make_optimizer  # noqa: E402
from predictor.training import train_step  # noqa: E402

LSTMState = tuple[Tensor, Tensor]


def _tanh(x: Tensor, out: Tensor) -> Tensor:
    """tanh(x) into `out` as 2 sigmoid(2 x) - 1: the same function, and on CPU (PyTorch 2.13,
    one thread) ~3x faster than torch.tanh, whose kernel is not vectorised as sigmoid's is."""
    return torch.mul(x, 2.0, out=out).sigmoid_().mul_(2.0).sub_(1.0)


class _Recurrence(torch.autograd.Function):
    """The recurrence in a transposed layout, time first, then hidden units, sequences last:
    each step's gates are one contiguous (4H, n) block and each gate a contiguous (H, n) block
    (elementwise ops on the strided gate columns of an (n, 4H) tensor were several times
    slower).

    Inputs: projected (S, 4H, n) = W_ih x_t + b_ih + b_hh, h_0 and c_0 (H, n), W_hh (4H, H).
    Outputs: h_1 .. h_S (S, H, n) and c_S (H, n).
    """

    @staticmethod
    def forward(
        ctx: FunctionCtx, projected: Tensor, h0: Tensor, c0: Tensor, weight_hh: Tensor
    ) -> tuple[Tensor, Tensor]:
        num_steps, width, batch = projected.shape
        hid = width // 4
        gates = torch.empty_like(projected)  # (S, 4H, n) activated [i f g o]
        cells = projected.new_empty(num_steps + 1, hid, batch)  # (S+1, H, n) c_0 .. c_S
        tanh_cells = projected.new_empty(num_steps, hid, batch)  # (S, H, n) tanh(c_1 .. c_S)
        out = projected.new_empty(num_steps, hid, batch)  # (S, H, n) h_1 .. h_S
        cells[0] = c0
        h = h0
        for t in range(num_steps):
            act, cell = gates[t], cells[t + 1]  # (4H, n), (H, n)
            g = act[2 * hid : 3 * hid]
            torch.addmm(projected[t], weight_hh, h, out=act)
            g.mul_(2.0)
            act.sigmoid_()  # i, f, o; sigmoid(2 z) for g
            g.mul_(2.0).sub_(1.0)  # tanh(z) = 2 sigmoid(2 z) - 1
            torch.mul(act[hid : 2 * hid], cells[t], out=cell)
            cell.addcmul_(act[:hid], g)
            _tanh(cell, tanh_cells[t])
            h = torch.mul(act[3 * hid :], tanh_cells[t], out=out[t])
        ctx.save_for_backward(gates, cells, tanh_cells, out, h0, weight_hh)
        return out, cells[num_steps]

    @staticmethod
    @once_differentiable
    def backward(
        ctx: FunctionCtx, grad_out: Tensor, grad_cell: Tensor
    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        gates, cells, tanh_cells, out, h0, weight_hh = ctx.saved_tensors
        num_steps, width, _ = gates.shape
        hid = width // 4
        grad_gates = torch.empty_like(gates)  # (S, 4H, n) pre-activation
        grad_weight = weight_hh.new_zeros(weight_hh.shape)  # (4H, H)
        d_h = grad_out[num_steps - 1].clone()  # (H, n)
        d_c = grad_cell.clone()  # (H, n)
        weight_t = weight_hh.t()  # (H, 4H)
        for t in range(num_steps - 1, -1, -1):
            act, tanh_c, d_gate = gates[t], tanh_cells[t], grad_gates[t]
            i, f, g, o = act[:hid], act[hid : 2 * hid], act[2 * hid : 3 * hid], act[3 * hid :]
            torch.mul(d_h, tanh_c, out=d_gate[3 * hid :])  # d o
            d_h.mul_(o)  # dh * o, the gradient reaching tanh(c_t)
            d_c.add_(d_h)
            d_h.mul_(tanh_c)
            d_c.addcmul_(d_h, tanh_c, value=-1.0)  # dc += dh * o * (1 - tanh(c_t)^2)
            torch.mul(d_c, g, out=d_gate[:hid])  # d i
            torch.mul(d_c, cells[t], out=d_gate[hid : 2 * hid])  # d f
            torch.mul(d_c, i, out=d_gate[2 * hid : 3 * hid])  # d g
            slope = torch.addcmul(act, act, act, value=-1.0)  # a (1 - a): sigmoid slopes
            torch.mul(g, g, out=slope[2 * hid : 3 * hid]).neg_().add_(1.0)  # 1 - g^2: tanh
            d_gate.mul_(slope)
            d_c.mul_(f)  # dc_{t-1}
            grad_weight.addmm_(d_gate, (out[t - 1] if t > 0 else h0).t())  # dgates h_{t-1}^T
            d_h = torch.mm(weight_t, d_gate)  # dh_{t-1} (H, n)
            if t > 0:
                d_h.add_(grad_out[t - 1])
        return grad_gates, d_h, d_c, grad_weight


class StepLSTM(nn.LSTM):
    """`nn.LSTM(input_size, hidden_size)` (one layer, sequence first) whose single-step calls
    (sequences of length 1, as in the fed-back rollout) run `_Recurrence` instead of the
    library kernel; longer sequences take `nn.LSTM`'s own path. Same parameters, initial
    values and state dicts as `nn.LSTM`.

    forward(x (S, n, in), state ((1, n, H), (1, n, H)) or None) -> (out (S, n, H), (h_S, c_S)
    each (1, n, H)); a missing state is zeros.
    """

    def forward(self, x: Tensor, state: LSTMState | None = None) -> tuple[Tensor, LSTMState]:
        if x.shape[0] != 1:
            return super().forward(x, state)
        bias = (self.bias_ih_l0 + self.bias_hh_l0).unsqueeze(1)  # (4H, 1)
        projected = torch.addmm(bias, self.weight_ih_l0, x[0].t()).unsqueeze(0)  # (1, 4H, n)
        if state is None:
            h0 = c0 = x.new_zeros(self.hidden_size, x.shape[1])  # (H, n)
        else:
            h0, c0 = state[0][0].t(), state[1][0].t()  # (H, n) each
        hidden, cell = _Recurrence.apply(projected, h0, c0, self.weight_hh_l0)
        out = hidden.transpose(1, 2).contiguous()  # (1, n, H)
        return out, (out, cell.t().contiguous().unsqueeze(0))


class MatmulFloorLSTM(nn.LSTM):
    """Not an LSTM: `nn.LSTM`'s interface and parameters, but each step computes only the
    products gates = x_t W_ih^T + b + h_{t-1} W_hh^T and passes the first H gate columns on as
    h_t (and c_t). Autograd then runs the backward products (dgates W_hh, dgates^T h_{t-1},
    dgates^T x_t, dgates W_ih) and nothing else of an LSTM's. The weights are scaled by 0.1 so
    that the linear recurrence stays small over 60 steps. For timing only (`--floor`)."""

    def forward(self, x: Tensor, state: LSTMState | None = None) -> tuple[Tensor, LSTMState]:
        hid = self.hidden_size
        h = x.new_zeros(x.shape[1], hid) if state is None else state[0][0]
        projected = torch.addmm(
            self.bias_ih_l0 + self.bias_hh_l0, x.flatten(0, 1), self.weight_ih_l0.t()
        )
        projected = projected.view(x.shape[0], x.shape[1], 4 * hid)
        outs = []
        for t in range(x.shape[0]):
            h = torch.addmm(projected[t], h, self.weight_hh_l0.t())[:, :hid]
            outs.append(h)
        out = torch.stack(outs)
        return out, (out[-1:], out[-1:])


def check_exact() -> None:
    """StepLSTM against nn.LSTM in float64 (one step from a given and from a zero state)."""
    torch.manual_seed(0)
    reference = nn.LSTM(5, 4).double()
    step = StepLSTM(5, 4).double()
    step.load_state_dict(reference.state_dict())
    x = torch.randn(1, 6, 5, dtype=torch.float64, requires_grad=True)
    h0 = torch.randn(1, 6, 4, dtype=torch.float64, requires_grad=True)
    c0 = torch.randn(1, 6, 4, dtype=torch.float64, requires_grad=True)
    for state in ((h0, c0), None):
        results = []
        for module in (reference, step):
            out, (h, c) = module(x, state)
            loss = (out * torch.arange(4.0)).sum() + (h**2).sum() + (c * 3).sum()
            inputs = [x, *module.parameters()] + ([h0, c0] if state else [])
            results.append([out, h, c, *torch.autograd.grad(loss, inputs)])
        for a, b in zip(*results):
            torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-12)
    shapes = ((3, 16, 6), (4, 6), (4, 6), (16, 4))  # projected, h0, c0, W_hh
    args = [torch.randn(*s, dtype=torch.float64, requires_grad=True) for s in shapes]
    assert torch.autograd.gradcheck(_Recurrence.apply, args)


def swap_lstms(model: SmoothAttentionPredictor, kind: type[nn.LSTM] | None = None) -> None:
    """Replace the model's three nn.LSTMs by `kind`s (default StepLSTM) holding the same
    weights (MatmulFloorLSTM: scaled by 0.1)."""
    kind = kind or StepLSTM
    for name in ("g_interact", "g_self", "g_pred"):
        old = getattr(model, name)
        new = kind(old.input_size, old.hidden_size)
        new.load_state_dict(old.state_dict())
        if kind is MatmulFloorLSTM:
            with torch.no_grad():
                for weight in new.parameters():
                    weight.mul_(0.1)
        setattr(model, name, new)


def time_preset(preset: str, repeats: int, floor: bool = False) -> dict:
    """Seconds per training step, current (nn.LSTM) against StepLSTM (and with `floor`
    MatmulFloorLSTM), alternating."""
    batch = synthetic_batch(8, 60, 22, seed=1)
    focal = torch.zeros(8, 22, dtype=torch.bool)
    focal[:, :2] = True  # the agent preset weights the main agents' loss terms
    batch = replace(batch, focal=focal)
    model_cfg, train_cfg = make_configs("ours", preset=preset)
    model_cfg = resolve_roles(model_cfg, ROLE_NAMES)
    runs = []
    for kind in (None, StepLSTM, MatmulFloorLSTM)[: 3 if floor else 2]:
        torch.manual_seed(0)
        model = SmoothAttentionPredictor(model_cfg)
        if kind is not None:
            swap_lstms(model, kind)
        if model_cfg.frame == "agent":
            model.fit_normalisation(batch.positions, batch.valid, 15, batch.roles)
        optimizer = make_optimizer(model, train_cfg)
        for _ in range(2):  # warm-up
            train_step(model, optimizer, batch, 15, train_cfg)
        runs.append((model, optimizer, []))
    for _ in range(repeats):
        for model, optimizer, times in runs:
            start = time.perf_counter()
            train_step(model, optimizer, batch, 15, train_cfg)
            times.append(time.perf_counter() - start)
    current, new, *rest = (statistics.median(times) for _, _, times in runs)
    result = {
        "preset": preset,
        "current_step_s": round(current, 3),
        "step_lstm_step_s": round(new, 3),
        "training_speedup": round(current / new, 3),
    }
    if rest:
        result["matmul_floor_step_s"] = round(rest[0], 3)
        result["floor_speedup"] = round(current / rest[0], 3)
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=8, help="timed steps per model")
    parser.add_argument(
        "--floor", action="store_true", help="also time the LSTMs' matrix products alone"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    check_exact()
    results = []
    for preset in ("paper", "agent"):
        results.append(time_preset(preset, args.repeats, args.floor))
        print(f"{preset}: {results[-1]}", file=sys.stderr)
    print(json.dumps({"benchmark": "step_lstm", "results": results}))


if __name__ == "__main__":
    main()
