"""The reproduction's protocol: the paper's settings, setting groups, variants and seed counts.

What a reproduction runs is a `Protocol` (settings, variants, seeds, epochs, preset, and the
presets compared with it); the
settings are the paper's Sec. V experiments. pipeline.reproduction runs a protocol, and
tools/reproduce.py builds one from its arguments (`pick` reads the comma lists).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

from predictor.presets import DEFAULT_PRESET
from predictor.registry import REPORTED_BASELINES, TRAINED

TRAINED_VARIANTS = TRAINED  # predictor.registry, in its order
ALL_VARIANTS = (*TRAINED_VARIANTS, *REPORTED_BASELINES)
DATA_SEED = 0  # one dataset per setting, fixed: seeds vary only the training
NUM_TEST = 50  # test trajectories per case (paper)
PAPER_EPOCHS, PAPER_SEEDS = 200, 10
QUICK_EPOCHS, QUICK_SEEDS, QUICK_NUM_TEST = 1, 2, 5
QUICK_MAX_MAJOR = 10  # a quick protocol shrinks every setting to at most 10 major trajectories
QUICK_MIN_MINOR = 2
# A reproduction without arguments: this project's model (the agent preset, docs/PREDICTOR.md)
# on every setting, and the paper's literal model beside it on the main settings.
REPRODUCTION_PRESET = DEFAULT_PRESET
REPRODUCTION_COMPARED = "paper@main"


class ReproductionError(ValueError):
    """A reproduction cannot use its inputs or its cache; the message is one line."""


# The settings use the v1 scenarios (docs/scenarios.md: there the labelled car's observed state
# decides the attending car's future), by exact version name: the published results are on v1.


@dataclass(frozen=True)
class Setting:
    """One experimental setting: a scenario, its major case and its training-pool sizes."""

    name: str
    scenario: str  # a version name (scenarios.VERSIONS)
    major_case: str
    num_major: int  # major-case trajectories, training + validation
    num_minor: int  # minor-case trajectories, training + validation
    group: str  # "ratio", "size" or "halting": the paper figure it belongs to
    title: str


SETTINGS = (
    Setting(
        "dm_r0.3", "double_merge_v1", "major", 50, 15, "ratio", "Double Merge, minor ratio 0.3"
    ),
    Setting(
        "dm_r0.8", "double_merge_v1", "major", 50, 40, "ratio", "Double Merge, minor ratio 0.8"
    ),
    Setting(
        "dm_3+10", "double_merge_v1", "major", 10, 3, "size", "Double Merge, 3 minor + 10 major"
    ),
    Setting(
        "dm_15+30", "double_merge_v1", "major", 30, 15, "size", "Double Merge, 15 minor + 30 major"
    ),
    Setting(
        "dm_30+100",
        "double_merge_v1",
        "major",
        100,
        30,
        "size",
        "Double Merge, 30 minor + 100 major",
    ),
    Setting(
        "hc_stop",
        "halting_car_v1",
        "stop",
        50,
        15,
        "halting",
        "Halting Car, stop major, minor ratio 0.3",
    ),
    Setting(
        "hc_go", "halting_car_v1", "go", 50, 15, "halting", "Halting Car, go major, minor ratio 0.3"
    ),
)
SETTING_BY_NAME = {s.name: s for s in SETTINGS}
GROUPS = {
    "main": ("dm_r0.3", "hc_stop"),
    "ratio": tuple(s.name for s in SETTINGS if s.group == "ratio"),
    "size": tuple(s.name for s in SETTINGS if s.group == "size"),
    "halting": tuple(s.name for s in SETTINGS if s.group == "halting"),
    "all": tuple(SETTING_BY_NAME),
}


@dataclass(frozen=True)
class Protocol:
    """What a reproduction runs (everything that changes results is here or in the settings)."""

    settings: tuple[Setting, ...]
    variants: tuple[str, ...]  # subset of ALL_VARIANTS, canonical order
    seeds: int  # training seeds 0 .. seeds-1
    epochs: int
    num_test: int = NUM_TEST  # test trajectories per case
    data_seed: int = DATA_SEED
    quick: bool = False  # cap every setting at QUICK_MAX_MAJOR major trajectories
    preset: str = DEFAULT_PRESET  # predictor.presets.PRESETS: the model and training config
    # other presets whose runs of `compare_variants` the report shows beside the preset's own
    # (same settings, seeds and epochs), e.g. the paper's literal version beside a default
    compare_presets: tuple[str, ...] = ()
    compare_variants: tuple[str, ...] = ("ours",)  # trained variants run under compare_presets
    # (preset, setting names) pairs that limit a compared preset to those settings (others: all)
    compare_only: tuple[tuple[str, tuple[str, ...]], ...] = ()
    # train new runs through a compiled graph step (TrainConfig.compile_graph_step): how runs
    # are computed, not what, so their keys and rows are the eager runs'; a resumed run keeps
    # the mode it began with, and each eval.json records its mode (graph_step)
    compile_graph_step: bool = False

    def presets_compared_on(self, setting: str) -> tuple[str, ...]:
        """The compared presets run on a setting: all of them unless `compare_only` limits one."""
        limits = dict(self.compare_only)
        return tuple(p for p in self.compare_presets if setting in limits.get(p, (setting,)))

    def counts(self, setting: Setting) -> tuple[int, int]:
        """(num_major, num_minor) generated for a setting; a quick protocol caps the major count."""
        if not self.quick or setting.num_major <= QUICK_MAX_MAJOR:
            return setting.num_major, setting.num_minor
        scale = QUICK_MAX_MAJOR / setting.num_major
        return QUICK_MAX_MAJOR, max(QUICK_MIN_MINOR, round(setting.num_minor * scale))

    def to_json(self) -> dict:
        """The protocol as results.json gives it (settings last)."""
        fields = {k: v for k, v in asdict(self).items() if k != "settings"}
        return {**fields, "settings": [asdict(s) for s in self.settings]}


def pick(
    text: str, known: Sequence[str], groups: dict[str, tuple[str, ...]], what: str
) -> tuple[str, ...]:
    """Names from a comma list (group names expand), in canonical order; ValueError if unknown."""
    chosen = set()
    for name in (part.strip() for part in text.split(",")):
        if name in groups:
            chosen.update(groups[name])
        elif name in known:
            chosen.add(name)
        else:
            raise ReproductionError(
                f"unknown {what} {name!r}; choose from {', '.join((*known, *groups))}"
            )
    return tuple(name for name in known if name in chosen)


def pick_compared(text: str) -> tuple[tuple[str, ...], tuple[tuple[str, tuple[str, ...]], ...]]:
    """Compared presets from "P,Q@group": (presets, compare_only). `@` limits a preset to one
    setting or group of settings; ReproductionError on an unknown setting or a repeated preset."""
    presets, only = [], []
    for part in (item.strip() for item in text.split(",")):
        if not part:
            continue
        preset, _, scope = part.partition("@")
        preset = preset.strip()
        if preset in presets:
            raise ReproductionError(f"--compare-presets names {preset!r} twice")
        presets.append(preset)
        if scope.strip():
            only.append((preset, pick(scope, tuple(SETTING_BY_NAME), GROUPS, "setting")))
    return tuple(presets), tuple(only)
