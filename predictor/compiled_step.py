"""Training through a compiled graph step (`TrainConfig.compile_graph_step`).

A training step is ~50-60 % fixed cost at the agent preset's batch of 4 scenes: one scene costs
half as much as eight (benchmarks/README.md, "A compiled graph step"), so the time goes into the
~13,000 small torch calls of a forward pass and their backward, not into arithmetic.
`torch.compile` of the graph step (`SmoothAttentionPredictor._run`, called once per observed
chunk and once per fed-back step) fuses them; with Dynamo's `allow_rnn` the three LSTMs are
traced too (without it Dynamo breaks the graph at each LSTM and the step was no faster).
Measured in benchmarks/README.md; the same mathematics to float rounding (tested).
"""

from __future__ import annotations

import os
import shutil
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # torch is imported where it is used: command lines check compiler_missing
    from torch import nn


GRAPH_STEP_RECOMPILE_LIMIT = 64  # compiled shapes of the graph step per process (Dynamo's: 8)


def compiler_missing() -> str | None:
    """Why the graph step cannot be compiled here (inductor's CPU kernels are C++), or None."""
    compiler = os.environ.get("CXX", "g++")
    if shutil.which(compiler) is None:
        return f"compile_graph_step needs a C++ compiler ({compiler!r}, or $CXX) on PATH"
    return None


def compile_graph_step(model: nn.Module) -> None:
    """Route `model`'s graph steps through `torch.compile` while it trains with gradients;
    validation, evaluation and prediction (eval mode or no grad) stay eager, so they neither
    wait for compilation nor depend on it. The weights and checkpoints are unchanged."""
    import torch

    torch._dynamo.config.allow_rnn = True  # trace the LSTMs instead of breaking the graph
    # Every model's graph step is one code object, and Dynamo keeps its compiled entries per code
    # object with a recompile limit (8): a process that trains run after run (a reproduction
    # worker) would fill it from the third or fourth model on and run later chunk shapes eager.
    # So the previous models' entries go; one compiled model trains at a time in a process, and
    # inductor's on-disk cache still makes the recompilation short.
    torch._dynamo.reset()
    # The step compiles once per input shape (dynamic=False): chunk lengths (chunk_steps, the
    # spans' remainders, the fed-back single step) times batch sizes (a full batch and a shorter
    # last one) times the variants' optional inputs. On a small training set (Double Merge
    # 3+10: batches of 4, 4 and 2 scenes) a run passed Dynamo's default limit of 8 shapes in its
    # first epoch and ran the rest eager; a run's shapes are few, so the limit is raised.
    limit = torch._dynamo.config.recompile_limit
    torch._dynamo.config.recompile_limit = max(limit, GRAPH_STEP_RECOMPILE_LIMIT)
    eager = model._run
    compiled = torch.compile(eager, dynamic=False)

    def graph_step(*args, **kwargs):
        if model.training and torch.is_grad_enabled():
            return compiled(*args, **kwargs)
        return eager(*args, **kwargs)

    model._run = graph_step  # an instance attribute: the model's own calls go through it
