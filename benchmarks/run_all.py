"""Run every benchmark (benchmarks/bench_*.py) and collect their figures.

Each benchmark prints one JSON line last; this writes them all to benchmarks/results.json and
refreshes the table between the result markers in benchmarks/README.md. With --only, the named
benchmarks' entries are replaced and the others kept from the last run; every entry carries the
date and machine it was measured on.
Usage: python benchmarks/run_all.py [--only simulator,env,...]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
START, END = "<!-- results:start -->", "<!-- results:end -->"


def run_benchmark(script: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(HERE.parent), "OMP_NUM_THREADS": "1"}
    result = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, env=env, cwd=HERE.parent
    )
    if result.returncode != 0:
        return {
            "benchmark": script.stem.removeprefix("bench_"),
            "error": result.stderr.strip()[-500:],
        }
    print(result.stdout.strip().splitlines()[0], flush=True)
    return json.loads(result.stdout.strip().splitlines()[-1])


def flat_figures(result: dict, prefix: str = "") -> list[tuple[str, object]]:
    """(name, value) of every scalar figure; lists of dicts (e.g. one entry per thread count)
    are labelled by their first field, e.g. `threads=1 epoch_s`."""
    figures = []
    for key, value in result.items():
        if key == "benchmark" or isinstance(value, dict):
            continue
        if isinstance(value, list):
            for entry in value:
                if isinstance(entry, dict) and entry:
                    first = next(iter(entry))
                    rest = {k: v for k, v in entry.items() if k != first}
                    figures += flat_figures(rest, f"{prefix}{first}={entry[first]} ")
            continue
        figures.append((prefix + key, value))
    return figures


def table(results: list[dict]) -> str:
    lines = ["| benchmark | figure | value |", "|---|---|---|"]
    for result in results:
        for name, value in flat_figures(result):
            shown = f"{value:,}" if isinstance(value, int) else str(value)
            lines.append(f"| {result['benchmark']} | {name} | {shown} |")
    return "\n".join(lines)


def merged(new: list[dict], path: Path, fallback_date: str) -> list[dict]:
    """`new` results with the entries of the other benchmarks in the results file `path` (each
    keeps its own date and machine; older entries without them get the file's), ordered by
    name."""
    kept = []
    if path.exists():
        old = json.loads(path.read_text())
        names = {r["benchmark"] for r in new}
        for entry in old.get("results", []):
            if entry.get("benchmark") not in names:
                dated = {"date": old.get("date", fallback_date), "machine": old.get("machine")}
                kept.append({**dated, **entry})
    return sorted(new + kept, key=lambda r: r["benchmark"])


def main() -> None:
    parser = argparse.ArgumentParser(description="run every benchmark")
    parser.add_argument("--only", default="", help="comma-separated benchmark names (default all)")
    args = parser.parse_args()
    wanted = {name for name in args.only.split(",") if name}
    known = {p.stem.removeprefix("bench_") for p in HERE.glob("bench_*.py")}
    if wanted - known:
        print(
            f"run_all.py: error: unknown benchmark(s) {', '.join(sorted(wanted - known))}; "
            f"choose from {', '.join(sorted(known))}",
            file=sys.stderr,
        )
        raise SystemExit(2)
    scripts = [
        p
        for p in sorted(HERE.glob("bench_*.py"))
        if not wanted or p.stem.removeprefix("bench_") in wanted
    ]
    today = time.strftime("%Y-%m-%d")
    machine = f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    results = [{**run_benchmark(script), "date": today, "machine": machine} for script in scripts]
    if wanted:  # keep the other benchmarks' last figures
        results = merged(results, HERE / "results.json", today)
    record = {
        "date": today,
        "machine": machine,
        "command": f"python benchmarks/run_all.py --only {args.only}"
        if wanted
        else "make bench (python benchmarks/run_all.py)",
        "results": results,
    }
    (HERE / "results.json").write_text(json.dumps(record, indent=2) + "\n")
    readme = HERE / "README.md"
    text = readme.read_text()
    block = (
        f"{START}\nLast run: {record['date']}, `{record['command']}`, {record['machine']}; "
        "each benchmark's `date` row says when its figures were measured.\n\n"
        f"{table(results)}\n{END}"
    )
    if START in text and END in text:
        text = text[: text.index(START)] + block + text[text.index(END) + len(END) :]
    else:
        text = text.rstrip() + "\n\n## Latest run\n\n" + block + "\n"
    readme.write_text(text)
    failed = [r["benchmark"] for r in results if "error" in r]
    print(
        f"benchmarks: {len(results) - len(failed)} ran, {len(failed)} failed"
        + (f" ({', '.join(failed)})" if failed else "")
        + "; wrote benchmarks/results.json"
    )
    raise SystemExit(1 if failed else 0)


if __name__ == "__main__":
    main()
