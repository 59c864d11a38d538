"""Check a trajectory dataset file against the schema and print a summary.

    python tools/inspect_data.py data/double_merge.h5

Exit status: 0 valid; 1 the file exists but is not a valid dataset; 2 usage error / missing file.
"""

from __future__ import annotations

from pipeline.cli import ArgumentParser, fail, require_file, run_main
from predictor.format import SCHEMA_VERSION, FormatError, summarize


def main(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("file", help="HDF5 trajectory file to check")
    args = parser.parse_args(argv)
    path = require_file(args.file)
    try:
        text = summarize(path)
    except FormatError as err:
        fail(str(err), code=1)
    print(text)
    print(f"OK: {path} is a valid schema v{SCHEMA_VERSION} dataset")


if __name__ == "__main__":
    run_main(main)
