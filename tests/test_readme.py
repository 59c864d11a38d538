"""The README's examples, run as written, in order, in a scratch folder (so they cannot go
stale): every ```bash line as a command, every ```python block as a script. Two substitutions
keep them quick, each checked to still apply: trainings run one epoch. The quick start's
`make demo` / `make test` are what tests/test_demo.py and CI itself run."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys

import pytest
from conftest import REPO_ROOT, tool_env

README = (REPO_ROOT / "README.md").read_text()
BLOCKS = re.findall(r"^```(\w+)\n(.*?)^```", README, re.S | re.M)  # (language, code)
QUICK_START = "make demo"  # the block run by CI and tests/test_demo.py, not here
FASTER = {  # README text -> what the test runs (trainings of one epoch)
    "--out runs/hc_ours": "--out runs/hc_ours --epochs 1",
    'api.train(data, "runs/hc_python", seed=0)': 'api.train(data, "runs/hc_python", seed=0, epochs=1)',  # noqa: E501
}


def commands(language: str, code: str) -> list[str]:
    """The commands of a block: each bash line (comments dropped), or the python block whole."""
    if language == "python":
        return [code]
    lines = [line.split("  #")[0].strip() for line in code.splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


def test_every_block_is_bash_or_python_and_the_substitutions_apply():
    assert BLOCKS and {language for language, _ in BLOCKS} == {"bash", "python"}
    for text in FASTER:
        assert README.count(text) == 1, f"the README no longer has {text!r}: update FASTER"


@pytest.fixture
def workspace(tmp_path):
    """A scratch folder the examples run in: the tools (linked) and a copy of the results."""
    (tmp_path / "tools").symlink_to(REPO_ROOT / "tools")
    shutil.copytree(REPO_ROOT / "results", tmp_path / "results")
    return tmp_path


def test_the_readme_examples_run_as_written(workspace):
    ran = []
    for language, code in BLOCKS:
        if QUICK_START in code:
            continue
        for command in commands(language, code):
            for text, faster in FASTER.items():
                command = command.replace(text, faster)
            if language == "python":
                argv = [sys.executable, "-c", command]
            else:
                assert command.startswith("python "), command
                argv = [sys.executable, *command.split()[1:]]
            done = subprocess.run(
                argv, cwd=workspace, env=tool_env(), capture_output=True, text=True, timeout=600
            )
            assert done.returncode == 0, f"{command}\n{done.stderr[-3000:]}"
            ran.append(command)
    assert len(ran) >= 8
    assert (workspace / "outputs" / "reproduce" / "RESULTS.md").is_file()
    assert (workspace / "runs" / "hc_ours" / "best.pt").is_file()
