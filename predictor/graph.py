"""The model's neighbour graph, packed: which directed edges (i -> j, "i attends to j") a window
has, and the per-edge operations (segment softmax, sums over an agent's edges) that cost
O(number of edges) instead of O(N^2).

Which graph (`ModelConfig.neighbours`):

- `all` (the paper's): every ordered pair of distinct agents that are present at some step the
  pass reads. Slots that are never present (padding) get no edges.
- `radius`: j within `radius_m` of i, and `knn`: the `k` agents nearest to i (ties: lower
  slot first). Distances are measured at i's *anchor step*: its last present step among the
  observed ones (t < num_observed; the last observed step for every agent that is rolled out),
  or, for an agent that first appears after the observed steps, its first present step. Only
  agents present at that same step are candidates. So an agent that left before the last
  observed step keeps edges to the agents it was near when it was last seen, and an agent never
  present gets none.

The graph is fixed for the whole window (each edge carries an LSTM state across steps); at each
step the attention runs over the edges whose two agents are both present then.

Edges are listed scene-major, then by tail slot, then by head slot, as flat agent indices
b * N + i into the batch's B * N agent slots; for the complete graph of a fully present batch
this is the order of `edge_index` repeated per scene.

Such a graph (every slot of every scene linked to every other: `Graph.complete`, the paper's
graph over a batch without padding slots) is stored the same way, but its per-edge operations
take a dense path: its edge list is exactly the compact layout (B, N, N-1) flattened, so a sum
over an agent's edges is a sum over the last axis, and the gathers of an edge's tail or head
values keep their `index_select` forward but sum densely backward, with no scatter
(`index_add`) either way. Same values to float rounding (sums in another order), several
times faster per call at the scenarios' shapes (benchmarks/README.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from predictor.config import NEIGHBOURS


@dataclass(frozen=True)
class Graph:
    """Directed edges of a batch of B scenes with N agent slots each, packed."""

    tail: Tensor  # (E,) int64 flat index b * N + i of the attending agent
    head: Tensor  # (E,) int64 flat index b * N + j of the attended agent
    num_scenes: int  # B
    num_agents: int  # N
    # every ordered pair of distinct slots is an edge (E = B * N * (N-1), N >= 2): the edge
    # list is then the compact layout, and the per-edge operations take their dense path
    complete: bool = False

    @property
    def num_edges(self) -> int:
        return int(self.tail.shape[0])

    @property
    def num_slots(self) -> int:
        """B * N, the number of flat agent indices."""
        return self.num_scenes * self.num_agents

    def head_slot(self) -> Tensor:
        """Slot j (0 .. N-1) of each edge's head within its scene, (E,)."""
        return self.head % self.num_agents

    def compact_index(self) -> Tensor:
        """Position of each edge in the compact layout (B, N, N-1) flattened, (E,): head j of
        tail i sits at column j, or j - 1 if j > i (the diagonal is left out)."""
        tail_slot, head_slot = self.tail % self.num_agents, self.head_slot()
        column = head_slot - (head_slot > tail_slot).long()  # (E,)
        return self.tail * (self.num_agents - 1) + column

    def to_compact(self, values: Tensor) -> Tensor:
        """Per-edge values (S, E) into the compact layout (S, B, N, N-1), zero off the graph."""
        if self.complete:
            return values.reshape(values.shape[0], self.num_scenes, self.num_agents, -1)
        width = self.num_slots * (self.num_agents - 1)
        out = values.new_zeros(values.shape[0], width)  # (S, B*N*(N-1))
        out = out.index_copy(1, self.compact_index(), values)
        return out.view(values.shape[0], self.num_scenes, self.num_agents, self.num_agents - 1)

    def sum_by_tail(self, values: Tensor) -> Tensor:
        """Sum of per-edge values (S, E, ...) over each agent's edges: (S, B*N, ...)."""
        if self.complete:
            rows = values.reshape(values.shape[0], self.num_slots, -1, *values.shape[2:])
            return rows.sum(2)
        out = values.new_zeros(values.shape[0], self.num_slots, *values.shape[2:])
        return out.index_add(1, self.tail, values)

    def at_tail(self, values: Tensor) -> Tensor:
        """Each edge's tail's value of per-agent values (S, B*N, ...): (S, E, ...)."""
        if not self.complete:
            return values.index_select(1, self.tail)
        return _CompleteTailGather.apply(values, self.tail, self.num_agents)

    def at_head(self, values: Tensor) -> Tensor:
        """Each edge's head's value of per-agent values (S, B*N, ...): (S, E, ...)."""
        if not self.complete:
            return values.index_select(1, self.head)
        return _CompleteHeadGather.apply(values, self.head, self.num_scenes, self.num_agents)

    def dot_with_tail(self, edge_values: Tensor, values: Tensor) -> Tensor:
        """Per edge, the dot product of its values (S, E, H) with its tail's (S, B*N, H):
        (S, E). A complete graph broadcasts each agent's values over its row of edges instead
        of gathering them."""
        if not self.complete:
            return (edge_values * self.at_tail(values)).sum(-1)
        rows = edge_values.view(values.shape[0], self.num_slots, -1, values.shape[-1])
        return (rows * values.unsqueeze(2)).sum(-1).view(edge_values.shape[:2])

    def edge_present(self, present: Tensor) -> Tensor:
        """Edges whose two agents are present: (S, B, N) -> (S, E) bool."""
        flat = present.flatten(1, 2)  # (S, B*N)
        return self.at_tail(flat) & self.at_head(flat)


