"""Torch access to a trajectory file: an in-memory `TrajectoryDataset` and named `Batch`es.

A dataset holds one split (optionally one case) of a trajectory file (schema 1 or 2), read and
validated through `trajectory_data.format`. `dataset[i]` is a `Batch` of one scene (batch size 1)
with the scene's own agent count (`agent_counts`: the slots up to its last ever-present one);
`collate_batch` concatenates such items along the batch axis, padding every scene to the
largest agent count of the batch (not of the split) with absent slots. Layout is `[B, T, N, F]`,
time-major per scene.

`make_loader(..., bucket=True)` groups scenes of similar agent count into batches
(`BucketBatchSampler`), so a crowd of 57 agents does not pad a batch of scenes of 5.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, fields

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, RandomSampler, Sampler, SequentialSampler

from trajectory_data.format import DatasetMeta, FormatError, TrajectorySet
from trajectory_data.reader import read_meta, read_split

# agent slots a dataset has at least: a split of one slot (e.g. ETH/UCY windows of one
# pedestrian) gets an invalid, non-focal second slot, which changes no prediction and no metric
MIN_AGENT_SLOTS = 2
# the agent axis of each Batch field that has one, and the value of an absent (padded) slot
AGENT_AXES = {"states": 2, "valid": 2, "attention": 2, "roles": 1, "focal": 1}
PAD_VALUES = {"attention": -1}  # every other field pads with zeros (False)


@dataclass
class Batch:
    """A batch of scenes. Absent agents have zero states and `valid == False`."""

    states: torch.Tensor  # (B, T, N, C) float32: meta.state_names, x [m] and y [m] first
    valid: torch.Tensor  # (B, T, N) bool: agent present at that step
    attention: torch.Tensor  # (B, T, N) int64: ground-truth attended agent, -1 = none
    interaction: torch.Tensor  # (B, T) bool: inside the interaction period
    case: torch.Tensor  # (B,) int64: index into meta.case_names
    seed: torch.Tensor  # (B,) int64: generating seed, -1 for foreign data
    roles: torch.Tensor | None = None  # (B, N) int64: index into meta.role_names
    focal: torch.Tensor | None = None  # (B, N) bool: agents scored (and weighted in the loss)
    index: torch.Tensor | None = None  # (B,) int64: each scene's position in its split

    @property
    def positions(self) -> torch.Tensor:
        """x, y positions [m]."""
        return self.states[..., :2]  # (B, T, N, 2)

    @property
    def batch_size(self) -> int:
        return int(self.states.shape[0])

    @property
    def num_steps(self) -> int:
        return int(self.states.shape[1])

    @property
    def num_agents(self) -> int:
        return int(self.states.shape[2])

    def to(self, device: torch.device | str) -> Batch:
        """A copy with every tensor on `device`."""
        return Batch(**{f.name: _move(getattr(self, f.name), device) for f in fields(self)})

    def with_agents(self, num_agents: int) -> Batch:
        """A copy with `num_agents` agent slots: the first ones kept, absent slots (zero states,
        invalid, attending to nobody, role 0, not focal) added after them."""
        return Batch(
            **{f.name: _resize(getattr(self, f.name), f.name, num_agents) for f in fields(self)}
        )


def _resize(tensor: torch.Tensor | None, name: str, num_agents: int) -> torch.Tensor | None:
    """`tensor` cut or padded to `num_agents` slots along its agent axis (if it has one)."""
    axis = AGENT_AXES.get(name)
    if tensor is None or axis is None:
        return tensor
    have = tensor.shape[axis]
    if num_agents <= have:
        return tensor.narrow(axis, 0, num_agents)
    shape = list(tensor.shape)
    shape[axis] = num_agents - have
    pad = torch.full(shape, PAD_VALUES.get(name, 0), dtype=tensor.dtype, device=tensor.device)
    return torch.cat([tensor, pad], axis)


def agent_counts(valid: torch.Tensor) -> torch.Tensor:
    """Agent slots each scene uses, (B,) int64 from valid (B, T, N): 1 + its last slot present
    at some step (1 for a scene with nobody present)."""
    slots = torch.arange(1, valid.shape[2] + 1)  # (N,)
    return torch.where(valid.any(1), slots, 0).amax(1).clamp(min=1)


def _move(tensor: torch.Tensor | None, device: torch.device | str) -> torch.Tensor | None:
    return None if tensor is None else tensor.to(device)


def collate_batch(items: Sequence[Batch]) -> Batch:
    """Concatenate batches (e.g. single scenes from the dataset) along the batch axis.

    All items must have the same T (true within one dataset split); items with fewer agent
    slots than the largest are padded with absent slots (`Batch.with_agents`).
    """
    if not items:
        raise ValueError("collate_batch needs at least one item")
    num_agents = max(item.num_agents for item in items)
    items = [item.with_agents(num_agents) for item in items]
    out = {}
    for f in fields(Batch):
        values = [getattr(item, f.name) for item in items]
        if any(v is None for v in values):
            out[f.name] = None
        else:
            out[f.name] = torch.cat(values, dim=0)
    return Batch(**out)


def batch_from_set(data: TrajectorySet) -> Batch:
    """All trajectories of a TrajectorySet as one Batch; states of absent agents are zeroed."""
    valid = torch.from_numpy(np.ascontiguousarray(data.valid))  # (B, T, N)
    states = torch.from_numpy(np.ascontiguousarray(data.states))  # (B, T, N, C)
    states = torch.where(valid[..., None], states, torch.zeros((), dtype=states.dtype))
    return Batch(
        states=states,
        valid=valid,
        attention=torch.from_numpy(data.attention.astype(np.int64)),  # (B, T, N)
        interaction=torch.from_numpy(np.ascontiguousarray(data.interaction)),  # (B, T)
        case=torch.from_numpy(data.case.astype(np.int64)),  # (B,)
        seed=torch.from_numpy(data.seed.astype(np.int64)),  # (B,)
        roles=torch.from_numpy(data.roles.astype(np.int64)),  # (B, N)
        focal=torch.from_numpy(np.ascontiguousarray(data.focal)),  # (B, N)
        index=torch.arange(len(data.valid)),  # (B,)
    )


class TrajectoryDataset(Dataset):
    """One split of a trajectory file, held in memory as tensors.

    Args:
        path: a trajectory file (schema 1 or 2).
        split: "train", "val" or "test".
        case: keep only this case (one of the file's case_names); None keeps all.
    Raises FormatError for an invalid file or an unknown case name. A split of fewer than
    MIN_AGENT_SLOTS agent slots is padded to that many (invalid, non-focal) slots.
    """

    def __init__(self, path: str | os.PathLike, split: str, case: str | None = None) -> None:
        self.path = os.fspath(path)
        self.split = split
        self.meta: DatasetMeta = read_meta(path)
        data = read_split(path, split)
        if case is not None:
            if case not in self.meta.case_names:
                raise FormatError(
                    f"{self.path}: unknown case {case!r}; valid cases: "
                    f"{', '.join(self.meta.case_names)}"
                )
            data = data.select_case(self.meta.case_names.index(case))
        if data.num_agents < MIN_AGENT_SLOTS:
            data = data.pad_agents(MIN_AGENT_SLOTS)
        self.case = case
        self.data: TrajectorySet = data  # numpy arrays, e.g. for plots and evaluation
        self._all = batch_from_set(data)
        self.agent_counts = agent_counts(self._all.valid)  # (n,) slots each scene uses

    def __len__(self) -> int:
        return self._all.batch_size

    def __getitem__(self, index: int) -> Batch:
        """Scene `index` as a Batch of size 1 with its own agent count (`agent_counts`)."""
        size = len(self)
        if not -size <= index < size:
            raise IndexError(f"index {index} out of range for {size} scenes")
        index = index % size
        scene = Batch(**{f.name: _slice(getattr(self._all, f.name), index) for f in fields(Batch)})
        return scene.with_agents(int(self.agent_counts[index]))

    def all(self) -> Batch:
        """Every scene of the dataset as one Batch, in file order, with the split's agent slots."""
        return self._all


def _slice(tensor: torch.Tensor | None, index: int) -> torch.Tensor | None:
    return None if tensor is None else tensor[index : index + 1]


class BucketBatchSampler(Sampler[list[int]]):
    """Batches of scenes with similar agent counts, every scene once per epoch.

    Each epoch takes the order `sampler` draws, sorts it stably by agent count, cuts it into
    batches of `batch_size` and yields them in the order of their earliest-drawn scene (each
    batch's scenes in drawn order). The batch order is thus as random as the draw and
    independent of crowd size, and no random number is drawn beyond the sampler's own. When
    every scene has the same count, the batches are exactly those of plain batching.
    """

    def __init__(self, sampler: Sampler[int], counts: Sequence[int], batch_size: int) -> None:
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.sampler = sampler
        self.counts = [int(c) for c in counts]
        self.batch_size = batch_size

    def __len__(self) -> int:
        return -(-len(self.counts) // self.batch_size)

    def __iter__(self) -> Iterator[list[int]]:
        order = list(self.sampler)  # scene indices in drawn order
        ranked = sorted(range(len(order)), key=lambda position: self.counts[order[position]])
        size = self.batch_size
        batches = [sorted(ranked[i : i + size]) for i in range(0, len(ranked), size)]
        for positions in sorted(batches, key=lambda batch: batch[0]):
            yield [order[position] for position in positions]


def make_loader(
    dataset: Dataset, batch_size: int, shuffle: bool, seed: int = 0, bucket: bool = False
) -> DataLoader:
    """A DataLoader yielding `Batch`es; shuffling is reproducible from `seed` alone.

    Two loaders made with the same seed give the same sequence of batches; successive epochs of
    one loader differ (its generator advances). No worker processes. `bucket`: batches of
    similar agent count (`BucketBatchSampler`; needs the dataset's `agent_counts`), drawing the
    same random numbers as plain batching.
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    generator = torch.Generator()
    generator.manual_seed(seed)
    shuffle = shuffle and len(dataset) > 0  # torch's RandomSampler rejects empty datasets
    if bucket:
        sampler = RandomSampler(dataset, generator=generator) if shuffle else None
        batches = BucketBatchSampler(
            sampler or SequentialSampler(dataset), dataset.agent_counts.tolist(), batch_size
        )
        return DataLoader(
            dataset,
            batch_sampler=batches,
            generator=generator,
            num_workers=0,
            collate_fn=collate_batch,
        )
    return DataLoader(
        dataset,
        batch_size=batch_size,
        shuffle=shuffle,
        generator=generator,
        num_workers=0,
        collate_fn=collate_batch,
        drop_last=False,
    )
