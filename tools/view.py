"""Write a browser viewer of a dataset's scenes, predictions and attention: one HTML file.

    python tools/view.py DATA.h5 --predictions PRED.npz --out view.html
    python tools/view.py DATA.h5 --run runs/hc_ours --out view.html   # evaluates the run here
    python tools/view.py DATA.h5 --split val --max-scenes 50 --out view.html

DATA.h5 is a trajectory dataset; PRED.npz a predictions file of one of its splits
(tools/evaluate.py --save-predictions), whose split is then the default; --run a training run,
described in the page, and evaluated on the split (its best checkpoint) when no --predictions is
given. The page holds its script and data: it opens from disk in a current browser with no
server and no network (docs/VIEWER.md). A page that would carry more than 64 MB of arrays is
refused unless --max-scenes keeps fewer scenes (the first ones; the page and the last line say
how many were left out). The output is written atomically; an existing one is replaced only
with --overwrite. Exit status (docs/CLI.md): 0 written; 2 usage or input error (a missing or
malformed file, predictions of another dataset, too many scenes); 1 a write that failed (full
disk); 130 interrupted (nothing written).
"""

from __future__ import annotations

from pipeline.cli import ArgumentParser, check_output, fail, run_main, status, writing
from pipeline.viewer import ViewerError, make_viewer
from trajectory_data.format import SPLITS


def _build_parser() -> ArgumentParser:
    parser = ArgumentParser(prog="view.py", description=__doc__.splitlines()[0])
    parser.add_argument("data", help="trajectory dataset (.h5)")
    parser.add_argument("--predictions", help="predictions file (.npz) of one of its splits")
    parser.add_argument("--run", help="training run directory (tools/train.py)")
    parser.add_argument(
        "--split", choices=SPLITS, help="split to show (default: the predictions', else test)"
    )
    parser.add_argument("--out", required=True, help="output page (.html)")
    parser.add_argument(
        "--max-scenes", type=int, help="keep only the first K scenes (for large splits)"
    )
    parser.add_argument("--title", help="title of the page (default: scenario, split, predictor)")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    parser.add_argument("--no-progress", action="store_true", help="no status lines on stderr")
    return parser


def main(argv: list[str] | None = None) -> None:
    args = _build_parser().parse_args(argv)
    if args.max_scenes is not None and args.max_scenes < 1:
        fail(f"--max-scenes must be at least 1, got {args.max_scenes}")
    out = check_output(args.out, args.overwrite)
    if out.suffix.lower() not in (".html", ".htm"):
        fail(f"--out must end in .html, got {out}")
    progress = not args.no_progress
    if progress:
        status(f"view: reading {args.data} and making the page")
    try:
        viewer = make_viewer(
            args.data,
            predictions=args.predictions,
            run=args.run,
            split=args.split,
            max_scenes=args.max_scenes,
            title=args.title,
            progress=progress,
        )
    except ViewerError as err:
        fail(str(err))
    with writing(out) as temp:
        temp.write_text(viewer.text, encoding="utf-8")
    print(viewer.summary(out))


if __name__ == "__main__":
    run_main(main)
