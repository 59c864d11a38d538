"""Import a public trajectory data set into the project's dataset format (schema 2, HDF5).

    python tools/import_data.py eth-ucy DATA/ETH_UCY --out data/
    python tools/import_data.py eth-ucy DATA/ETH_UCY --out data/ --scenes hotel zara1
    python tools/import_data.py interaction DATA/INTERACTION/recorded_trackfiles --out data/inter.h5

eth-ucy: ROOT holds the scenes eth, hotel, univ, zara1, zara2, each with train/, val/ and test/
folders of `frame ped x y` text files (the standard leave-one-out layout); writes
OUT/eth_ucy_<scene>.h5 per scene: 8 observed + 12 predicted steps of 0.4 s, windows of 20 frames
with stride 1, the pedestrians present in all 20 frames focal (scored), a window kept when it has
at least --min-focal-agents of them (default 2, Social-GAN's windows). See
trajectory_data/importers/eth_ucy.py.

interaction: INPUT files or folders (searched for *.csv) of INTERACTION track CSVs (columns
case_id (optional), track_id, frame_id, timestamp_ms, agent_type, x, y, vx, vy, psi_rad, length,
width); writes one file: 40 observed + 60 predicted steps of 0.1 s, a window every --stride
frames, the agents present in all 100 frames focal, 80/10/10 train/val/test: by sequence (a
case_id) for files with case_id; for files without it (continuous recordings, a folder's
vehicle_tracks_NNN.csv and pedestrian_tracks_NNN.csv together) by time, each recording's first
80 % of frames train, the next 10 % val, the last 10 % test, windows across a boundary dropped.
See trajectory_data/importers/interaction.py.

The data is read from disk as downloaded; nothing is fetched.

All files or none are written; an existing output is refused unless --overwrite, and so is an
import that would leave a train, val or test split without windows (one line naming the file,
the split and what to change). Exit status (docs/CLI.md): 0 written; 2 usage error, malformed
input (one line naming the file and line), an empty split or an output that cannot be written
there; 1 a write that failed (full disk); 130 interrupted.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pipeline.cli import INTERRUPTED, ArgumentParser, fail, run_main, write_failure_code
from trajectory_data.format import FormatError
from trajectory_data.importers.common import ImportDataError
from trajectory_data.importers.eth_ucy import SCENES, EthUcyConfig, import_eth_ucy
from trajectory_data.importers.interaction import InteractionConfig, import_interaction
from trajectory_data.reader import summarize


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = ArgumentParser(prog="import_data.py", description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True, parser_class=ArgumentParser)
    eth = commands.add_parser("eth-ucy", help="ETH/UCY pedestrians, leave-one-out folders")
    eth.add_argument("root", help="folder holding <scene>/{train,val,test}/*.txt")
    eth.add_argument("--out", required=True, help="output folder (created if missing)")
    defaults = EthUcyConfig()
    eth.add_argument(
        "--scenes",
        nargs="+",
        choices=SCENES,
        default=list(defaults.scenes),
        help=f"scenes to import (default all: {' '.join(SCENES)})",
    )
    eth.add_argument(
        "--stride",
        type=int,
        default=defaults.stride,
        help=f"steps between window starts (default {defaults.stride})",
    )
    eth.add_argument(
        "--min-focal-agents",
        type=int,
        default=defaults.min_focal_agents,
        metavar="N",
        help="keep a window only when at least N pedestrians are present at all its frames "
        f"(default {defaults.min_focal_agents}: Social-GAN's windows; 1: any scored pedestrian)",
    )
    eth.add_argument("--overwrite", action="store_true", help="replace existing output files")
    inter = commands.add_parser("interaction", help="INTERACTION track CSVs, one output file")
    inter.add_argument("inputs", nargs="+", help="track CSV files or folders holding them")
    inter.add_argument("--out", required=True, help="output file (.h5)")
    defaults_i = InteractionConfig()
    inter.add_argument(
        "--stride",
        type=int,
        default=defaults_i.stride,
        help=f"frames between window starts (default {defaults_i.stride})",
    )
    inter.add_argument(
        "--seed",
        type=int,
        default=defaults_i.seed,
        help="seed of the split by sequence (default 0; recordings split by time use none)",
    )
    inter.add_argument("--overwrite", action="store_true", help="replace an existing output file")
    return parser.parse_args(argv)


def _run(args: argparse.Namespace) -> list[Path]:
    """The import the subcommand asks for; ValueError for a bad setting."""
    if args.command == "eth-ucy":
        config = EthUcyConfig(
            scenes=tuple(args.scenes),
            stride=args.stride,
            min_focal_agents=args.min_focal_agents,
        )
        return import_eth_ucy(args.root, args.out, config, args.overwrite, progress=True)
    config = InteractionConfig(stride=args.stride, seed=args.seed)
    return [import_interaction(args.inputs, args.out, config, args.overwrite, progress=True)]


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    try:
        paths = _run(args)
    except KeyboardInterrupt:
        fail("interrupted; nothing was written", code=INTERRUPTED)
    except (ImportDataError, FormatError, ValueError) as err:
        fail(str(err))
    except OSError as err:
        fail(f"cannot write to {args.out}: {err.strerror or err}", write_failure_code(err.errno))
    for path in paths:
        print(summarize(Path(path)), end="\n\n")
    print(f"wrote {len(paths)} file(s): {', '.join(str(p) for p in paths)}")


if __name__ == "__main__":
    run_main(main)
