"""List the scenario versions: each family's versions, what changed in each, the latest one.

    python tools/list_scenarios.py              # for the terminal
    python tools/list_scenarios.py --markdown   # docs/scenarios.md's table (a test keeps it)

The versions are declared in scenarios/versions.py; a family name given to any tool means its
latest version.
"""

from __future__ import annotations

import textwrap

from pipeline.cli import ArgumentParser, run_main
from scenarios import FAMILIES
from scenarios.registry import versions_markdown


def table() -> str:
    """Every version, one paragraph each, the latest of a family marked."""
    lines = []
    for versions in FAMILIES.values():
        for version in versions:
            latest = " (latest)" if version is versions[-1] else ""
            lines.append(f"{version.name}{latest}: {version.scenario_class.__name__}")
            lines.append(textwrap.fill(version.changes, 96, initial_indent="  changed: ",
                                       subsequent_indent="    "))  # fmt: skip
            lines.append(textwrap.fill(version.why, 96, initial_indent="  why: ",
                                       subsequent_indent="    "))  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = ArgumentParser(prog="list_scenarios.py", description=__doc__.splitlines()[0])
    parser.add_argument(
        "--markdown", action="store_true", help="print the docs table (markdown) instead"
    )
    args = parser.parse_args(argv)
    print(versions_markdown().rstrip() if args.markdown else table())


if __name__ == "__main__":
    run_main(main)
