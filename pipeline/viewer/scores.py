"""Per-scene and overall scores for the viewer's scene list, with the project's own metrics.

Each scene's ADE/FDE is `predictor.metrics.displacement_metrics` of the main (focal) agents with
the scene as its own "case", so a scene's number is exactly what the evaluation would report
for a file holding that scene alone; its attention accuracy is `attention_hits`' hits over
counted pairs (None where nothing counts or the scene's attention is NaN, as for a baseline).
The overall line is `headline` of the same metrics over the shown scenes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from predictor.metrics import (
    attention_accuracy,
    attention_hits,
    displacement_metrics,
    headline,
    prediction_mask,
)
from predictor.predictions import Predictions


@dataclass(frozen=True)
class SceneScores:
    """Scores of each shown scene (None where undefined) and the headline over all of them."""

    ade: list[float | None]  # main agents [m]
    fde: list[float | None]  # main agents [m]
    accuracy: list[float | None]  # attention accuracy, share of counted (step, agent) pairs
    headline: str


def scene_scores(pred: Predictions) -> SceneScores:
    """ADE/FDE of the main agents and attention accuracy of every scene of `pred`."""
    names = [str(k) for k in range(pred.n)]
    scene = np.arange(pred.n)
    args = (
        pred.pred_mean,
        pred.true_xy[:, pred.num_observed :],
        prediction_mask(pred.valid, pred.num_observed),
    )
    per_scene = displacement_metrics(*args, scene, names, pred.focal)["main_agents"]["cases"]
    hits, counts, _ = attention_hits(
        pred.attention, pred.attention_label, pred.interaction, pred.valid, pred.num_observed
    )
    undefined = np.isnan(pred.attention).reshape(pred.n, -1).any(axis=1)
    accuracy = [
        None if undefined[k] or counts[k] == 0 else float(hits[k] / counts[k])
        for k in range(pred.n)
    ]
    overall = displacement_metrics(*args, pred.case, pred.case_names, pred.focal)
    overall["attention_accuracy"] = attention_accuracy(
        pred.attention,
        pred.attention_label,
        pred.interaction,
        pred.valid,
        pred.num_observed,
        pred.case,
        pred.case_names,
    )
    return SceneScores(
        ade=[per_scene[name]["ade"] for name in names],
        fde=[per_scene[name]["fde"] for name in names],
        accuracy=accuracy,
        headline=headline(overall),
    )
