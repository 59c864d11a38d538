"""Plot sample trajectories, predictions and attention (paper style).

    python tools/plot.py samples FILE --split test --num 4 --out samples.png
    python tools/plot.py predictions PRED.npz --index 0 --out pred.png
    python tools/plot.py attention PRED.npz --index 0 --agent 0 --target 1 --out attn.png

FILE is a trajectory dataset (schema 1 or 2); PRED.npz is a predictions file written by
tools/evaluate.py --save-predictions. The output format follows the suffix of --out (.png, .pdf,
.svg); an existing output is replaced only with --overwrite. --dpi is limited to [10, 1200] and
the image to 100 million pixels. The output is written atomically and its path printed at the
end.
"""

from __future__ import annotations

import argparse

from matplotlib.backend_bases import FigureCanvasBase

from pipeline.cli import ArgumentParser, check_output, fail, require_file, run_main, writing
from predictor.plots import (
    MAX_DPI,
    MAX_SAMPLES_PER_CASE,
    MIN_DPI,
    PlotInputError,
    plot_attention,
    plot_predictions,
    plot_samples,
    save_figure,
)
from predictor.predictions import PredictionsError, load_predictions
from trajectory_data.format import SPLITS, FormatError
from trajectory_data.reader import read_meta, read_split


def _build_parser() -> ArgumentParser:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True, parser_class=ArgumentParser)
    samples = commands.add_parser("samples", help="sample trajectories, one column per case")
    samples.add_argument("file", help="trajectory dataset (.h5)")
    samples.add_argument("--split", choices=SPLITS, default="test", help="split to draw from")
    samples.add_argument(
        "--num",
        type=int,
        default=4,
        help=f"trajectories per case, the first ones (1 to {MAX_SAMPLES_PER_CASE})",
    )
    predictions = commands.add_parser("predictions", help="predicted vs true trajectories")
    predictions.add_argument("file", help="predictions file (.npz) from tools/evaluate.py")
    predictions.add_argument("--index", type=int, default=0, help="scene index in the file")
    attention = commands.add_parser("attention", help="attention of one agent on another")
    attention.add_argument("file", help="predictions file (.npz) from tools/evaluate.py")
    attention.add_argument("--index", type=int, default=0, help="scene index in the file")
    attention.add_argument("--agent", type=int, default=0, help="attending agent")
    attention.add_argument("--target", type=int, default=1, help="attended agent")
    for sub in (samples, predictions, attention):
        sub.add_argument("--out", required=True, help="output image (.png, .pdf, .svg)")
        sub.add_argument(
            "--dpi",
            type=int,
            default=120,
            help=f"resolution of raster output ({MIN_DPI} to {MAX_DPI}, default 120)",
        )
        sub.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    return parser


def _make_figure(args: argparse.Namespace):
    if args.command == "samples":
        meta = read_meta(args.file)
        return plot_samples(read_split(args.file, args.split), meta, num_per_case=args.num)
    predictions = load_predictions(args.file)
    if args.command == "predictions":
        return plot_predictions(predictions, args.index)
    return plot_attention(predictions, args.index, args.agent, args.target)


def main(argv: list[str] | None = None) -> None:
    args = _build_parser().parse_args(argv)
    require_file(args.file)
    out = check_output(args.out, args.overwrite)
    formats = sorted(FigureCanvasBase.get_supported_filetypes())
    if out.suffix.lower().lstrip(".") not in formats:
        fail(f"--out must end in an image format's suffix ({', '.join(formats)}), got {out}")
    if not MIN_DPI <= args.dpi <= MAX_DPI:
        fail(f"--dpi must be in [{MIN_DPI}, {MAX_DPI}], got {args.dpi}")
    try:
        fig = _make_figure(args)
    except (FormatError, PlotInputError, PredictionsError) as err:
        fail(str(err))
    try:
        with writing(out) as temp:
            save_figure(fig, temp, dpi=args.dpi)
    except PlotInputError as err:
        fail(str(err))
    except ValueError as err:  # e.g. an unsupported output suffix
        fail(f"cannot write {out}: {err}")
    print(out)


if __name__ == "__main__":
    run_main(main)
