"""The command examples of docs/*.md (their ```bash blocks), run as written where this machine
can run them, so they cannot go stale: each block is classified in `PLAN`, and a new block
fails the test until it is. A block runs in a scratch folder holding the inputs its commands
name, made up small (an ETH/UCY folder, INTERACTION tracks, FILE.h5); trainings run one epoch.
The blocks that need a Ray cluster, or hours, are listed with the reason they do not run."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import REPO_ROOT, tool_env
from test_import_data import make_pairs_scene, write_interaction

SKIP = "skip"
PLAN = {  # (doc, index of its bash block) -> how the test treats it
    ("CLI.md", 0): "train FILE.h5",
    ("REAL_DATA.md", 0): "eth_ucy folder, each line alone",
    ("REAL_DATA.md", 1): "eth_ucy imported",
    ("REAL_DATA.md", 2): "eth_ucy imported",
    ("REAL_DATA.md", 3): "interaction folder",
    ("SCALING.md", 0): (SKIP, "installs Ray (make venv does)"),
    ("SCALING.md", 1): "plain",
    ("SCALING.md", 2): (SKIP, "needs a Ray cluster (HEAD_IP)"),
    ("SCALING.md", 3): (SKIP, "needs a Ray cluster (HEAD_IP)"),
    ("SCALING.md", 4): (SKIP, "hours of training (the reproduction on Ray)"),
    ("VIEWER.md", 0): "train FILE.h5",
}


def bash_blocks(doc: Path) -> list[list[str]]:
    """The commands of each ```bash block of `doc`: continuation lines joined, comments and
    prompts of other programs dropped."""
    blocks = re.findall(r"^```bash\n(.*?)^```", doc.read_text(), re.S | re.M)
    return [
        [line.split("  #")[0].strip() for line in code.replace("\\\n", " ").splitlines()]
        for code in blocks
    ]


def every_block() -> list[tuple[str, int, list[str]]]:
    found = []
    for doc in sorted((REPO_ROOT / "docs").glob("*.md")):
        for index, lines in enumerate(bash_blocks(doc)):
            found.append((doc.name, index, [line for line in lines if line]))
    return found


def test_every_docs_example_is_classified():
    found = {(doc, index) for doc, index, _ in every_block()}
    assert found == set(PLAN), "classify the new or removed docs examples in PLAN"


def prepare(kind: str, folder: Path) -> None:
    """Make the inputs the block names."""
    if kind.startswith("eth_ucy"):
        for scene in ("eth", "hotel", "univ", "zara1", "zara2"):  # the same small scene, renamed
            made = folder / f"made_{scene}"
            make_pairs_scene(made, "hotel")  # imports under the default window rule
            (folder / "ETH_UCY").mkdir(exist_ok=True)
            (made / "hotel").rename(folder / "ETH_UCY" / scene)
            made.rmdir()
        if kind == "eth_ucy imported":
            run(folder, "python tools/import_data.py eth-ucy ETH_UCY --out data/")
    elif kind == "interaction folder":
        write_interaction(folder / "INTERACTION/recorded_trackfiles/DR_USA_Intersection_EP0")
    elif kind == "train FILE.h5":
        run(folder, "python tools/generate.py --scenario halting_car_v3 --num-major 4 "
                    "--num-test 2 --out FILE.h5")  # fmt: skip


def run(folder: Path, command: str) -> None:
    """Run one documented `python ...` command in `folder` (trainings of one epoch)."""
    assert command.startswith("python "), command
    argv = command.split()[1:]
    if argv[0] == "tools/train.py":
        argv += ["--epochs", "1"]
    done = subprocess.run(
        [sys.executable, *argv], cwd=folder, env=tool_env(), capture_output=True, text=True,
        timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, f"{command}\n{done.stderr[-3000:]}"


def scratch(tmp_path: Path, name: str) -> Path:
    folder = tmp_path / name
    folder.mkdir()
    (folder / "tools").symlink_to(REPO_ROOT / "tools")
    return folder


@pytest.mark.parametrize(
    ("doc", "index", "commands"),
    every_block(),
    ids=[f"{doc}-{index}" for doc, index, _ in every_block()],
)
def test_docs_example_runs(doc, index, commands, tmp_path):
    plan = PLAN[doc, index]
    if isinstance(plan, tuple):
        pytest.skip(plan[1])
    if plan.endswith("each line alone"):  # alternatives that write the same files
        for number, command in enumerate(commands):
            folder = scratch(tmp_path, f"line{number}")
            prepare(plan, folder)
            run(folder, command)
        return
    folder = scratch(tmp_path, "block")
    prepare(plan, folder)
    for command in commands:
        run(folder, command)
