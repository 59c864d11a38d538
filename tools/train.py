"""Train a smooth-attention trajectory predictor on a dataset file.

Example: python tools/train.py --data data/double_merge.h5 --out runs/s0
         python tools/train.py --data data/double_merge.h5 --out runs/knn \
             --set model.neighbours=knn --set model.neighbour_k=8 --set train.lr=0.001

Writes config.json, metrics.jsonl, last.pt and best.pt (lowest validation ADE of the main agents)
to --out. Variants: ours, nonsmooth, s_attn, average, correct. The configuration is the preset
(default agent) changed by `--set section.field=value`; `--list-settings` lists every setting
(predictor/settings.py reads them from predictor/config.py), `--show-config` prints the resolved
configuration as the run stores it.

Resuming: an interrupted run continues bit-identically with the same command plus --resume.
Settings the stored run fixes (--preset, --variant, --seed and every --set) may be repeated:
equal to the stored value is fine, a different one is refused with one line naming both;
settings left out keep the stored values. Only --epochs (more than done), --device,
train.threads and train.eval_every may change. --resume of a finished run says so and trains
nothing (exit 0: the run the command asks for is there; a larger --epochs trains it further).

A run that fails or is interrupted before its first epoch ends leaves nothing behind; with
--overwrite the previous run is put back as it was, and the message says so.

Exit status (docs/CLI.md): 0 trained (or already finished); 1 training diverged or a write
failed (full disk); 2 usage or input error (one line); 130 interrupted (Ctrl-C, SIGTERM), with
one line saying what the run directory holds and the command that continues or restarts it.
"""

from __future__ import annotations

import shlex
import sys
from dataclasses import fields

from pipeline.cli import (
    FAILED,
    INTERRUPTED,
    ArgumentParser,
    fail,
    require_file,
    run_main,
    write_failure_code,
)
from predictor.checkpoints import CheckpointError
from predictor.config import VARIANTS, ModelConfig, TrainConfig
from predictor.presets import DEFAULT_PRESET, PRESETS
from predictor.run_files import RunError, RunWriteError
from predictor.run_state import RESUME_MAY_CHANGE, ResumeMismatch, resume_configs, run_status
from predictor.settings import list_settings, parse_assignments, resolve, show_config, tree_names
from predictor.training import (
    NOTHING_KEPT,
    RESTORED,
    RESUMABLE,
    TrainingInterrupted,
    train,
)
from trajectory_data.format import FormatError

MODEL_FIELDS = frozenset(item.name for item in fields(ModelConfig))
EVERYDAY = ("epochs", "seed", "device")  # TrainConfig fields with a flag of their own
MAY_CHANGE = ", ".join(
    f"--{name}" if name in EVERYDAY else f"train.{name}" for name in RESUME_MAY_CHANGE
)


def parse_args(argv: list[str] | None = None):
    parser = ArgumentParser(
        prog="train.py",
        description="Train a smooth-attention predictor. Every model and training setting is "
        "--set section.field=value (--list-settings shows them with their values under "
        "--preset, what each allows and needs).",
    )
    parser.add_argument(
        "--data", help="dataset file (HDF5, schema 1 or 2) or a sharded dataset's FOLDER/index.h5"
    )
    parser.add_argument("--out", help="run directory (created)")
    parser.add_argument(
        "--preset",
        default=None,
        choices=sorted(PRESETS),
        help=f"named configuration (default {DEFAULT_PRESET}; paper = the paper's literal "
        "model and optimiser; predictor/presets.py)",
    )
    parser.add_argument(
        "--variant", default=None, choices=sorted(VARIANTS), help="model variant (default ours)"
    )
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.FIELD=VALUE",
        dest="assignments",
        help="change one setting of the preset, e.g. --set train.lr=0.003 --set "
        "model.neighbours=knn (repeatable; sections model and train)",
    )
    parser.add_argument(
        "--epochs", type=int, default=None, help="training epochs (default: the preset's)"
    )
    parser.add_argument("--seed", type=int, default=None, help="random seed (default 0)")
    parser.add_argument(
        "--device",
        default=None,
        help="where training runs: cpu (default), or cuda / cuda:N where torch finds a CUDA "
        "device (evaluation runs on the CPU)",
    )
    parser.add_argument(
        "--resume",
        action="store_true",
        help=f"continue the run in --out: the same command plus --resume (only {MAY_CHANGE} "
        "may change; other settings, if given, must equal the stored run's)",
    )
    parser.add_argument("--overwrite", action="store_true", help="start over in a non-empty --out")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    parser.add_argument(
        "--show-config",
        action="store_true",
        help="print the resolved configuration, as the run would store it, and exit",
    )
    parser.add_argument(
        "--list-settings",
        action="store_true",
        help="list every setting with its value under --preset, allowed values and doc; exit",
    )
    args = parser.parse_args(argv)
    if not (args.show_config or args.list_settings):
        missing = [f"--{name}" for name in ("data", "out") if getattr(args, name) is None]
        if missing:
            parser.error(f"the following arguments are required: {', '.join(missing)}")
    if args.show_config and args.resume and args.out is None:
        parser.error("--show-config --resume needs --out (the run to resume)")
    return args


def everyday(args) -> dict:
    """The training fields given by their own flags."""
    return {name: getattr(args, name) for name in EVERYDAY if getattr(args, name) is not None}


def configs_for(args) -> tuple[ModelConfig, TrainConfig, str | None]:
    """Configs and preset of a new run, or the stored ones (with the allowed changes, the others
    checked to equal the stored run's) for --resume."""
    if not args.resume:
        preset = args.preset or DEFAULT_PRESET
        model_cfg, train_cfg = resolve(
            args.variant or "ours",
            preset,
            args.assignments,
            **{"seed": 0, **everyday(args)},
        )
        return model_cfg, train_cfg, preset
    values = parse_assignments(args.assignments)
    changes = {**values["model"], **values["train"], **everyday(args)}
    if args.variant is not None:
        changes["variant"] = args.variant
    return (*resume_configs(args.out, changes, preset=args.preset), args.preset)


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else [str(a) for a in argv]
    args = parse_args(argv)
    if args.list_settings:
        print(list_settings(args.preset or DEFAULT_PRESET))
        return
    if not args.show_config:
        require_file(args.data, "data file")
    try:
        model_cfg, train_cfg, preset = configs_for(args)
        if args.show_config:
            print(show_config(model_cfg, train_cfg, preset))
            return
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
        fail(tree_names(str(err)))
    print(result.summary(train_cfg.variant))


def shown(value: object) -> str:
    """A config value as typed on the command line (yes/no for booleans)."""
    if isinstance(value, bool):
        return "yes" if value else "no"
    return str(value)


def as_typed(name: str, value: object) -> str:
    """How a setting with this value is given on the command line."""
    if name in (*EVERYDAY, "variant", "preset"):
        return f"--{name} {shown(value)}"
    section = "model" if name in MODEL_FIELDS else "train"
    return f"--set {section}.{name}={shown(value)}"


def mismatch_message(err: ResumeMismatch) -> str:
    """One line naming the setting, the stored and the asked value."""
    keeps = f"a resumed run keeps its configuration; only {MAY_CHANGE} may change"
    if err.preset is not None:  # a run from before presets were recorded
        return (
            f"--preset {err.preset} sets {as_typed(err.name, err.asked)}, but the stored run "
            f"(its preset not recorded) has {shown(err.stored)} ({keeps})"
        )
    return (
        f"{as_typed(err.name, err.asked)} differs from the stored run's "
        f"{as_typed(err.name, err.stored)} ({keeps})"
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
