"""Check a trajectory dataset file against the schema and print a summary.

    python tools/inspect_data.py data/double_merge.h5
    python tools/inspect_data.py data/double_merge.h5 --interaction-gain

With --interaction-gain, also the interaction gain of the labelled cars
(predictor.interaction_gain):
the test ADE of ridge regressions fitted on the train split on the attending car's own history,
plus the labelled car's, plus a random car's, per case and role; --gain-groups relation fits
the attending cars' regressions per relation to the labelled car (ahead or behind it) instead
of per role; --gain-penalty banded gives the other car's features a ridge penalty of their own
(chosen by cross-validation), so features that carry nothing cost no accuracy;
--gain-control shuffled replaces the random car by the labelled car of another scene, a null
control whose change is what fitting features that carry nothing costs at the file's size.

Exit status (docs/CLI.md): 0 valid; 2 usage error, a missing file, a file that is not a valid
dataset or one the interaction gain cannot use (one line naming the problem); 130 interrupted.
"""

from __future__ import annotations

from pipeline.cli import ArgumentParser, fail, require_file, run_main
from predictor.baselines import GROUPINGS
from predictor.interaction_gain import CONTROLS, PENALTIES, format_gain_table, interaction_gain
from trajectory_data.format import FormatError
from trajectory_data.reader import read_meta, summarize


def main(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file", help="HDF5 trajectory file to check")
    parser.add_argument(
        "--interaction-gain",
        action="store_true",
        help="also fit ridge baselines and report how much the labelled car explains",
    )
    parser.add_argument(
        "--gain-groups",
        choices=GROUPINGS,
        default=None,
        help="with --interaction-gain: one ridge regression per role (default); for the "
        "attending cars one per relation to the labelled car (ahead or behind it); or one per "
        "role and case (an oracle gate on the case)",
    )
    parser.add_argument(
        "--gain-penalty",
        choices=tuple(PENALTIES),
        default=None,
        help="with --interaction-gain: one ridge penalty for all features (shared, default), "
        "or one of its own for the other car's (banded)",
    )
    parser.add_argument(
        "--gain-control",
        choices=CONTROLS,
        default=None,
        help="with --interaction-gain: the control's car, a random other car (default), a random "
        "distractor (distractor) or the labelled car of another scene (shuffled, a null control)",
    )
    args = parser.parse_args(argv)
    for option in ("gain_groups", "gain_penalty", "gain_control"):
        if getattr(args, option) is not None and not args.interaction_gain:
            fail(f"--{option.replace('_', '-')} needs --interaction-gain")
    path = require_file(args.file)
    try:
        text, version = summarize(path), read_meta(path).schema_version
    except FormatError as err:  # an input error, as in every tool that reads the file
        fail(str(err))
    print(text)
    print(f"OK: {path} is a valid schema v{version} dataset")
    if args.interaction_gain:
        try:
            rows = interaction_gain(
                path,
                grouping=args.gain_groups or "role",
                penalty=args.gain_penalty or "shared",
                control=args.gain_control or "random",
            )
        except ValueError as err:
            fail(str(err))
        print("\ninteraction gain (ridge test ADE of the attending agents, fitted on train):")
        print(format_gain_table(rows, args.gain_control or "random"))


if __name__ == "__main__":
    run_main(main)