class _CompleteTailGather(torch.autograd.Function):
    """`Graph.at_tail` of a complete graph: a gather forward; backward, each agent's gradient
    is the sum over its N-1 consecutive edges (a dense sum, where `index_select`'s backward
    would scatter)."""

    @staticmethod
    def forward(ctx, values: Tensor, tail: Tensor, num_agents: int) -> Tensor:
        ctx.num_agents = num_agents
        return values.index_select(1, tail)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad: Tensor) -> tuple[Tensor, None, None]:
        steps, edges, rest = grad.shape[0], grad.shape[1], grad.shape[2:]
        rows = grad.reshape(steps, edges // (ctx.num_agents - 1), ctx.num_agents - 1, *rest)
        return rows.sum(2), None, None


class _CompleteHeadGather(torch.autograd.Function):
    """`Graph.at_head` of a complete graph: a gather forward; backward, each agent's gradient
    is the sum over the edges it heads, taken as a dense sum over the (N, N) matrix of edges
    with a zero diagonal, where `index_select`'s backward would scatter (`index_add`)."""

    @staticmethod
    def forward(ctx, values: Tensor, head: Tensor, num_scenes: int, num_agents: int) -> Tensor:
        ctx.sizes = (num_scenes, num_agents)
        return values.index_select(1, head)

    @staticmethod
    @torch.autograd.function.once_differentiable
    def backward(ctx, grad: Tensor) -> tuple[Tensor, None, None, None]:
        scenes, n = ctx.sizes
        steps, rest = grad.shape[0], grad.shape[2:]
        # edges of tail i are row i of the (N, N) matrix without its diagonal: flattened, that
        # is the full matrix without its first entry and the last of every N + 1 that follow
        rows = grad.reshape(steps, scenes, n - 1, n, -1)  # (S, B, N-1, N, C)
        padded = F.pad(rows, (0, 0, 0, 1)).reshape(steps, scenes, (n - 1) * (n + 1), -1)
        square = F.pad(padded, (0, 0, 1, 0)).view(steps, scenes, n, n, -1)  # [i, j], 0 at i = j
        return square.sum(2).reshape(steps, scenes * n, *rest), None, None, None


def anchor_steps(valid: Tensor, num_observed: int) -> Tensor:
    """Each agent's anchor step (B, N) int64: its last present step before num_observed, else
    its first present step, else -1 (never present). valid (B, T, N)."""
    num_steps = valid.shape[1]
    steps = torch.arange(num_steps, device=valid.device).view(1, -1, 1)  # (1, T, 1)
    observed = valid & (steps < num_observed)  # (B, T, N)
    last = torch.where(observed, steps, -1).amax(1)  # (B, N)
    first = torch.where(valid, steps, num_steps).amin(1)  # (B, N), T if never present
    first = torch.where(first < num_steps, first, -1)
    return torch.where(last >= 0, last, first)


def anchor_distances(positions: Tensor, valid: Tensor, anchor: Tensor) -> tuple[Tensor, Tensor]:
    """Distances [m] from each agent i to every agent j at i's anchor step, (B, N, N), and
    whether j is a candidate neighbour there (present, j != i, i has an anchor), (B, N, N)."""
    num_agents = positions.shape[2]
    step = anchor.clamp(min=0)  # (B, N)
    index = step[:, :, None, None].expand(-1, -1, num_agents, 2)  # (B, N, N, 2)
    at_anchor = positions.gather(1, index)  # (B, N, N, 2): row i = everyone at i's anchor
    present = valid.gather(1, step[:, :, None].expand(-1, -1, num_agents))  # (B, N, N)
    own = torch.diagonal(at_anchor, dim1=1, dim2=2).transpose(1, 2)  # (B, N, 2)
    distance = (at_anchor - own.unsqueeze(2)).norm(dim=-1)  # (B, N, N)
    other = ~torch.eye(num_agents, dtype=torch.bool, device=valid.device)
    candidate = present & other & (anchor >= 0).unsqueeze(-1)
    return distance, candidate


def adjacency(
    positions: Tensor,
    valid: Tensor,
    num_observed: int,
    neighbours: str = "all",
    radius_m: float = 50.0,
    k: int = 16,
) -> Tensor:
    """(B, N, N) bool: entry [b, i, j] is the edge i -> j of scene b (see the module docstring).
    positions (B, T, N, 2) [m] and valid (B, T, N) of the steps the pass reads."""
    if neighbours not in NEIGHBOURS:
        raise ValueError(f"neighbours must be one of {NEIGHBOURS}, got {neighbours!r}")
    num_agents = valid.shape[2]
    if neighbours == "all":
        ever = valid.any(1)  # (B, N)
        other = ~torch.eye(num_agents, dtype=torch.bool, device=valid.device)
        return ever.unsqueeze(2) & ever.unsqueeze(1) & other
    distance, candidate = anchor_distances(positions, valid, anchor_steps(valid, num_observed))
    if neighbours == "radius":
        return candidate & (distance <= radius_m)
    ranked = torch.where(candidate, distance, torch.inf)  # (B, N, N)
    order = torch.sort(ranked, dim=-1, stable=True).indices  # (B, N, N) nearest first
    slots = torch.arange(num_agents, device=valid.device).expand_as(order)
    rank = torch.empty_like(order).scatter_(-1, order, slots)  # (B, N, N) 0 = nearest
    return candidate & (rank < k)


def neighbour_graph(
    positions: Tensor,
    valid: Tensor,
    num_observed: int,
    neighbours: str = "all",
    radius_m: float = 50.0,
    k: int = 16,
) -> Graph:
    """The packed graph of a batch; arguments as `adjacency`."""
    batch, _, num_agents = valid.shape
    scene, tail, head = adjacency(positions, valid, num_observed, neighbours, radius_m, k).nonzero(
        as_tuple=True
    )  # (E,) each, scene-major, then tail, then head
    complete = num_agents >= 2 and len(tail) == batch * num_agents * (num_agents - 1)
    return Graph(scene * num_agents + tail, scene * num_agents + head, batch, num_agents, complete)


def segment_softmax(scores: Tensor, mask: Tensor, graph: Graph) -> Tensor:
    """Softmax of per-edge scores (S, E) over each tail's edges where `mask` (S, E) holds;
    masked edges, and every edge of a tail without an unmasked one, get 0."""
    lowest, tiny = torch.finfo(scores.dtype).min, torch.finfo(scores.dtype).tiny
    if graph.complete:  # each agent's edges are a row of (S, B*N, N-1): row-wise, no gathers
        rows = scores.view(scores.shape[0], graph.num_slots, -1)
        row_mask = mask.view(rows.shape)
        peak = rows.detach().masked_fill(~row_mask, lowest).amax(-1, keepdim=True)  # stability
        weights = torch.exp((rows - peak).masked_fill(~row_mask, -torch.inf))  # 0 where masked
        return (weights / weights.sum(-1, keepdim=True).clamp(min=tiny)).view(scores.shape)
    masked = scores.detach().masked_fill(~mask, lowest)  # (S, E)
    tails = graph.tail.expand_as(masked)  # (S, E)
    peak = masked.new_full((scores.shape[0], graph.num_slots), lowest)  # (S, B*N)
    peak = peak.scatter_reduce(1, tails, masked, "amax")
    shifted = (scores - graph.at_tail(peak)).masked_fill(~mask, -torch.inf)
    weights = torch.exp(shifted)  # (S, E), 0 where masked
    total = graph.sum_by_tail(weights)  # (S, B*N)
    return weights / graph.at_tail(total).clamp(min=tiny)


def segment_uniform(mask: Tensor, graph: Graph, dtype: torch.dtype = torch.float32) -> Tensor:
    """1 / (number of unmasked edges of the tail) on unmasked edges, 0 elsewhere: (S, E)."""
    weights = mask.to(dtype)  # (S, E)
    count = graph.sum_by_tail(weights)  # (S, B*N)
    return weights / graph.at_tail(count).clamp(min=1.0)


def role_balance(
    roles: Tensor, mask: Tensor, graph: Graph, num_roles: int, dtype: torch.dtype = torch.float32
) -> Tensor:
    """-log(number of the tail's unmasked edges whose head has this edge's head role), (S, E).

    Added to attention logits it gives every role among an agent's neighbours the same total
    prior weight, shared by that role's agents, instead of every agent the same weight: with
    one other main car among 20 distractors, equal logits put 1/2 on the main car, not 1/21.
    roles (B, N) int64 in [0, num_roles); mask (S, E) bool; masked edges get 0.
    """
    head_role = roles.flatten().index_select(0, graph.head)  # (E,)
    onehot = torch.nn.functional.one_hot(head_role, num_roles).to(dtype)  # (E, R)
    per_edge = mask.to(dtype).unsqueeze(-1) * onehot  # (S, E, R)
    counts = graph.at_tail(graph.sum_by_tail(per_edge))  # (S, E, R)
    same = counts.gather(-1, head_role.view(1, -1, 1).expand(mask.shape[0], -1, 1)).squeeze(-1)
    return -torch.log(same.clamp(min=1.0)).masked_fill(~mask, 0.0)
