"""One registry of predictors: the paper's trained variants and the baselines, each with its
name, label, colour, role in the report and what builds it. Command-line choices, the
reproduction's variants, report labels, statistics and figures all derive from `PREDICTORS`,
so adding a variant or a baseline is one entry here.

| role       | meaning in the report                                              |
|------------|--------------------------------------------------------------------|
| `ours`     | the method: every statistic compares with it                       |
| `rival`    | a trained variant compared with Ours (Welch's t-test)              |
| `baseline` | an untrained reference, evaluated once per setting                 |
| `oracle`   | an untrained reference that reads the ground-truth label: the bar  |
| `""`       | available to tools/evaluate.py, not run by the reproduction        |
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Variant:
    """What a trained variant fixes in its configs: the attention mode (learned, uniform or
    oracle), whether it trains with the sequence loss, and whether it is smooth (False forces
    beta2 = 0)."""

    attention_mode: str
    sequence_loss: bool
    smooth: bool


@dataclass(frozen=True)
class Predictor:
    """One registry entry: a trained variant (`variant` set) or a baseline (`ridge` set for a
    ridge regression, both None for constant velocity)."""

    name: str
    label: str  # how tables and figures name it
    color: str  # its colour in figures
    role: str  # "ours", "rival", "baseline", "oracle" or "" (see the module docstring)
    variant: Variant | None = None
    ridge: dict[str, Any] | None = None  # predictor.baselines.RidgeConfig fields
    compared_with: tuple[str, ...] = ()  # further Welch comparisons of this one with others

    @property
    def trained(self) -> bool:
        return self.variant is not None

    @property
    def learns_attention(self) -> bool:
        """Whether it has a learned attention whose accuracy the report scores."""
        return self.variant is not None and self.variant.attention_mode == "learned"


PREDICTORS: tuple[Predictor, ...] = (
    Predictor("ours", "Ours", "#ff7f0e", "ours", Variant("learned", True, smooth=True)),
    Predictor("s_attn", "S-Attn", "#1f77b4", "rival", Variant("learned", False, smooth=False)),
    Predictor(
        "nonsmooth", "Ours-NonSmooth", "#2ca02c", "rival", Variant("learned", True, smooth=False)
    ),
    Predictor("average", "Ours-Average", "#9467bd", "rival", Variant("uniform", True, False)),
    Predictor(
        "correct",
        "Ours-Correct",
        "#d62728",
        "rival",
        Variant("oracle", True, smooth=False),
        # the oracle attention against the uniform one: does the interaction pathway carry
        # information?
        compared_with=("average",),
    ),
    Predictor("const_vel", "Const-Vel", "#7f7f7f", "baseline"),
    Predictor("ridge", "Ridge", "#8c564b", "baseline", ridge={"neighbours": "none"}),
    Predictor("ridge_nearest", "Ridge+nearest", "#e377c2", "", ridge={"neighbours": "nearest"}),
    Predictor(
        "ridge_labelled",
        "Ridge+label (oracle)",
        "#bcbd22",
        "oracle",
        ridge={"neighbours": "labelled"},
    ),
    Predictor("ridge_random", "Ridge+random", "#aec7e8", "", ridge={"neighbours": "random"}),
    Predictor(
        "ridge_labelled_relation",
        "Ridge+label per relation (oracle)",
        "#17becf",
        "oracle",
        ridge={"neighbours": "labelled", "groups": "relation"},
    ),
)
BY_NAME: dict[str, Predictor] = {entry.name: entry for entry in PREDICTORS}

# what the rest of the code reads, all derived from PREDICTORS
VARIANTS: dict[str, Variant] = {e.name: e.variant for e in PREDICTORS if e.variant is not None}
TRAINED: tuple[str, ...] = tuple(VARIANTS)  # the reproduction's canonical order
BASELINES: tuple[str, ...] = tuple(e.name for e in PREDICTORS if not e.trained)
RIDGE_BASELINES: dict[str, dict[str, Any]] = {
    e.name: e.ridge for e in PREDICTORS if e.ridge is not None
}
REPORTED_BASELINES: tuple[str, ...] = tuple(
    e.name for e in PREDICTORS if not e.trained and e.role in ("baseline", "oracle")
)
ORACLE_BASELINES: tuple[str, ...] = tuple(e.name for e in PREDICTORS if e.role == "oracle")
OURS: str = next(e.name for e in PREDICTORS if e.role == "ours")
RIVALS: tuple[str, ...] = tuple(e.name for e in PREDICTORS if e.role == "rival")
# every (first, other) pair the report tests: Ours against each rival, then the extra ones
PAIRS: tuple[tuple[str, str], ...] = (
    *((OURS, rival) for rival in RIVALS),
    *((e.name, other) for e in PREDICTORS for other in e.compared_with),
)
LABELS: dict[str, str] = {e.name: e.label for e in PREDICTORS}
COLORS: dict[str, str] = {e.name: e.color for e in PREDICTORS}
FIXED_ATTENTION: tuple[str, ...] = tuple(e.name for e in PREDICTORS if not e.learns_attention)
