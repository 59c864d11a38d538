"""tools/generate.py: counts, determinism across runs and workers, atomicity, bad input."""

from __future__ import annotations

import dataclasses
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from predictor.format import read_dataset, read_meta

REPO = Path(__file__).resolve().parents[1]
TOOL = REPO / "tools" / "generate.py"
sys.path.insert(0, str(REPO / "tools"))

import generate  # noqa: E402


def run_tool(*args: str, timeout: float = 120) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(TOOL), *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=REPO,
    )


def counts(config: generate.GenerateConfig) -> dict[tuple[str, str], int]:
    tally: dict[tuple[str, str], int] = {}
    for slot in generate.plan(config):
        tally[(slot.split, slot.case)] = tally.get((slot.split, slot.case), 0) + 1
    return tally


def config_for(*argv: str) -> generate.GenerateConfig:
    return generate.config_from_args(generate.parse_args(list(argv)))


def test_default_counts_follow_the_paper():
    config = config_for("--scenario", "double_merge", "--minor-ratio", "0.3")
    assert (config.major_case, config.minor_case) == ("major", "minor")
    assert counts(config) == {
        ("train", "major"): 40,
        ("val", "major"): 10,
        ("train", "minor"): 12,
        ("val", "minor"): 3,
        ("test", "major"): 50,
        ("test", "minor"): 50,
    }


@pytest.mark.parametrize(
    "argv, minor_pool, major_pool",
    [
        (("--minor-ratio", "0.8"), 40, 50),
        (("--num-major", "10", "--num-minor", "3"), 3, 10),
        (("--num-major", "30", "--num-minor", "15"), 15, 30),
        (("--num-major", "100", "--num-minor", "30"), 30, 100),
        (("--num-major", "100", "--minor-ratio", "0.3"), 30, 100),
    ],
)
def test_paper_settings_counts(argv, minor_pool, major_pool):
    config = config_for("--scenario", "halting_car", *argv)
    assert (config.major_case, config.minor_case) == ("stop", "go")
    tally = counts(config)
    assert tally[("train", "go")] + tally[("val", "go")] == minor_pool
    assert tally[("train", "stop")] + tally[("val", "stop")] == major_pool
    assert tally[("val", "stop")] == round(0.2 * major_pool)
    seeds = [slot.seed for slot in generate.plan(config)]
    assert len(set(seeds)) == len(seeds)


def test_go_as_major_case():
    config = config_for("--scenario", "halting_car", "--major-case", "go")
    assert (config.major_case, config.minor_case) == ("go", "stop")


def test_round_trip_file_contents(tmp_path):
    out = tmp_path / "hc.h5"
    generate.main(
        [
            "--scenario",
            "halting_car",
            "--num-major",
            "5",
            "--num-minor",
            "2",
            "--num-test",
            "3",
            "--out",
            str(out),
        ]
    )
    meta, splits = read_dataset(out)
    assert meta.scenario == "halting_car" and meta.major_case == "stop"
    assert meta.config["generator"]["num_major"] == 5
    assert splits["train"].n == 4 + 2 and splits["val"].n == 1 + 0 and splits["test"].n == 6
    case_names = list(meta.case_names)
    test_cases = [case_names[i] for i in splits["test"].case]
    assert test_cases == ["stop"] * 3 + ["go"] * 3
    # the stored arrays are exactly what the scenario's rollout gives for the stored seeds
    from scenarios import SCENARIOS
    from scenarios.rollout import rollout

    scenario = SCENARIOS["halting_car"]()
    index = 4
    episode = rollout(scenario, int(splits["test"].seed[index]), test_cases[index])
    np.testing.assert_array_equal(splits["test"].states[index], episode.states.astype(np.float32))
    np.testing.assert_array_equal(splits["test"].attention[index], episode.attention)


def test_same_arguments_same_data_for_any_worker_count(tmp_path):
    args = ["--scenario", "double_merge", "--num-major", "6", "--num-minor", "3", "--num-test", "4"]
    generate.main([*args, "--out", str(tmp_path / "a.h5")])
    generate.main([*args, "--out", str(tmp_path / "b.h5")])
    generate.main([*args, "--workers", "2", "--out", str(tmp_path / "c.h5")])
    generate.main([*args, "--seed", "1", "--out", str(tmp_path / "d.h5")])
    _, a = read_dataset(tmp_path / "a.h5")
    for other in ("b.h5", "c.h5"):
        _, b = read_dataset(tmp_path / other)
        for split in a:
            for name, array in a[split].arrays().items():
                np.testing.assert_array_equal(
                    array, b[split].arrays()[name], err_msg=f"{split}.{name}"
                )
    _, d = read_dataset(tmp_path / "d.h5")
    assert not np.array_equal(a["train"].states, d["train"].states)


