"""Tests for trajectory_data.torch_dataset: dataset sizes, Batch layout, collation and
deterministic loading."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import make_meta, make_trajectory_set

from trajectory_data.format import FormatError, TrajectorySet, write_dataset
from trajectory_data.torch_dataset import Batch, TrajectoryDataset, collate_batch, make_loader

torch.set_num_threads(1)


def test_length_per_split_and_case(dataset_file: Path) -> None:
    # counts (6, 3, 4), cases alternate major, minor, major, ...
    expected = {"train": (6, 3, 3), "val": (3, 2, 1), "test": (4, 2, 2)}
    for split, (total, major, minor) in expected.items():
        assert len(TrajectoryDataset(dataset_file, split)) == total
        assert len(TrajectoryDataset(dataset_file, split, case="major")) == major
        minor_set = TrajectoryDataset(dataset_file, split, case="minor")
        assert len(minor_set) == minor
        assert (minor_set.all().case == 1).all()


def test_unknown_case_lists_valid_names(dataset_file: Path) -> None:
    with pytest.raises(FormatError, match="unknown case 'rare'; valid cases: major, minor"):
        TrajectoryDataset(dataset_file, "train", case="rare")


def test_empty_split_has_length_zero(make_dataset_file) -> None:
    path = make_dataset_file(counts=(4, 0, 2))
    dataset = TrajectoryDataset(path, "val")
    assert len(dataset) == 0
    assert list(make_loader(dataset, batch_size=2, shuffle=True, seed=0)) == []


def test_item_is_one_scene_with_contract_dtypes(dataset_file: Path) -> None:
    dataset = TrajectoryDataset(dataset_file, "train")
    source = dataset.data
    item = dataset[4]
    assert isinstance(item, Batch)
    assert (item.batch_size, item.num_steps, item.num_agents) == (1, 10, 4)
    assert item.states.shape == (1, 10, 4, 4) and item.states.dtype == torch.float32
    assert item.valid.shape == (1, 10, 4) and item.valid.dtype == torch.bool
    assert item.attention.shape == (1, 10, 4) and item.attention.dtype == torch.int64
    assert item.interaction.shape == (1, 10) and item.interaction.dtype == torch.bool
    assert item.case.shape == (1,) and item.case.dtype == torch.int64
    assert item.seed.dtype == torch.int64 and item.roles.shape == (1, 4)
    np.testing.assert_array_equal(item.states[0].numpy(), source.states[4])
    np.testing.assert_array_equal(item.attention[0].numpy(), source.attention[4])
    assert item.seed.item() == source.seed[4]
    assert torch.equal(item.positions, item.states[..., :2])
    assert torch.equal(dataset[-1].seed, dataset[5].seed)
    with pytest.raises(IndexError):
        dataset[6]


def test_absent_agents_have_zero_states(tmp_path: Path) -> None:
    meta = make_meta()
    data = make_trajectory_set(3, meta.num_steps)
    states = data.states.copy()
    states[~data.valid] = np.nan  # allowed by the format where invalid
    data = TrajectorySet(**{**data.arrays(), "states": states})
    path = write_dataset(tmp_path / "nan.h5", meta, {"train": data})
    batch = TrajectoryDataset(path, "train").all()
    assert torch.isfinite(batch.states).all()
    assert (batch.states[~batch.valid] == 0).all()


def test_collate_and_to(dataset_file: Path) -> None:
    dataset = TrajectoryDataset(dataset_file, "train")
    batch = collate_batch([dataset[2], dataset[0], dataset[5]])
    assert (batch.batch_size, batch.num_steps, batch.num_agents) == (3, 10, 4)
    assert batch.positions.shape == (3, 10, 4, 2)
    np.testing.assert_array_equal(batch.seed.numpy(), dataset.data.seed[[2, 0, 5]])
    moved = batch.to("cpu")
    assert isinstance(moved, Batch) and moved.states.device.type == "cpu"
    assert torch.equal(moved.states, batch.states) and torch.equal(moved.roles, batch.roles)


def _seed_order(loader) -> list[int]:
    return [int(s) for batch in loader for s in batch.seed]


def test_loader_is_deterministic_per_seed(dataset_file: Path) -> None:
    dataset = TrajectoryDataset(dataset_file, "train")
    all_seeds = sorted(int(s) for s in dataset.data.seed)
    first = _seed_order(make_loader(dataset, batch_size=4, shuffle=True, seed=3))
    again = _seed_order(make_loader(dataset, batch_size=4, shuffle=True, seed=3))
    assert first == again
    assert sorted(first) == all_seeds  # every scene exactly once
    orders = {tuple(_seed_order(make_loader(dataset, 4, True, seed))) for seed in range(4, 10)}
    assert len(orders | {tuple(first)}) > 1  # other seeds shuffle differently
    batches = list(make_loader(dataset, batch_size=4, shuffle=False, seed=0))
    assert [b.batch_size for b in batches] == [4, 2]
    assert _seed_order(batches) == [int(s) for s in dataset.data.seed]


def crowd_file(tmp_path: Path, counts: list[int], num_agents: int = 6) -> Path:
    """A train split whose scene k uses agent slots 0 .. counts[k]-1 (the rest never present)."""
    meta = make_meta()
    data = make_trajectory_set(len(counts), meta.num_steps, num_agents, seed=5)
    valid, states = data.valid.copy(), data.states.copy()
    for scene, count in enumerate(counts):
        valid[scene, :, count:] = False
        valid[scene, 0, :count] = True  # every used slot present at least once
    states[~valid] = 0.0
    data = TrajectorySet(**{**data.arrays(), "valid": valid, "states": states})
    return write_dataset(tmp_path / "crowd.h5", meta, {"train": data})


def test_items_have_their_own_agent_count_and_batches_pad_to_their_largest(
    tmp_path: Path,
) -> None:
    dataset = TrajectoryDataset(crowd_file(tmp_path, [2, 6, 3, 1, 4]), "train")
    assert dataset.agent_counts.tolist() == [2, 6, 3, 1, 4]
    assert dataset.all().num_agents == 6  # the whole split keeps the split's slots
    assert [dataset[k].num_agents for k in range(5)] == [2, 6, 3, 1, 4]
    batch = collate_batch([dataset[0], dataset[2]])
    assert batch.num_agents == 3
    full = dataset.all()
    for row, (scene, used) in enumerate([(0, 2), (2, 3)]):  # used slots as in the file
        for name in ("states", "valid", "attention"):
            got, want = getattr(batch, name)[row], getattr(full, name)[scene]
            assert torch.equal(got[:, :used], want[:, :used]), name
        assert torch.equal(batch.roles[row, :used], full.roles[scene, :used])
        assert torch.equal(batch.focal[row, :used], full.focal[scene, :used])
    # scene 0's padded third slot: absent, attending to nobody, zero, role 0, not focal
    assert not batch.valid[0, :, 2].any() and (batch.attention[0, :, 2] == -1).all()
    assert (batch.states[0, :, 2] == 0).all() and not batch.focal[0, 2] and batch.roles[0, 2] == 0


def _index_batches(loader) -> list[list[int]]:
    return [batch.index.tolist() for batch in loader]


def test_bucketing_covers_every_scene_once_in_batches_of_similar_count(tmp_path: Path) -> None:
    counts = [1, 6, 2, 6, 3, 5, 1, 4, 2, 6, 3]
    dataset = TrajectoryDataset(crowd_file(tmp_path, counts), "train")
    loader = make_loader(dataset, batch_size=3, shuffle=True, seed=4, bucket=True)
    epochs = [_index_batches(loader) for _ in range(3)]
    assert len(loader) == 4
    for batches in epochs:
        assert sorted(i for batch in batches for i in batch) == list(range(len(counts)))
        assert [len(b) for b in batches].count(3) == 3  # one short batch of 2
        spans = sorted((min(counts[i] for i in b), max(counts[i] for i in b)) for b in batches)
        for (_, high), (low, _) in zip(spans, spans[1:]):
            assert high <= low  # batches cut from the count-sorted order
    assert len({tuple(map(tuple, b)) for b in epochs}) > 1  # epochs differ
    again = make_loader(dataset, batch_size=3, shuffle=True, seed=4, bucket=True)
    assert [_index_batches(again) for _ in range(3)] == epochs  # deterministic per seed
    other = make_loader(dataset, batch_size=3, shuffle=True, seed=5, bucket=True)
    assert _index_batches(other) != epochs[0]
    for batch in make_loader(dataset, batch_size=3, shuffle=True, seed=4, bucket=True):
        assert batch.num_agents == max(counts[i] for i in batch.index.tolist())


def test_bucketing_with_equal_counts_gives_the_plain_batches(dataset_file: Path) -> None:
    """Every scene of the conftest file uses its 4 slots: bucketed batches are those of a plain
    shuffled torch DataLoader with the same seed, epoch after epoch."""
    dataset = TrajectoryDataset(dataset_file, "train")
    assert set(dataset.agent_counts.tolist()) == {4}
    for seed in (0, 3):
        plain = torch.utils.data.DataLoader(
            range(len(dataset)),
            batch_size=4,
            shuffle=True,
            generator=torch.Generator().manual_seed(seed),
        )
        bucketed = make_loader(dataset, batch_size=4, shuffle=True, seed=seed, bucket=True)
        for _ in range(3):
            expected = [batch.tolist() for batch in plain]
            got = list(bucketed)
            assert [b.index.tolist() for b in got] == expected
            for batch, indices in zip(got, expected, strict=True):
                assert torch.equal(batch.states, dataset.all().states[indices])
        assert torch.equal(bucketed.generator.get_state(), plain.generator.get_state())
