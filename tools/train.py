"""Train a smooth-attention trajectory predictor on a dataset file.

Example: python tools/train.py --data data/double_merge.h5 --variant ours --seed 0 --out runs/s0

Writes config.json, metrics.jsonl, last.pt and best.pt (lowest validation ADE of the main agents)
to --out. An interrupted run continues bit-identically with --resume (only --epochs, --threads
and --eval-every may change then). A run that fails or is interrupted before its first epoch
ends leaves nothing behind. Variants: ours, nonsmooth, s_attn, average, correct.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.cli import ArgumentParser, fail, require_file, run_main
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
from predictor.run_files import RunError
from predictor.run_state import RESUME_MAY_CHANGE, resume_configs
from predictor.training import train

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
    may_change = ", ".join(f"--{name.replace('_', '-')}" for name in RESUME_MAY_CHANGE)
    parser.add_argument(
        "--resume",
        action="store_true",
        help=f"continue the run in --out (only {may_change} may change)",
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


def configs_for(args) -> tuple[ModelConfig, TrainConfig]:
    """Configs of a new run, or the stored ones (with the allowed changes) for --resume."""
    if not args.resume:
        train_values = {
            "seed": args.seed if args.seed is not None else 0,
            **given(args, TRAIN_FLAGS),
        }
        preset = args.preset or DEFAULT_PRESET
        return make_configs(
            args.variant or "ours", given(args, MODEL_FLAGS), preset=preset, **train_values
        )
    changes = {
        **given(args, MODEL_FLAGS),
        **given(args, TRAIN_FLAGS),
        **given(args, ("variant", "seed")),
    }
    if args.preset is not None:
        fail("--preset applies to a new run; a resumed run keeps its stored configuration")
    return resume_configs(args.out, changes)


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    require_file(args.data, "data file")
    try:
        model_cfg, train_cfg = configs_for(args)
        result = train(
            args.data,
            model_cfg,
            train_cfg,
            args.out,
            resume=args.resume,
            overwrite=args.overwrite,
            progress=not args.no_progress,
        )
    except KeyboardInterrupt:
        fail(_interrupted(Path(args.out)), code=130)
    except FloatingPointError as err:
        fail(f"training diverged: {err}", code=1)
    except (CheckpointError, FormatError, RunError, ValueError, OSError) as err:
        fail(str(err))
    print(result.summary(train_cfg.variant))


def _interrupted(out: Path) -> str:
    if (out / "last.pt").is_file():
        return f"interrupted; continue with --resume --out {out}"
    return f"interrupted before the first epoch ended; nothing was kept in {out}"


if __name__ == "__main__":
    run_main(main)