def test_unsafe_episodes_are_replaced_deterministically(monkeypatch):
    real_rollout = generate.rollout
    bad_seeds = {2, 5}

    def flaky_rollout(scenario, seed, case):
        episode = real_rollout(scenario, seed, case)
        if seed in bad_seeds:
            return dataclasses.replace(episode, collided=True)
        return episode

    monkeypatch.setattr(generate, "rollout", flaky_rollout)
    config = config_for(
        "--scenario", "halting_car", "--num-major", "4", "--num-minor", "2", "--num-test", "1"
    )
    slots, episodes, rejected = generate.generate(config)
    assert rejected == 2
    seeds = [slot.seed for slot in slots]
    assert not bad_seeds & set(seeds)
    assert seeds[2] == len(seeds) and seeds[5] == len(seeds) + 1  # fresh seeds, in slot order
    assert all(generate.is_safe(e) for e in episodes)


def test_is_safe_rejects_nan_and_off_road():
    states = np.zeros((3, 2, 4))
    good = SimpleNamespace(
        states=states, actions=np.zeros((3, 2, 2)), collided=False, off_road=False
    )
    assert generate.is_safe(good)
    nan_states = states.copy()
    nan_states[1, 0, 0] = np.nan
    assert not generate.is_safe(SimpleNamespace(**{**vars(good), "states": nan_states}))
    assert not generate.is_safe(SimpleNamespace(**{**vars(good), "off_road": True}))
    assert not generate.is_safe(SimpleNamespace(**{**vars(good), "collided": True}))


def test_cli_smoke_summary_and_refuses_overwrite(tmp_path):
    out = tmp_path / "dm.h5"
    args = [
        "--scenario",
        "double_merge",
        "--num-major",
        "3",
        "--minor-ratio",
        "0.8",
        "--num-test",
        "2",
        "--out",
        str(out),
    ]
    result = run_tool(*args)
    assert result.returncode == 0, result.stderr
    assert f"wrote {out}" in result.stdout and "train" in result.stdout
    assert read_meta(out).num_steps > 0
    first = out.read_bytes()
    again = run_tool(*args)
    assert again.returncode == 2 and "--overwrite" in again.stderr
    assert out.read_bytes() == first
    replaced = run_tool(*args, "--overwrite", "--seed", "3")
    assert replaced.returncode == 0 and out.read_bytes() != first


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--scenario", "roundabout"], "invalid choice"),
        (["--scenario", "halting_car", "--minor-ratio", "-0.1"], "--minor-ratio"),
        (["--scenario", "halting_car", "--minor-ratio", "1e6"], "--minor-ratio"),
        (["--scenario", "halting_car", "--num-major", "2.5"], "invalid int"),
        (["--scenario", "halting_car", "--num-test", "ten"], "invalid int"),
        (["--scenario", "halting_car", "--num-major", "0"], "--num-major"),
        (["--scenario", "halting_car", "--val-fraction", "1.0"], "--val-fraction"),
        (["--scenario", "halting_car", "--val-fraction", "-0.2"], "--val-fraction"),
        (["--scenario", "halting_car", "--major-case", "major"], "--major-case"),
        (["--scenario", "halting_car", "--minor-ratio", "0.3", "--num-minor", "3"], "either"),
    ],
)
def test_bad_input_exits_2_with_one_line_and_no_file(tmp_path, argv, message):
    out = tmp_path / "x.h5"
    result = run_tool(*argv, "--out", str(out))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in result.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_unwritable_directory_exits_2(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("not a directory")
    result = run_tool(
        "--scenario",
        "halting_car",
        "--num-major",
        "2",
        "--num-test",
        "1",
        "--out",
        str(blocker / "sub" / "x.h5"),
    )
    assert result.returncode == 2 and "cannot create output directory" in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_interrupted_run_leaves_no_file(tmp_path, sig):
    out = tmp_path / "big.h5"
    process = subprocess.Popen(
        [
            sys.executable,
            str(TOOL),
            "--scenario",
            "double_merge",
            "--num-major",
            "5000",
            "--out",
            str(out),
        ],
        cwd=REPO,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    time.sleep(3.0)  # well into generating
    process.send_signal(sig)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode != 0
    assert "Traceback" not in stderr
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == []
    assert os.path.isdir(tmp_path)
