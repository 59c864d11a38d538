"""Torch access to a trajectory file: an in-memory `TrajectoryDataset` and named `Batch`es.

A dataset holds one split (optionally one case) of a trajectory file (schema 1 or 2), read and
validated through `predictor.format`. `dataset[i]` is a `Batch` of one scene (batch size 1);
`collate_batch` concatenates such items along the batch axis. Layout is `[B, T, N, F]`,
time-major per scene.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, fields

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from predictor.format import DatasetMeta, FormatError, TrajectorySet, read_meta, read_split

# agent slots a dataset has at least: the model builds the N(N-1) directed edges between slots
# and fails on a split of one slot (no edges, e.g. ETH/UCY windows of one pedestrian), so such
# a split gets an invalid, non-focal second slot, which changes no prediction and no metric
MIN_AGENT_SLOTS = 2


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


def _move(tensor: torch.Tensor | None, device: torch.device | str) -> torch.Tensor | None:
    return None if tensor is None else tensor.to(device)


def collate_batch(items: Sequence[Batch]) -> Batch:
    """Concatenate batches (e.g. single scenes from the dataset) along the batch axis.

    All items must have the same T and N (true within one dataset split).
    """
    if not items:
        raise ValueError("collate_batch needs at least one item")
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

    def __len__(self) -> int:
        return self._all.batch_size

    def __getitem__(self, index: int) -> Batch:
        """Scene `index` as a Batch of size 1."""
        size = len(self)
        if not -size <= index < size:
            raise IndexError(f"index {index} out of range for {size} scenes")
        index = index % size
        return Batch(**{f.name: _slice(getattr(self._all, f.name), index) for f in fields(Batch)})

    def all(self) -> Batch:
        """Every scene of the dataset as one Batch, in file order."""
        return self._all


def _slice(tensor: torch.Tensor | None, index: int) -> torch.Tensor | None:
    return None if tensor is None else tensor[index : index + 1]


def make_loader(dataset: Dataset, batch_size: int, shuffle: bool, seed: int = 0) -> DataLoader:
    """A DataLoader yielding `Batch`es; shuffling is reproducible from `seed` alone.

    Two loaders made with the same seed give the same sequence of batches; successive epochs of
    one loader differ (its generator advances). No worker processes.
    """
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    generator = torch.Generator()
    generator.manual_seed(seed)
    shuffle = shuffle and len(dataset) > 0  # torch's RandomSampler rejects empty datasets
    return DataLoader(
        dataset,
        batch_size=batch_size,
        shuffle=shuffle,
        generator=generator,
        num_workers=0,
        collate_fn=collate_batch,
        drop_last=False,
    )
