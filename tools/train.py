"""Train a smooth-attention trajectory predictor on a dataset file.

Example: python tools/train.py --data data/double_merge.h5 --variant ours --seed 0 --out runs/s0

Writes config.json, metrics.jsonl, last.pt and best.pt (lowest validation ADE of the main agents)
to --out. Variants: ours, nonsmooth, s_attn, average, correct.

Resuming: an interrupted run continues bit-identically with the same command plus --resume.
Options the stored run fixes (--preset, --variant, --seed and every config option) may be
repeated: equal to the stored value is fine, a different one is refused with one line naming
both; options left out keep the stored values. Only --epochs (more than done), --threads and
--eval-every may change. --resume of a finished run says so and trains nothing (exit 0: the
run the command asks for is there; a larger --epochs trains it further).

A run that fails or is interrupted before its first epoch ends leaves nothing behind; with
--overwrite the previous run is put back as it was, and the message says so.

Exit status (docs/CLI.md): 0 trained (or already finished); 1 training diverged or a write
failed (full disk); 2 usage or input error (one line); 130 interrupted (Ctrl-C, SIGTERM), with
one line saying what the run directory holds and the command that continues or restarts it.
"""

from __future__ import annotations

import argparse
import shlex
import sys

from pipeline.cli import (
    FAILED,
    INTERRUPTED,
    ArgumentParser,
    fail,
    require_file,
    run_main,
    write_failure_code,
)
from predictor.config import (
    ATTENDED_FITS,
    FRAMES,
    LR_SCHEDULES,
    MEAN_LOSSES,
    MEAN_PRIORS,
    NEIGHBOURS,
    OFFSET_SCALES,
    ROLLOUT_FEEDS,
    ROLLOUT_PRIORS,
    VARIANTS,
    ModelConfig,
    TrainConfig,
)
from predictor.evaluation import CheckpointError
from predictor.format import FormatError
from predictor.presets import DEFAULT_PRESET, PRESETS, make_configs
from predictor.run_files import RunError, RunWriteError
from predictor.run_state import RESUME_MAY_CHANGE, ResumeMismatch, resume_configs, run_status
from predictor.training import (
    NOTHING_KEPT,
    RESTORED,
    RESUMABLE,
    TrainingInterrupted,
    train,
)

MODEL_FLAGS = (
    "embed_dim",
    "edge_hidden",
    "node_hidden",
    "attn_dim",
    "position_scale_m",
    "interaction_scale_m",
    "step_scale_m",
    "min_std_m",
    "init_std_m",
    "log_std_gain",
    "mean_prior",
    "frame",
    "standardise",
    "edge_velocity",
    "offset_scale",
    "detach_covariance",
    "rollout_prior",
    "num_roles",
    "role_input",
    "acceleration_input",
    "attention_gain",
    "highway_steps",
    "highway_horizon",
    "highway_attended",
    "attended_refit",
    "attended_fit",
    "highway_relation",
    "highway_head_groups",
    "role_attention_bias",
    "role_bias_by_group",
    "role_balanced_attention",
    "refit_on_prior",
    "highway_role_groups",
    "neighbours",
    "neighbour_radius_m",
    "neighbour_k",
)
TRAIN_FLAGS = (
    "epochs",
    "batch_size",
    "lr",
    "beta1",
    "beta2",
    "tau",
    "grad_clip_norm",
    "eval_every",
    "threads",
    "lr_schedule",
    "lr_final_ratio",
    "rollout_feed",
    "mean_loss",
    "one_step_needs_previous",
    "weight_decay",
    "observed_jitter",
    "main_agent_weight",
    "one_step_weight",
    "bucket_batches",
    "compile_graph_step",
)
CHOICES = {  # string fields with a fixed set of values
    "mean_prior": MEAN_PRIORS,
    "frame": FRAMES,
    "offset_scale": OFFSET_SCALES,
    "rollout_prior": ROLLOUT_PRIORS,
    "lr_schedule": LR_SCHEDULES,
    "rollout_feed": ROLLOUT_FEEDS,
    "mean_loss": MEAN_LOSSES,
    "neighbours": NEIGHBOURS,
    "attended_fit": ATTENDED_FITS,
}


MAY_CHANGE = ", ".join(f"--{name.replace('_', '-')}" for name in RESUME_MAY_CHANGE)


def yes_no(text: str) -> bool:
    """argparse type of a boolean option: yes/no, true/false, 1/0."""
    value = text.strip().lower()
    if value in ("yes", "true", "1"):
        return True
    if value in ("no", "false", "0"):
        return False
    raise argparse.ArgumentTypeError(f"expected yes or no, got {text!r}")


def add_config_flag(parser, owner: str, name: str, value: object, note: str = "") -> None:
    """--name for the config field `name` with default `value` (of its preset, see --preset)."""
    kind = yes_no if isinstance(value, bool) else type(value)
    parser.add_argument(
        f"--{name.replace('_', '-')}",
        type=kind,
        default=None,
        choices=CHOICES.get(name),
        metavar="yes|no" if isinstance(value, bool) else None,
        help=f"{owner}.{name} (paper preset: {value}{note})",
    )


