"""tools/reproduce.py and tools/_report.py: a --quick smoke run (twice: the second reuses the
cache) in subprocesses, usage errors, and the statistics on hand-made numbers."""

from __future__ import annotations

import dataclasses
import json
import math
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import REPO_ROOT, tool_env
from scipy import stats

sys.path.insert(0, str(REPO_ROOT / "tools"))
import _report  # noqa: E402
import reproduce  # noqa: E402

SETTINGS = ("dm_r0.3", "dm_r0.8", "dm_3+10", "dm_15+30", "dm_30+100", "hc_stop", "hc_go")
VARIANTS = ("ours", "s_attn", "nonsmooth", "average", "correct", "const_vel")
NOTES = "The lead's notes.\n\n- verbatim *markdown* line\n"
REDONE = ("nonsmooth", 1)  # this run's eval.json is deleted before the second run


def run_reproduce(*args: str) -> tuple[subprocess.CompletedProcess, float]:
    started = time.perf_counter()
    done = subprocess.run(
        [sys.executable, str(REPO_ROOT / "tools" / "reproduce.py"), *args],
        capture_output=True,
        text=True,
        env=tool_env(),
        timeout=400,
    )
    return done, time.perf_counter() - started


def eval_files(cache: Path) -> dict[Path, int]:
    return {path: path.stat().st_mtime_ns for path in sorted(cache.rglob("eval.json"))}


@pytest.fixture(scope="module")
def quick(tmp_path_factory) -> dict:
    """`--quick` into a fresh cache, then again (--overwrite) after adding notes and deleting
    one run's eval.json."""
    root = tmp_path_factory.mktemp("reproduce")
    cache, results = root / "cache", root / "report" / "RESULTS.md"
    args = ("--quick", "--out-dir", str(cache), "--results", str(results))
    first, first_s = run_reproduce(*args)
    assert first.returncode == 0, first.stderr[-2000:]
    markdown_first = results.read_text()
    before = eval_files(cache)
    redone = next(
        p
        for p in before
        if p.parent.name.startswith(f"seed{REDONE[1]}_ep1_") and p.parent.parent.name == REDONE[0]
    )
    redone_before = json.loads(redone.read_text())
    redone.unlink()
    refused, _ = run_reproduce(*args)  # the report exists and --overwrite is missing
    results.with_name("results_notes.md").write_text(NOTES)
    second, second_s = run_reproduce(*args, "--overwrite")
    assert second.returncode == 0, second.stderr[-2000:]
    print(f"--quick: first run {first_s:.1f} s, cached rerun {second_s:.1f} s")
    return {
        "root": root,
        "cache": cache,
        "results": results,
        "first": first,
        "first_s": first_s,
        "second": second,
        "second_s": second_s,
        "before": before,
        "after": eval_files(cache),
        "redone": redone,
        "redone_before": redone_before,
        "refused": refused,
        "markdown_first": markdown_first,
        "json": json.loads(results.with_name("results.json").read_text()),
    }


def test_quick_run_writes_markdown_with_tables(quick):
    first = quick["first"]
    assert first.stdout.count("\n") == 1 and first.stdout.startswith("wrote ")
    assert "0 failed" in first.stdout and "runs:" in first.stderr  # tqdm over jobs
    text = quick["markdown_first"]
    for section in (
        "## How this was produced",
        "## Settings and datasets",
        "## Paper claims",
        "## Training-set size study",
        "## Trajectories and attention",
        "## Sample trajectories",
        "## Discussion",
        "Quick smoke run",
    ):
        assert section in text
    for setting in SETTINGS:
        assert f"### `{setting}`" in text
        assert sum(line.startswith(f"| `{setting}` | Ours") for line in text.splitlines()) == 4
    assert text.count("| Ours | ") == 2 * len(SETTINGS)  # main-car and all-agent tables
    assert text.count("| Ours vs S-Attn | ") == len(SETTINGS)
    assert "cores" in text and "torch" in text and "--quick" in text
    assert "15/30 = 0.5" in text


