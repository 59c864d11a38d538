"""The words output uses for a data file's agents and scenes: simulated scenes and their main
cars, or windows of a recording and their focal agents."""

from __future__ import annotations

from dataclasses import dataclass

from trajectory_data.format import DatasetMeta


@dataclass(frozen=True)
class Wording:
    """The words output uses for a file's agents and scenes: simulated scenes record attention
    labels and score their two main cars; imported recordings are cut into windows that score
    their focal agents (pedestrians, vehicles)."""

    agents: str  # the scored agents, e.g. "main agents"
    scenes: str  # e.g. "scenes"
    labelled: str  # the agent an attending agent's label names, e.g. "labelled car"

    @staticmethod
    def of(meta: DatasetMeta) -> Wording:
        if meta.has("attention"):
            return Wording("main agents", "scenes", "labelled car")
        return Wording("focal agents", "windows", "labelled agent")
