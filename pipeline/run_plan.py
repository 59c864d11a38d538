"""The plan of a reproduction: which datasets and runs a protocol needs, and where the cache
keeps them (pipeline.reproduction runs them).

Cache keys: `data/<stem>.h5` per dataset (the stem names every generator input, the scenario's
configuration by its digest) and `runs/<stem>/<variant>/seed<k>_ep<E>_<hash>/` per run, the hash
of the model and training configurations (a changed default starts new runs; the code is not
hashed). Identical inputs share one cache entry.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path

from pipeline.generation import GenerateConfig
from pipeline.protocol import Protocol, Setting
from pipeline.report.records import BASELINES, compared_variant

FIGURE_VARIANTS = ("ours", "s_attn")  # their first seed keeps predictions of the figure scenes
RUN_THREADS = 1  # torch threads of a training/evaluation job: a Ray task asks for this many CPUs


@dataclass(frozen=True)
class DataSpec:
    """The generator inputs of one dataset."""

    scenario: str
    major_case: str
    num_major: int
    num_minor: int
    num_test: int
    seed: int
    scenario_digest: str  # of the scenario's configuration (a changed default changes the key)

    @property
    def stem(self) -> str:
        return (
            f"{self.scenario}_{self.major_case}-major_{self.num_minor}+{self.num_major}"
            f"_test{self.num_test}_seed{self.seed}_{self.scenario_digest}"
        )

    def config(self) -> GenerateConfig:
        """The generator configuration (validated)."""
        return GenerateConfig.for_scenario(
            self.scenario,
            major_case=self.major_case,
            num_major=self.num_major,
            num_minor=self.num_minor,
            num_test=self.num_test,
            seed=self.seed,
        )


@dataclass(frozen=True)
class Job:
    """Train (unless the baseline) and evaluate one (dataset, variant, seed)."""

    data_path: str
    variant: str
    seed: int  # training seed (0 for the baseline: unused)
    epochs: int
    run_dir: str
    save_scenes: bool  # keep predictions of the figure scenes (scenes.npz)
    store_dir: str = ""  # where the results store keeps its eval.json (and scenes.npz); "" none
    preset: str = "paper"  # predictor.presets.PRESETS
    compared: bool = False  # run under one of Protocol.compare_presets, not Protocol.preset
    compile_graph_step: bool = False  # train a new run through torch.compile (not in the key)

    @property
    def record_variant(self) -> str:
        """The variant's name in the records ("ours@agent_zero_cv" under a compared preset)."""
        return compared_variant(self.variant, self.preset) if self.compared else self.variant


def digest(value: object) -> str:
    """Short stable hash of a JSON-able value (cache keys)."""
    text = json.dumps(value, sort_keys=True, default=str)
    return hashlib.sha1(text.encode()).hexdigest()[:8]


def data_spec(protocol: Protocol, setting: Setting) -> DataSpec:
    """The dataset a setting uses under a protocol."""
    from scenarios import VERSIONS

    num_major, num_minor = protocol.counts(setting)
    config = asdict(VERSIONS[setting.scenario].config())
    return DataSpec(
        setting.scenario,
        setting.major_case,
        num_major,
        num_minor,
        protocol.num_test,
        protocol.data_seed,
        digest(config),
    )


def run_configs(
    variant: str, seed: int, epochs: int, preset: str = "paper", compile_graph_step: bool = False
) -> tuple:
    """(ModelConfig, TrainConfig) of a run: the preset's configuration, one torch thread, the
    graph step compiled or not (`predictor.stored_config.EXECUTION_FIELDS`: not in the key)."""
    from predictor.presets import make_configs

    return make_configs(
        variant,
        None,
        preset=preset,
        seed=seed,
        epochs=epochs,
        threads=RUN_THREADS,
        compile_graph_step=compile_graph_step,
    )


def data_path(out_dir: Path, spec: DataSpec) -> Path:
    """Where the cache keeps a dataset."""
    return out_dir / "data" / f"{spec.stem}.h5"


def run_dir(
    out_dir: Path, spec: DataSpec, variant: str, seed: int, epochs: int, preset: str = "paper"
) -> Path:
    """runs/<stem>/<variant>/seed<k>_ep<E>_<digest of the model and training configs>."""
    from predictor.stored_config import config_key

    base = out_dir / "runs" / spec.stem / variant
    if variant in BASELINES:
        return base
    configs = [config_key(c) for c in run_configs(variant, seed, epochs, preset)]
    return base / f"seed{seed}_ep{epochs}_{digest(configs)}"


def setting_jobs(
    protocol: Protocol, setting: Setting, out_dir: Path, store: Path | None = None
) -> list[Job]:
    """The jobs of one setting, in variant then seed order, then those of each preset compared
    on it (`Protocol.presets_compared_on`: its `compare_variants`, no figure scenes); with a
    results `store`, each job keeps its results under the same relative path there as under
    out_dir/runs. A compared preset whose configuration of a variant equals the protocol's
    gives a job with the same run directory (`unique_runs` runs it once)."""
    spec = data_spec(protocol, setting)
    path = str(data_path(out_dir, spec))
    planned = [(protocol.preset, variant, False) for variant in protocol.variants]
    planned += [
        (preset, variant, True)
        for preset in protocol.presets_compared_on(setting.name)
        for variant in protocol.compare_variants
    ]
    jobs = []
    for preset, variant, compared in planned:
        for seed in [0] if variant in BASELINES else range(protocol.seeds):
            directory = run_dir(out_dir, spec, variant, seed, protocol.epochs, preset)
            kept = "" if store is None else str(store / directory.relative_to(out_dir / "runs"))
            save_scenes = variant in FIGURE_VARIANTS and seed == 0 and not compared
            jobs.append(
                Job(
                    path,
                    variant,
                    seed,
                    protocol.epochs,
                    str(directory),
                    save_scenes,
                    kept,
                    preset,
                    compared,
                    protocol.compile_graph_step,
                )
            )
    return jobs


def unique(items: list) -> list:
    """Items in first-seen order without repeats (settings may share data or runs)."""
    return list(dict.fromkeys(items))


def unique_runs(jobs: list[Job]) -> list[Job]:
    """The first job of each run directory (a variant whose configuration a compared preset
    leaves unchanged is one run, trained once), the main preset's before a compared one's."""
    first: dict[str, Job] = {}
    for job in sorted(jobs, key=lambda j: j.compared):
        first.setdefault(job.run_dir, job)
    return [job for job in jobs if first[job.run_dir] is job]
