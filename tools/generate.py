"""Generate a major/minor trajectory dataset from a scenario's expert and write it to HDF5.

Example: python tools/generate.py --scenario halting_car --minor-ratio 0.3
(a family name means its latest version, here halting_car_v3, and a notice says so; name a
version, e.g. --scenario halting_car_v0, to pin one; without --scenario: double_merge_v1)

The training pool holds `--num-major` trajectories of the major case and round(R x num-major)
of the minor case (or `--num-minor` exactly); `--val-fraction` of each case is split off for
validation. The test split holds `--num-test` trajectories of each case. The work is one call of
`pipeline.generation.generate_dataset` (see there: seeds, determinism for any `--workers` and
`--batch-scenes`, safety checks, atomic writing); Ctrl-C or SIGTERM ends it with exit status 130
and no file.

With `--shard-size N` the output is a folder (default data/<name> without .h5) of shard files of
at most N trajectories of one split each, plus FOLDER/index.h5, which every tool reads as the one
file (docs/dataset_format.md, "Sharded datasets"); each shard is written as soon as it is done,
so a dataset larger than memory can be generated.

`--influence` also stores every trajectory's counterfactual influence matrices (how far each
agent's predicted steps move when another agent is removed; schema 4, single files only; about
5 times the generation's time); `--influence-window-steps L` stores the same per predicted-time
window of L steps (the agent removed from each window's first step, the ADE over that window;
for scenes where whom an agent reacts to changes during the episode). `--observation-noise-m
SIGMA` adds Gaussian noise of SIGMA metres to the stored positions of the observed steps (labels
and influence stay those of the clean run). All are off by default, so a plain run writes the
same bytes as before.
"""

from __future__ import annotations

import argparse
import re
import signal
import sys
from pathlib import Path

from pipeline.backends import BACKENDS
from pipeline.cli import FAILED, ArgumentParser, fail, run_main, write_failure_code
from pipeline.episode_runner import DEFAULT_BATCH_SCENES
from pipeline.generation import (
    DEFAULT_MINOR_RATIO,
    DEFAULT_SCENARIO,
    GenerateConfig,
    UnsafeExpertError,
    default_output,
    generate_dataset,
)
from pipeline.ray_backend import RayUnavailableError
from scenarios import choices_text, lookup
from scenarios.observation_noise import check_noise

# config and generate_dataset errors name these fields; the user typed the flags
_FLAGS = re.compile(r"\b(num_major|num_minor|num_test|val_fraction|major_case|minor_ratio|seed)\b")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = ArgumentParser(
        prog="generate.py",
        description="Generate a major/minor trajectory dataset (HDF5) from a scenario's expert.",
    )
    parser.add_argument(
        "--scenario",
        default=DEFAULT_SCENARIO,
        help=f"scenario version to simulate, family_vN; a family name means its latest "
        f"version ({choices_text()}; default {DEFAULT_SCENARIO})",
    )
    parser.add_argument(
        "--minor-ratio",
        type=float,
        default=None,
        help="minor-case training trajectories = round(R x num-major), R in [0, 1]: the minor "
        "case is the rarer one; for more of the other case give it as --major-case "
        f"(default {DEFAULT_MINOR_RATIO:g}; the paper uses 0.3 and 0.8)",
    )
    parser.add_argument(
        "--num-minor",
        type=int,
        default=None,
        help="explicit minor-case training count instead of --minor-ratio, at most --num-major",
    )
    parser.add_argument(
        "--major-case",
        default=None,
        help="the frequent case (default: 'major' for Double Merge, 'stop' for Halting Car)",
    )
    parser.add_argument(
        "--num-major",
        type=int,
        default=50,
        help="major-case training trajectories, validation included (default 50)",
    )
    parser.add_argument(
        "--num-test", type=int, default=50, help="test trajectories of each case (default 50)"
    )
    parser.add_argument(
        "--val-fraction",
        type=float,
        default=0.2,
        help="share of each case's training trajectories kept for validation, "
        "in [0, 1) (default 0.2)",
    )
    parser.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    parser.add_argument(
        "--workers",
        type=int,
        default=1,
        help="worker processes; the output is identical for any number (default 1)",
    )
    parser.add_argument(
        "--batch-scenes",
        type=int,
        default=DEFAULT_BATCH_SCENES,
        help="episodes stepped together as one batched world, per worker task; 1 rolls them out "
        f"one by one; the output is identical for any number (default {DEFAULT_BATCH_SCENES})",
    )
    parser.add_argument(
        "--backend",
        choices=BACKENDS,
        default="local",
        help="local: --workers processes here (default); ray: Ray tasks on a cluster, the same "
        "output (pip install -e '.[ray]')",
    )
    parser.add_argument(
        "--address",
        default=None,
        help="with --backend ray: the cluster (default $RAY_ADDRESS, else a local Ray instance "
        "with --workers CPUs)",
    )
    parser.add_argument(
        "--out",
        default=None,
        help="output file (default data/<scenario>_<major>-major_<M>+<m>_seed<S>.h5), or "
        "with --shard-size the output folder (default the same without .h5)",
    )
    parser.add_argument(
        "--shard-size",
        type=int,
        default=None,
        metavar="N",
        help="write a folder of shard files of at most N trajectories per split plus "
        "FOLDER/index.h5, read as one dataset; for outputs larger than memory (default: one file)",
    )
    parser.add_argument(
        "--influence",
        action="store_true",
        help="also compute and store the influence matrices (counterfactual ground truth: each "
        "agent's predicted ADE when another is removed; single files only, ~5x the time)",
    )
    parser.add_argument(
        "--influence-window-steps",
        type=int,
        default=0,
        metavar="L",
        help="also store the influence per predicted-time window of L >= 1 steps (each agent's "
        "ADE over a window when another is removed from its first step; single files only; "
        "default 0: none)",
    )
    parser.add_argument(
        "--observation-noise-m",
        type=float,
        default=0.0,
        metavar="SIGMA",
        help="Gaussian noise [m] on the stored positions of the observed steps, seeded per "
        "trajectory; labels and influence from the clean run (default 0: none)",
    )
    parser.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    parser.add_argument(
        "--no-progress", action="store_true", help="no progress bar or status lines on stderr"
    )
    return parser.parse_args(argv)


