"""The data a viewer page carries: a JSON description (`spec`) and the packed arrays.

Arrays (n shown scenes, T steps, N agent slots, P = T - num_observed predicted steps; the names
the page's script reads):

| name | type | shape | what |
|---|---|---|---|
| `xy` | float32 | (n, T, N, 2) | true positions [m], exactly the dataset's |
| `valid` | uint8 | (n, T, N) | agent present |
| `focal` | uint8 | (n, N) | scored ("main") agents |
| `roles` | uint8 | (n, N) | index into role_names |
| `label` | int16 | (n, T, N) | labelled attended agent, -1 none |
| `interaction` | uint8 | (n, T) | inside the interaction period |
| `heading` | float32 | (n, T, N) | [rad], where the states have a heading channel |
| `pred` | float32 | (n, P, N, 2) | predicted mean [m], with predictions |
| `attention` | uint16 | (n, T-1, N, N) | weight of i on j computed at t, `pack.quantize_unit` |
| `samples` | float32 | (n, S, P, N, 2) | predicted samples [m], where the predictions hold them |
| `influence` | float32 | (n, T-1, N, N) | influence of j on i at t, where the predictions hold it |

`samples` are the predictions' first `SHOWN_SAMPLES` sampled futures, where they hold any
(`tools/evaluate.py --samples K`). No predictions file holds an influence matrix yet: `influence`
is taken from an attribute of that name on the predictions when it exists. The page draws each
only when present.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pipeline.viewer.inputs import Shown
from pipeline.viewer.pack import quantize_unit
from pipeline.viewer.roads import road_of
from pipeline.viewer.scores import scene_scores
from predictor.plots import role_color

SPEC_FORMAT = "smooth-attention-viewer"
SPEC_VERSION = 1
SHOWN_SAMPLES = 6  # sampled futures per scene the page carries (a predictions file has up to K)


def scene_arrays(shown: Shown) -> dict[str, np.ndarray]:
    """The arrays of the shown scenes, in the page's layout (see the module docstring)."""
    data = shown.data
    arrays = {
        "xy": data.states[..., :2].astype(np.float32),
        "valid": data.valid.astype(np.uint8),
        "focal": data.focal.astype(np.uint8),
        "roles": data.roles.astype(np.uint8),
        "label": data.attention.astype(np.int16),
        "interaction": data.interaction.astype(np.uint8),
    }
    heading = shown.meta.state_index("heading")
    if heading is not None:
        arrays["heading"] = data.states[..., heading].astype(np.float32)
    pred = shown.predictions
    if pred is not None:
        arrays["pred"] = pred.pred_mean.astype(np.float32)
        arrays["attention"] = quantize_unit(pred.attention)
        if pred.num_samples:  # the first SHOWN_SAMPLES: 20 would make the page ~4x larger
            arrays["samples"] = pred.samples[:, :SHOWN_SAMPLES].astype(np.float32)
        influence = getattr(pred, "influence", None)  # optional: no predictions file holds it yet
        if influence is not None:
            arrays["influence"] = np.asarray(influence, dtype=np.float32)
    return arrays


def page_spec(shown: Shown, title: str | None = None) -> dict:
    """The JSON description of the page (everything but the arrays' bytes)."""
    meta, pred = shown.meta, shown.predictions
    scenes: dict = {
        "row": [int(r) for r in shown.rows],
        "case": [int(c) for c in shown.data.case],
        "ade": None,
        "fde": None,
        "accuracy": None,
    }
    headline = None
    if pred is not None:
        scores = scene_scores(pred)
        scenes.update(ade=scores.ade, fde=scores.fde, accuracy=scores.accuracy)
        headline = scores.headline
    default_title = f"{meta.scenario}, {shown.split} split" + (
        f": {pred.predictor}" if pred is not None else ""
    )
    return {
        "format": SPEC_FORMAT,
        "version": SPEC_VERSION,
        "title": title or default_title,
        "source": {
            "data": Path(shown.data_path).name,
            "split": shown.split,
            "predictions": Path(shown.predictions_path).name if shown.predictions_path else None,
            "predictor": pred.predictor if pred is not None else None,
            "run": shown.run.text() if shown.run is not None else None,
        },
        "scenario": meta.scenario,
        "dt": meta.dt,
        "num_observed": meta.num_observed,
        "num_steps": shown.data.num_steps,
        "num_agents": shown.data.num_agents,
        "case_names": list(meta.case_names),
        "role_names": list(meta.role_names),
        "role_colors": [role_color(name, k) for k, name in enumerate(meta.role_names)],
        "road": road_of(meta),
        "labels_recorded": meta.has("attention"),
        "scenes": scenes,
        "headline": headline,
        "shown": shown.n,
        "available": shown.available,
        "left_out": left_out_note(shown),
    }


def left_out_note(shown: Shown) -> str | None:
    """What thinning left out, in words (None if nothing)."""
    if shown.left_out == 0:
        return None
    return (
        f"shows the first {shown.n} of {shown.available} scenes; "
        f"{shown.left_out} left out (max_scenes {shown.n})"
    )