def parse_args(argv: list[str] | None = None):
    parser = ArgumentParser(prog="train.py", description="Train a smooth-attention predictor.")
    parser.add_argument(
        "--data",
        required=True,
        help="dataset file (HDF5, schema 1 or 2) or a sharded dataset's FOLDER/index.h5",
    )
    parser.add_argument("--out", required=True, help="run directory (created)")
    parser.add_argument(
        "--variant", default=None, choices=sorted(VARIANTS), help="model variant (default ours)"
    )
    parser.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    parser.add_argument(
        "--resume",
        action="store_true",
        help=f"continue the run in --out: the same command plus --resume (only {MAY_CHANGE} "
        "may change; other options, if given, must equal the stored run's)",
    )
    parser.add_argument("--overwrite", action="store_true", help="start over in a non-empty --out")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--preset",
        default=None,
        choices=sorted(PRESETS),
        help=f"named configuration the options below change (default {DEFAULT_PRESET}): "
        "paper = the paper's literal model and optimiser; agent = agent-centric standardised "
        "inputs, displacement-trained means (predictor/presets.py: PRESETS)",
    )
    defaults_t, defaults_m = TrainConfig(), ModelConfig()
    for name in TRAIN_FLAGS:
        note = ", 0 for non-smooth variants" if name == "beta2" else ""
        add_config_flag(parser, "TrainConfig", name, getattr(defaults_t, name), note)
    for name in MODEL_FLAGS:
        add_config_flag(parser, "ModelConfig", name, getattr(defaults_m, name))
    return parser.parse_args(argv)


def given(args, names: tuple[str, ...]) -> dict:
    """The options among `names` that were passed on the command line."""
    return {name: getattr(args, name) for name in names if getattr(args, name) is not None}


def configs_for(args) -> tuple[ModelConfig, TrainConfig, str | None]:
    """Configs and preset of a new run, or the stored ones (with the allowed changes, the others
    checked to equal the stored run's) for --resume."""
    if not args.resume:
        train_values = {
            "seed": args.seed if args.seed is not None else 0,
            **given(args, TRAIN_FLAGS),
        }
        preset = args.preset or DEFAULT_PRESET
        model_cfg, train_cfg = make_configs(
            args.variant or "ours", given(args, MODEL_FLAGS), preset=preset, **train_values
        )
        return model_cfg, train_cfg, preset
    changes = {
        **given(args, MODEL_FLAGS),
        **given(args, TRAIN_FLAGS),
        **given(args, ("variant", "seed")),
    }
    return (*resume_configs(args.out, changes, preset=args.preset), args.preset)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    args = parse_args(argv)
    require_file(args.data, "data file")
    try:
        model_cfg, train_cfg, preset = configs_for(args)
        if args.resume:
            status = run_status(args.out)
            if status.finished and train_cfg.epochs <= status.epoch:
                print(status.summary())
                return
        result = train(
            args.data,
            model_cfg,
            train_cfg,
            args.out,
            resume=args.resume,
            overwrite=args.overwrite,
            progress=not args.no_progress,
            preset=preset,
        )
    except TrainingInterrupted as err:
        fail(interrupted_message(err, argv), code=INTERRUPTED)
    except KeyboardInterrupt:
        fail(f"interrupted before training started; nothing in {args.out} changed", INTERRUPTED)
    except FloatingPointError as err:
        fail(f"training diverged: {err}", code=FAILED)
    except ResumeMismatch as err:
        fail(mismatch_message(err))
    except RunWriteError as err:
        fail(str(err), code=write_failure_code(err.errno))
    except (CheckpointError, FormatError, RunError, ValueError, OSError) as err:
        fail(str(err))
    print(result.summary(train_cfg.variant))


def shown(value: object) -> str:
    """A config value as typed on the command line (yes/no for booleans)."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    return str(value)


def mismatch_message(err: ResumeMismatch) -> str:
    """One line naming the option, the stored and the asked value."""
    keeps = f"a resumed run keeps its configuration; only {MAY_CHANGE} may change"
    if err.preset is not None:  # a run from before presets were recorded
        return (
            f"--preset {err.preset} sets --{err.name.replace('_', '-')} {shown(err.asked)}, but "
            f"the stored run (its preset not recorded) has {shown(err.stored)} ({keeps})"
        )
    flag = f"--{err.name.replace('_', '-')}"
    return (
        f"{flag} {shown(err.asked)} differs from the stored run's {flag} {shown(err.stored)} "
        f"({keeps})"
    )


def interrupted_message(err: TrainingInterrupted, argv: list[str]) -> str:
    """What the run directory holds after Ctrl-C, and the command that goes on from there."""
    out = err.out_dir
    if err.outcome == RESUMABLE:
        again = [a for a in argv if a != "--overwrite"]
        again += [] if "--resume" in again else ["--resume"]
        command = shlex.join(["python", "tools/train.py", *again])
        return (
            f"interrupted; {out} holds the run after epoch {err.epoch} of {err.epochs}; "
            f"continue it with: {command}"
        )
    if err.outcome == RESTORED:
        return (
            f"interrupted before the new run's first epoch ended; the previous run in {out} was "
            "put back as it was and the new run was not kept; run the same command again to "
            "start the new run over"
        )
    if err.outcome == NOTHING_KEPT:
        return (
            f"interrupted before the first epoch ended; nothing was kept in {out}; run the same "
            "command again to start over"
        )
    return f"interrupted before training started; nothing in {out} changed"


if __name__ == "__main__":
    run_main(main)