def test_training_invocations_are_logged_and_reported(quick):
    lines = (quick["cache"] / "invocations.jsonl").read_text().splitlines()
    first, second = (json.loads(line) for line in lines)  # the refused run trained nothing
    assert first["runs"] == len(quick["before"])  # every job, const_vel's evaluations included
    assert second["runs"] == 1 and "--quick" in second["command"]
    assert 0 < second["seconds"] < first["seconds"]
    assert "Training invocations logged in the cache: 2," in quick["results"].read_text()


def test_quick_run_writes_the_figures(quick):
    figures = quick["results"].parent / "results"
    names = {p.name for p in figures.glob("*.png")}
    expected = {f"bars_{s}.png" for s in SETTINGS} | {
        "size_study.png",
        "samples_double_merge.png",
        "samples_halting_car.png",
        *(f"scene_{s}_{c}.png" for s in ("dm_r0.3", "hc_stop") for c in ("major", "minor")),
    }
    assert names == expected
    for name in names:
        data = (figures / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
        assert f"(results/{name})" in quick["markdown_first"]


def test_results_json_has_every_setting_variant_and_seed(quick):
    document = quick["json"]
    assert [s["name"] for s in document["protocol"]["settings"]] == list(SETTINGS)
    assert tuple(document["protocol"]["variants"]) == VARIANTS
    assert document["protocol"]["quick"] and document["protocol"]["epochs"] == 1
    runs = document["runs"]
    assert len(runs) == len(SETTINGS) * (5 * 2 + 1)
    for setting in SETTINGS:
        assert set(document["aggregates"][setting]) == set(VARIANTS)
        for variant in VARIANTS:
            seeds = sorted(
                r["seed"] for r in runs if r["setting"] == setting and r["variant"] == variant
            )
            assert seeds == ([0] if variant == "const_vel" else [0, 1])
    assert document["machine"]["cores"] >= 1 and document["machine"]["torch"]


def test_results_json_aggregates_match_the_runs(quick):
    document = quick["json"]
    for setting in ("dm_r0.8", "hc_go"):
        for group in ("main_agents", "all_agents"):
            for case in ("major", "minor"):
                per_seed = [
                    r[group][case]["fde"]
                    for r in document["runs"]
                    if r["setting"] == setting and r["variant"] == "ours"
                ]
                summary = document["aggregates"][setting]["ours"][group][case]["fde"]
                assert summary["mean"] == pytest.approx(np.mean(per_seed))
                assert summary["std"] == pytest.approx(np.std(per_seed, ddof=1))
    cell = document["tests"]["hc_stop"]["ours_vs_s_attn"]["main_agents"]["minor"]["ade"]
    ours = [
        r["main_agents"]["minor"]["ade"]
        for r in document["runs"]
        if r["setting"] == "hc_stop" and r["variant"] == "ours"
    ]
    other = [
        r["main_agents"]["minor"]["ade"]
        for r in document["runs"]
        if r["setting"] == "hc_stop" and r["variant"] == "s_attn"
    ]
    assert cell["p"] == pytest.approx(stats.ttest_ind(ours, other, equal_var=False).pvalue)


def test_second_run_reuses_the_cache(quick):
    second = quick["second"]
    assert "0 trained, 1 resumed, 54 reused" in second.stdout
    assert "0 datasets generated, 5 reused" in second.stdout
    after = quick["after"]
    assert set(after) == set(quick["before"])
    changed = [path for path, mtime in after.items() if quick["before"][path] != mtime]
    assert changed == [quick["redone"]]
    redone = json.loads(quick["redone"].read_text())
    for key in ("main_agents", "all_agents", "attention_accuracy", "best_epoch"):
        assert redone[key] == quick["redone_before"][key]  # resumed run: same result
    assert quick["second_s"] < 0.5 * quick["first_s"]


def test_second_run_includes_the_notes_verbatim(quick):
    text = quick["results"].read_text()
    assert "## Discussion\n\n" + NOTES.rstrip() in text


def test_existing_report_needs_overwrite(quick):
    refused = quick["refused"]
    assert refused.returncode == 2
    assert refused.stderr.count("\n") == 1 and "--overwrite" in refused.stderr


@pytest.mark.parametrize(
    "args, message",
    [
        (["--settings", "dm_r0.5"], "unknown setting 'dm_r0.5'"),
        (["--variants", "ours,bogus"], "unknown variant 'bogus'"),
        (["--seeds", "0"], "--seeds must be at least 1"),
        (["--jobs", "0"], "--jobs must be at least 1"),
        (["--epochs", "x"], "invalid int value"),
        (["--results", "report.txt"], "must name a .md file"),
    ],
)
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as exit_:
        reproduce.main(["--out-dir", str(tmp_path / "c"), *args])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert not (tmp_path / "c").exists()


# ---------------------------------------------------------------------------------- planning
def test_settings_and_groups_expand_in_canonical_order():
    names = reproduce.pick(
        "hc_go,main,dm_r0.3", tuple(reproduce.SETTING_BY_NAME), reproduce.GROUPS, "setting"
    )
    assert names == ("dm_r0.3", "hc_stop", "hc_go")
    assert reproduce.GROUPS["size"] == ("dm_3+10", "dm_15+30", "dm_30+100")


def test_quick_caps_the_major_count_and_keeps_small_settings():
    by_name = reproduce.SETTING_BY_NAME
    quick = reproduce.Protocol(tuple(by_name.values()), VARIANTS, 2, 1, quick=True)
    full = reproduce.Protocol(tuple(by_name.values()), VARIANTS, 10, 200)
    assert quick.counts(by_name["dm_3+10"]) == (10, 3)
    assert quick.counts(by_name["dm_r0.8"]) == (10, 8)  # 40 * 10/50
    assert quick.counts(by_name["dm_30+100"]) == (10, 3)
    assert full.counts(by_name["dm_15+30"]) == (30, 15)
    assert full.counts(by_name["hc_go"]) == (50, 15)


def test_jobs_cover_every_variant_and_seed(tmp_path):
    setting = reproduce.SETTING_BY_NAME["hc_go"]
    protocol = reproduce.Protocol((setting,), VARIANTS, 3, 7)
    jobs = reproduce.setting_jobs(protocol, setting, tmp_path)
    assert len(jobs) == 5 * 3 + 1
    assert {(j.variant, j.seed) for j in jobs if j.save_scenes} == {("ours", 0), ("s_attn", 0)}
    data = Path(jobs[0].data_path)
    assert data.parent == tmp_path / "data"
    assert re.fullmatch(r"halting_car_go-major_15\+50_test50_seed0_[0-9a-f]{8}\.h5", data.name)
    assert all(j.data_path == jobs[0].data_path for j in jobs)
    assert re.fullmatch(r"seed0_ep7_[0-9a-f]{8}", Path(jobs[0].run_dir).name)
    assert Path(jobs[0].run_dir).parent.name == "ours" and jobs[-1].run_dir.endswith("const_vel")
    names = {Path(j.run_dir).name for j in jobs if j.variant == "s_attn"}
    assert len(names) == 3


def test_cache_keys_change_with_the_configs(tmp_path):
    setting = reproduce.SETTING_BY_NAME["dm_r0.3"]
    protocol = reproduce.Protocol((setting,), ("ours",), 1, 5)
    spec = reproduce.data_spec(protocol, setting)
    other = dataclasses.replace(spec, scenario_digest=reproduce.digest({"changed": 1}))
    assert spec.stem != other.stem

    def key(variant: str, seed: int, epochs: int) -> str:
        return reproduce.run_dir(tmp_path, spec, variant, seed, epochs).name.split("_")[-1]

    keys = {key("ours", 0, 5), key("nonsmooth", 0, 5), key("ours", 1, 5), key("ours", 0, 6)}
    assert len(keys) == 4 and key("ours", 0, 5) == key("ours", 0, 5)
    assert reproduce.digest({"a": 1, "b": 2}) == reproduce.digest({"b": 2, "a": 1})


def test_figure_scenes_pick_the_first_interacting_scene_per_case():
    case = np.array([1, 0, 0, 1, 0])
    interaction = np.zeros((5, 4), dtype=bool)
    interaction[2, 1] = interaction[4, 3] = True
    assert reproduce.figure_scenes(case, interaction, 2) == [2, 0]  # case 1: none -> first


# ---------------------------------------------------------------------------------- statistics
def test_summary_is_mean_and_sample_std():
    summary = _report.summarize([1.0, 2.0, None, 3.0, 4.0])
    assert summary["n"] == 4 and summary["mean"] == pytest.approx(2.5)
    assert summary["std"] == pytest.approx(math.sqrt(5.0 / 3.0))  # squared deviations 5, n-1 3
    assert _report.summarize([2.0]) == {"mean": 2.0, "std": None, "n": 1}
    assert _report.summarize([None]) == {"mean": None, "std": None, "n": 0}


def test_welch_test_matches_scipy_and_the_formula():
    a, b = [0.51, 0.48, 0.55, 0.50, 0.47], [0.62, 0.70, 0.58, 0.66]
    result = _report.welch_test(a, b)
    assert result["p"] == pytest.approx(stats.ttest_ind(a, b, equal_var=False).pvalue)
    va, vb = np.var(a, ddof=1) / len(a), np.var(b, ddof=1) / len(b)
    t = (np.mean(a) - np.mean(b)) / math.sqrt(va + vb)
    df = (va + vb) ** 2 / (va**2 / (len(a) - 1) + vb**2 / (len(b) - 1))
    assert result["t"] == pytest.approx(t)
    assert result["p"] == pytest.approx(2 * stats.t.sf(abs(t), df))
    assert _report.welch_test([1.0], [2.0, 3.0]) == {"t": None, "p": None}


def fake_eval(ade: dict, fde: dict, accuracy: float = 0.5) -> dict:
    """An eval.json of a halting-car setting with `go` as the major case."""
    names = {"major": "go", "minor": "stop"}

    def group(scale: float) -> dict:
        cases = {names[r]: {"ade": scale * ade[r], "fde": scale * fde[r]} for r in names}
        return {"cases": cases, "overall": {"ade": scale * ade["major"], "fde": 0.0}}

    acc = {
        "cases": {n: {"accuracy": accuracy, "mean_weight": accuracy / 2} for n in names.values()},
        "overall": {"accuracy": accuracy, "mean_weight": accuracy / 2},
    }
    return {
        "major_case": "go",
        "case_names": ["stop", "go"],
        "main_agents": group(1.0),
        "all_agents": group(0.1),
        "attention_accuracy": acc,
        "train_seconds": 2.0,
    }


def hand_records() -> list[dict]:
    rows = [
        ("ours", 0, 1.0, 2.0),
        ("ours", 1, 3.0, 4.0),
        ("s_attn", 0, 5.0, 8.0),
        ("s_attn", 1, 7.0, 8.0),
        ("const_vel", 0, 9.0, 9.0),
    ]
    return [
        _report.make_record(
            "hc_go", v, s, fake_eval({"major": a, "minor": m}, {"major": 2 * a, "minor": 2 * m})
        )
        for v, s, a, m in rows
    ]


def test_records_map_case_names_to_major_and_minor():
    record = hand_records()[0]
    assert record["case_names"] == {"major": "go", "minor": "stop"}
    assert record["main_agents"]["major"] == {"ade": 1.0, "fde": 2.0}
    assert record["main_agents"]["minor"] == {"ade": 2.0, "fde": 4.0}
    assert record["all_agents"]["minor"]["ade"] == pytest.approx(0.2)


def test_attention_weight_is_aggregated_and_tabled():
    aggregates = _report.aggregate(hand_records())
    weight = aggregates["hc_go"]["ours"]["attention_weight"]["minor"]
    assert weight == {"mean": 0.25, "std": 0.0, "n": 2}  # fake_eval: weight = accuracy / 2
    names = {"major": "go", "minor": "stop"}
    lines = _report.results_table(
        aggregates, "hc_go", ("ours", "const_vel"), "main_agents", names
    ).splitlines()
    assert "attn. weight major" in lines[0]
    assert lines[2].startswith("| Ours |") and lines[2].count("0.250 ± 0.000") == 2
    assert lines[3].startswith("| Const-Vel |") and lines[3].count("n/a") == 4


def test_bar_inputs_from_hand_made_runs():
    aggregates = _report.aggregate(hand_records())
    bars = _report.bar_inputs(
        aggregates, "hc_go", "ade", ("s_attn", "nonsmooth", "ours", "const_vel")
    )
    assert bars.variants == ("s_attn", "ours", "const_vel")  # nonsmooth was not run
    assert bars.cases == ("major", "minor")
    np.testing.assert_allclose(bars.means, [[6.0, 8.0], [2.0, 3.0], [9.0, 9.0]])
    root2 = math.sqrt(2.0)  # sample std of two values d apart is d / sqrt(2)
    np.testing.assert_allclose(bars.errors, [[root2, 0.0], [root2, root2], [0.0, 0.0]])
    fde = _report.bar_inputs(aggregates, "hc_go", "fde", ("ours",))
    np.testing.assert_allclose(fde.means, [[4.0, 6.0]])


def test_size_series_from_hand_made_runs():
    aggregates = _report.aggregate(hand_records())
    mean, std = _report.series(aggregates, ["hc_go", "missing"], "s_attn", "minor", "fde")
    np.testing.assert_allclose(mean, [16.0, np.nan])  # 2 x minor ADE 8 in both seeds
    np.testing.assert_allclose(std, [0.0, 0.0])


def test_comparisons_and_verdicts_on_hand_made_runs():
    tests = _report.compare(hand_records())
    cell = tests["hc_go"]["ours_vs_s_attn"]["main_agents"]["major"]["ade"]
    assert cell["mean_ours"] == 2.0 and cell["mean_other"] == 6.0
    assert cell["p"] == pytest.approx(stats.ttest_ind([1, 3], [5, 7], equal_var=False).pvalue)
    assert _report.better_verdict(1.0, 2.0, 0.001, 0.01) == "holds"
    assert _report.better_verdict(1.0, 2.0, 0.02, 0.01) == "not significant"
    assert _report.better_verdict(1.0, 2.0, None, 0.01) == "not significant"
    assert _report.better_verdict(2.0, 1.0, 0.001, 0.01) == "does not hold"
    assert _report.better_verdict(None, 1.0, 0.5, 0.01) == "n/a"
    assert _report.claim_cell(None, "better") == "n/a (not run)"
    assert _report.claim_cell(
        {"mean_ours": 1.1, "mean_other": 1.0, "p": 0.4}, "comparable"
    ).startswith("holds (no significant difference) (+10%")


@pytest.mark.parametrize(
    "ours_by_size, verdict",
    [
        ([1.0, 1.6, 1.9], "holds"),  # margins 1.0, 0.4, 0.1
        ([1.0, 1.9, 1.6], "partly"),  # margins 1.0, 0.1, 0.4
        ([1.9, 1.6, 1.0], "does not hold"),  # margins 0.1, 0.4, 1.0
    ],
)
def test_size_claim_needs_a_shrinking_margin(ours_by_size, verdict):
    records = []
    for k, ours in enumerate(ours_by_size):
        for variant, ade in (("ours", ours), ("nonsmooth", 2.0)):
            records.append(
                _report.make_record(
                    f"size{k}",
                    variant,
                    0,
                    fake_eval({"major": ade, "minor": ade}, {"major": ade, "minor": ade}),
                )
            )
    cells = _report.size_claim(_report.aggregate(records), ["size0", "size1", "size2"])
    assert set(cells) == {"major ade", "major fde", "minor ade", "minor fde"}
    assert all(cell.startswith(verdict + " (") for cell in cells.values())
