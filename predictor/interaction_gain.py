"""Interaction gain: does observing the labelled car make an attending car's future predictable?

A synthetic interaction benchmark is useful only if the attended car's observed state decides
something of the attending car's future. This module measures it with the ridge baseline
(predictor.baselines): for every attending agent (one whose attention label is set at some step
of its scene), the test ADE of ridge regressions fitted on the training split with

- `own`: the agent's own history only,
- `labelled`: plus the history of the agent its label names (oracle; where the label moves from
  car to car during a scene, of every agent it names, `predictor.label_slots.attended_agents`),
- `random`: plus the history of as many random other agents (the control; with
  `control="distractor"` random agents of the role "distractor", with `control="shuffled"` the
  labelled agents' histories from another scene, a null control that carries nothing about the
  scene: it measures what fitting such features costs at the file's size),

per case and role. `gain` = 1 - labelled / own (how much the attended car explains); `control`
= random / own - 1 (what any extra car does). A scenario whose labels are causal and observable
shows a large gain and a control near zero.

The ridge baseline fits one regression per agent role (`RidgeConfig.groups` "role"). In Double
Merge a colour is the rear car in one case and the front car in the other, and one linear map per
colour cannot read the other car both ways; at the paper's size (40 major + 12 minor training
scenes) the minor case's few scenes are drowned by the major case's. "relation" fits the
attending agents' regressions per relation to the labelled agent instead (ahead of it or behind
it at the last observed step, `predictor.baselines.relation_groups`), pooling the roles: the
three regressions (own, labelled, random) get the same groups, so the gain still measures only
what the labelled car's *history* adds. "case" fits one regression per role and case (the
case read from the data, an oracle gate like the label): set beside "role", it says how much of
a scenario's error is not knowing the case, which a linear map of the history cannot infer.

`penalty` "banded" gives the other car's features a ridge penalty of their own, chosen by the
same cross-validation (`RidgeConfig.neighbour_scales`): with one shared penalty, 27 features
that carry nothing cost a few per cent of accuracy on the paper's 52 training scenes, which the
control then reads as if the random car carried (negative) information.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from predictor.baselines import BANDED_SCALES, RidgeBaseline, RidgeConfig
from predictor.metrics import prediction_mask
from trajectory_data.reader import read_meta, read_split

MODES = ("none", "labelled", "random")  # RidgeConfig.neighbours of own, labelled, random
# RidgeConfig.neighbours of the control (GainRow.random)
CONTROLS = ("random", "shuffled", "distractor")
PENALTIES = {"shared": (1.0,), "banded": BANDED_SCALES}  # -> RidgeConfig.neighbour_scales


@dataclass(frozen=True)
class GainRow:
    """Ridge test ADE [m] of the attending agents of one (case, role)."""

    case: str
    role: str
    agents: int  # attending (scene, agent) pairs scored
    own: float
    labelled: float
    random: float  # with the control of `interaction_gain` (a random car by default)

    @property
    def gain(self) -> float:
        """Relative ADE reduction by the labelled car's history (0.3 = 30 % lower)."""
        return 1.0 - self.labelled / self.own

    @property
    def control(self) -> float:
        """Relative ADE change by a random car's history (ideally near 0)."""
        return self.random / self.own - 1.0


def interaction_gain(
    data_path: str | os.PathLike,
    split: str = "test",
    fit_split: str = "train",
    grouping: str = "role",
    penalty: str = "shared",
    control: str = "random",
) -> list[GainRow]:
    """Gain rows of every (case, role) with attending agents in `split`, ridge fitted on
    `fit_split` with one regression per `grouping` (`RidgeConfig.groups`), the other car's
    features penalised as `penalty` says (`PENALTIES`), and `control` (`CONTROLS`) as the
    control's neighbour. Raises ValueError if the file has no attention labels in `split`, or
    for an unknown grouping, penalty or control."""
    if penalty not in PENALTIES:
        raise ValueError(f"penalty must be one of {', '.join(PENALTIES)}, got {penalty!r}")
    if control not in CONTROLS:
        raise ValueError(f"control must be one of {', '.join(CONTROLS)}, got {control!r}")
    meta = read_meta(data_path)
    fit, data = read_split(data_path, fit_split), read_split(data_path, split)
    attending = (data.attention >= 0).any(axis=1)  # (n, N)
    if not attending.any():
        raise ValueError(f"{data_path}: no agent of the {split} split has an attention label")
    mask = prediction_mask(data.valid, meta.num_observed)  # (n, P, N)
    truth = data.states[:, meta.num_observed :, :, :2]
    ade = {}
    random_role = None
    if control == "distractor":
        if "distractor" not in meta.role_names:
            raise ValueError(f"{data_path}: no agent role named distractor for the control")
        random_role = meta.role_names.index("distractor")
    for mode in MODES:
        neighbours = mode
        if mode == "random":
            neighbours = "random" if control == "distractor" else control
        config = RidgeConfig(
            neighbours=neighbours,
            groups=grouping,
            neighbour_scales=PENALTIES[penalty],
            random_role=random_role if mode == "random" else None,
        )
        ridge = RidgeBaseline(config).fit_set(fit, meta)
        pred = ridge.predict_set(data, meta)
        error = np.where(mask, np.linalg.norm(pred - truth, axis=-1), 0.0)  # (n, P, N)
        ade[mode] = (error.sum(axis=1), mask.sum(axis=1))  # (n, N) each
    rows = []
    for c, case in enumerate(meta.case_names):
        for r, role in enumerate(meta.role_names):
            chosen = attending & (data.case == c)[:, None] & (data.roles == r)
            if not (chosen & (mask.sum(axis=1) > 0)).any():
                continue
            means = {
                mode: float(total[chosen].sum() / count[chosen].sum())
                for mode, (total, count) in ade.items()
            }
            agents = int(chosen.sum())
            rows.append(
                GainRow(case, role, agents, means["none"], means["labelled"], means["random"])
            )
    return rows


def format_gain_table(rows: list[GainRow], control: str = "random") -> str:
    """Plain-text table of the rows, whose control was `control` (`CONTROLS`)."""
    header = (
        f"{'case':<10}{'role':<14}{'agents':>7}{'own [m]':>10}{'+label [m]':>12}"
        f"{f'+{control} [m]':>15}{'gain':>8}{'control':>9}"
    )
    lines = [header, "-" * len(header)]
    for row in rows:
        lines.append(
            f"{row.case:<10}{row.role:<14}{row.agents:>7}{row.own:>10.3f}{row.labelled:>12.3f}"
            f"{row.random:>15.3f}{row.gain:>8.0%}{row.control:>+9.1%}"
        )
    return "\n".join(lines)