def config_from_args(args: argparse.Namespace) -> GenerateConfig:
    """The validated config; exits 2 with one line (naming the flag) on a bad value. A family
    name resolves to its latest version, with a notice on stderr."""
    try:
        version, notice = lookup(args.scenario)
    except ValueError as error:
        fail(f"--scenario: {error}")
    if notice is not None:
        print(f"notice: {notice}", file=sys.stderr)
    try:
        return GenerateConfig.for_scenario(
            version.name,
            major_case=args.major_case,
            num_major=args.num_major,
            minor_ratio=args.minor_ratio,
            num_minor=args.num_minor,
            num_test=args.num_test,
            val_fraction=args.val_fraction,
            seed=args.seed,
        )
    except ValueError as error:
        fail(_in_flag_terms(str(error)))


def _in_flag_terms(message: str) -> str:
    """'num_major must be ...' -> '--num-major must be ...'."""
    return _FLAGS.sub(lambda match: "--" + match.group().replace("_", "-"), message)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    if args.address is not None and args.backend != "ray":
        fail("--address needs --backend ray")
    config = config_from_args(args)
    if args.workers < 1:
        fail(f"--workers must be at least 1, got {args.workers}")
    if args.batch_scenes < 1:
        fail(f"--batch-scenes must be at least 1, got {args.batch_scenes}")
    sharded = args.shard_size is not None
    if sharded and args.shard_size < 1:
        fail(f"--shard-size must be at least 1, got {args.shard_size}")
    out = Path(args.out) if args.out is not None else default_output(config, sharded)
    if sharded and out.suffix in (".h5", ".hdf5"):
        fail(f"with --shard-size, --out names a folder (its index is FOLDER/index.h5), got {out}")
    window = args.influence_window_steps
    if window < 0:
        fail(f"--influence-window-steps must be at least 1 (0: none), got {window}")
    if sharded and (args.influence or window):
        flag = "--influence" if args.influence else "--influence-window-steps"
        fail(f"{flag} is written to single files only, not with --shard-size")
    try:
        check_noise(args.observation_noise_m)
    except ValueError as error:
        fail(f"--observation-noise-m: {error}")
    try:
        result = generate_dataset(
            config,
            out,
            workers=args.workers,
            overwrite=args.overwrite,
            backend=args.backend,
            address=args.address,
            batch_scenes=args.batch_scenes,
            shard_size=args.shard_size,
            progress=not args.no_progress,
            influence=args.influence,
            influence_window_steps=window,
            observation_noise_m=args.observation_noise_m,
        )
    except KeyboardInterrupt:
        fail("interrupted; nothing was written", code=130)
    except FileExistsError:
        fail(f"output {out} already exists; pass --overwrite to replace it")
    except IsADirectoryError:
        fail(f"output {out} is a directory" + (" but not a sharded dataset" if sharded else ""))
    except UnsafeExpertError as error:
        fail(str(error), code=1)
    except RayUnavailableError as error:
        fail(str(error))
    except OSError as error:
        if error.filename is None:  # not a file's error (e.g. a lost Ray connection)
            fail(f"generation failed: {error}", code=FAILED)
        detail = error.strerror or str(error)
        if Path(error.filename) != out:
            detail += f": {error.filename}"
        fail(f"cannot write {out}: {detail}", code=write_failure_code(error.errno))
    print(result.summary())


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt  # SIGTERM cleans up like Ctrl-C: no file is left behind


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, _interrupt)
    run_main(main)
