"""Checkpoint names (predictor.model.state_names): a model's parts' tensors are written and
read under their names within their parts, the part-qualified names are read too, and missing
tensors are reported by their checkpoint names."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from predictor.model.state_names import checkpoint_names, use_checkpoint_names


class Encoder(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.f_embed = nn.Sequential(nn.Linear(2, 3), nn.ReLU())
        self.register_buffer("input_std", torch.ones(2))


class Toy(nn.Module):
    """Two parts (one absent) and a tensor of its own."""

    def __init__(self) -> None:
        super().__init__()
        self.scale = nn.Parameter(torch.ones(1))
        self.encoder = Encoder()
        self.highway = None
        self.f_pred = nn.Linear(3, 2)  # a child that is not a part: keeps its names
        use_checkpoint_names(self, ("encoder", "highway"))


def test_parts_are_written_without_the_part_and_in_order():
    model = Toy()
    assert list(model.state_dict()) == [
        "scale",
        "input_std",  # a module's own tensors come before its children's
        "f_embed.0.weight",
        "f_embed.0.bias",
        "f_pred.weight",
        "f_pred.bias",
    ]
    assert checkpoint_names(model, ("encoder", "highway")) == {
        "encoder.f_embed.0.weight": "f_embed.0.weight",
        "encoder.f_embed.0.bias": "f_embed.0.bias",
        "encoder.input_std": "input_std",
    }


def test_checkpoint_names_and_part_qualified_names_both_load():
    source, target = Toy(), Toy()
    with torch.no_grad():
        source.encoder.input_std.fill_(3.0)
        source.encoder.f_embed[0].weight.fill_(0.5)
    target.load_state_dict(source.state_dict())
    assert torch.equal(target.encoder.input_std, torch.full((2,), 3.0))
    qualified = {name: value for name, value in source.named_parameters()}
    qualified["encoder.input_std"] = torch.full((2,), 4.0)
    target.load_state_dict(qualified)
    assert torch.equal(target.encoder.input_std, torch.full((2,), 4.0))
    assert torch.equal(target.encoder.f_embed[0].weight, torch.full((3, 2), 0.5))


def test_missing_and_unexpected_tensors_are_named_as_in_checkpoints():
    model = Toy()
    state = model.state_dict()
    del state["input_std"]
    state["highway_weight"] = torch.zeros(1)
    with pytest.raises(RuntimeError) as error:
        model.load_state_dict(state)
    message = str(error.value)
    assert 'Missing key(s) in state_dict: "input_std"' in message
    assert 'Unexpected key(s) in state_dict: "highway_weight"' in message
    assert "encoder." not in message


def test_parts_with_tensors_of_one_name_are_refused():
    class Twice(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.first, self.second = Encoder(), Encoder()
            use_checkpoint_names(self, ("first", "second"))

    with pytest.raises(ValueError, match="the same name"):
        Twice()
