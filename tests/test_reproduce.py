"""tools/reproduce.py and pipeline.reproduction: a --quick smoke run (twice: the second reuses
the cache) in subprocesses, interrupts, usage errors and where the report goes. The results
store and the invocation log are in test_result_store.py, the planning (which jobs, where,
under which keys) in test_run_plan.py; the report's statistics are tested on hand-made
numbers in test_report.py."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from browser import chromium, open_page, requested
from conftest import REPO_ROOT, load_tool, run_tool, tool_env
from scipy import stats
from test_viewer import page_content

from predictor.checkpoints import read_checkpoint
from trajectory_data.reader import read_split

reproduce = load_tool("reproduce.py")

SETTINGS = ("dm_r0.3", "dm_r0.8", "dm_3+10", "dm_15+30", "dm_30+100", "hc_stop", "hc_go")
BASELINE_VARIANTS = ("const_vel", "ridge", "ridge_labelled", "ridge_labelled_relation")
VARIANTS = ("ours", "s_attn", "nonsmooth", "average", "correct", *BASELINE_VARIANTS)
# the baselines are evaluated once, not trained per seed
NOTES = "The lead's notes.\n\n- verbatim *markdown* line\n"
REDONE = ("nonsmooth", 1)  # this run's eval.json is deleted before the second run


def run_reproduce(*args: str) -> tuple[subprocess.CompletedProcess, float]:
    started = time.perf_counter()
    done = run_tool("reproduce.py", *args, timeout=1200)
    return done, time.perf_counter() - started


STALE_FIGURE = "bars_dm_gone.png"  # listed by the first report's results.json, not redrawn
USER_FILE = "kept_by_user.png"  # in results/ but never listed: not the report's to remove


def eval_files(cache: Path) -> dict[Path, int]:
    return {path: path.stat().st_mtime_ns for path in sorted(cache.rglob("eval.json"))}


@pytest.fixture(scope="module")
def quick(tmp_path_factory) -> dict:
    """`--quick` into a fresh cache, then again (--overwrite) after adding notes and deleting
    one run's eval.json."""
    root = tmp_path_factory.mktemp("reproduce")
    cache, results = root / "cache", root / "report" / "RESULTS.md"
    args = ("--quick", "--out-dir", str(cache), "--report", str(results))
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
    # a figure the first report listed but the second will not draw, and a file of the user's
    listed = json.loads(results.with_name("results.json").read_text())
    listed["figures"]["bars"].append(STALE_FIGURE)
    results.with_name("results.json").write_text(json.dumps(listed))
    (results.parent / "results" / STALE_FIGURE).write_bytes(b"stale")
    (results.parent / "results" / USER_FILE).write_bytes(b"mine")
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
    # no silent phase after the bar: status lines while the results are gathered and written
    assert "reproduce: collecting the results of" in first.stderr
    assert "reproduce: writing the report, its figures and results.json to" in first.stderr
    text = quick["markdown_first"]
    for section in (
        "## How this was produced",
        "## Settings and datasets",
        "## Paper claims",
        "## The bar: simple baselines",
        "## Training-set size study",
        "## Trajectories and attention",
        "## Sample trajectories",
        "## Discussion",
        "Quick smoke run",
    ):
        assert section in text
    lines = text.splitlines()
    for setting in SETTINGS:
        assert f"### `{setting}`" in text
        ours = [line for line in lines if line.startswith(f"| `{setting}` | Ours ")]
        bar = [line for line in ours if "| major |" in line or "| minor |" in line]
        assert len(ours) - len(bar) == 4  # the claims table's rows
    # main-car and all-agent tables, the main cars' sampled scores (runs evaluate K = 20) and
    # the attention's faithfulness (its total variation, measured for every run with attention)
    assert sum(line.startswith("| Ours | ") for line in lines) == 4 * len(SETTINGS)
    for case in ("major", "minor"):  # the bar: Ours (and Ours [paper]) against the oracle ridges
        for model, settings in (("Ours", SETTINGS), ("Ours [paper]", ("dm_r0.3", "hc_stop"))):
            rows = [f"| `{s}` | {model} | {case} | " for s in settings]
            assert sum(line.startswith(tuple(rows)) for line in text.splitlines()) == len(rows)
    assert text.count("| Ours vs S-Attn | ") == len(SETTINGS)
    assert "cores" in text and "torch" in text and "--quick" in text
    assert "compared with `paper` (on `dm_r0.3`, `hc_stop`) (Ours)" in text
    assert "## Presets side by side" in text
    assert sum(line.startswith("| Ours [paper] | ") for line in text.splitlines()) == 2
    assert "15/30 = 0.5" in text


def test_training_invocations_are_logged_and_reported(quick):
    lines = (quick["cache"] / "invocations.jsonl").read_text().splitlines()
    first, second = (json.loads(line) for line in lines)  # the refused run trained nothing
    assert first["runs"] == len(quick["before"])  # every job, const_vel's evaluations included
    assert second["runs"] == 1 and "--quick" in second["command"]
    assert 0 < second["seconds"] < first["seconds"]
    assert "Training invocations logged: 2," in quick["results"].read_text()


def test_quick_run_writes_the_figures(quick):
    figures = quick["results"].parent / "results"
    names = {p.name for p in figures.glob("*.png")} - {USER_FILE}
    expected = {f"bars_{s}.png" for s in SETTINGS} | {
        "size_study.png",
        "samples_double_merge_v1.png",
        "samples_halting_car_v1.png",
        *(f"scene_{s}_{c}.png" for s in ("dm_r0.3", "hc_stop") for c in ("major", "minor")),
    }
    assert names == expected
    for name in names:
        data = (figures / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000
        assert f"(results/{name})" in quick["markdown_first"]
    listed = [name for names in quick["json"]["figures"].values() for name in names]
    assert sorted(listed) == sorted(expected | set(VIEWERS.values()))


VIEWERS = {setting: f"view_{setting}.html" for setting in ("dm_r0.3", "hc_stop")}


def test_quick_run_writes_a_viewer_of_the_figure_scenes_and_links_it(quick):
    """Per main setting, the viewer of its test scenes drawn in the report (per case the first
    with an interaction period, else the first) with Ours' predictions, linked from the
    markdown."""
    for setting, name in VIEWERS.items():
        page = quick["results"].parent / "results" / name
        spec, arrays = page_content(page.read_text())
        test = read_split(quick["cache"] / "data" / spec["source"]["data"], "test")
        first = []
        for case in range(len(spec["case_names"])):
            rows = np.flatnonzero(test.case == case)
            busy = [k for k in rows if test.interaction[k].any()]
            first.append(int((busy or rows)[0]))
        assert spec["scenes"]["row"] == first, setting
        assert np.array_equal(arrays["xy"], test.states[first, ..., :2])
        assert spec["source"]["predictor"] == "ours" and arrays["attention"].shape[0] == 2
        assert f"[`{setting}`](results/{name})" in quick["markdown_first"]


def test_the_reproductions_viewer_opens_from_disk_and_asks_for_nothing_else(quick):
    page = quick["results"].parent / "results" / VIEWERS["hc_stop"]
    with chromium() as driver:
        requested(driver)
        open_page(driver, page)
        assert requested(driver) == [page.resolve().as_uri()]
        assert len(driver.find_elements("css selector", "#scenes tbody tr")) == 2


def test_rerun_removes_the_stale_figures_its_report_listed_only(quick):
    figures = quick["results"].parent / "results"
    assert not (figures / STALE_FIGURE).exists()
    assert (figures / USER_FILE).read_bytes() == b"mine"


def test_results_json_has_every_setting_variant_and_seed(quick):
    document = quick["json"]
    assert [s["name"] for s in document["protocol"]["settings"]] == list(SETTINGS)
    assert tuple(document["protocol"]["variants"]) == VARIANTS
    assert document["protocol"]["quick"] and document["protocol"]["epochs"] == 1
    assert document["protocol"]["preset"] == "agent"  # the default: this project's model
    assert document["protocol"]["compare_presets"] == ["paper"]  # beside it on main
    runs = document["runs"]
    assert len(runs) == len(SETTINGS) * (5 * 2 + len(BASELINE_VARIANTS)) + 2 * 2
    for setting in SETTINGS:
        paper = ["ours@paper"] if setting in ("dm_r0.3", "hc_stop") else []  # main only
        assert set(document["aggregates"][setting]) == {*VARIANTS, *paper}
        seeds = sorted(
            r["seed"] for r in runs if (r["setting"], r["variant"]) == (setting, "ours@paper")
        )
        assert seeds == ([0, 1] if paper else [])
        for variant in VARIANTS:
            seeds = sorted(
                r["seed"] for r in runs if r["setting"] == setting and r["variant"] == variant
            )
            assert seeds == ([0] if variant in BASELINE_VARIANTS else [0, 1])
    assert document["machine"]["cores"] >= 1 and document["machine"]["torch"]
    modes = {r["graph_step"] for r in runs if r["variant"] not in BASELINE_VARIANTS}
    assert modes == {"eager"} and not document["protocol"]["compile_graph_step"]
    assert {r["graph_step"] for r in runs if r["variant"] in BASELINE_VARIANTS} == {None}
    trained = len(runs) - len(SETTINGS) * len(BASELINE_VARIANTS)
    assert f"rounding, one row): eager ({trained} runs)" in quick["results"].read_text()


def test_the_sampled_scores_of_each_runs_eval_json_are_in_the_report(quick):
    """hc_go's table of sampled scores gives mean ± std over Ours' two seeds of what their
    eval.json files hold; results.json lists them per run and aggregated."""
    files = [
        json.loads(path.read_text())
        for path in sorted(
            (quick["cache"] / "runs").glob("halting_car_*_go-major_*/ours/*/eval.json")
        )
    ]
    assert len(files) == 2 and all(f["sampling"]["k"] == 20 for f in files)
    assert all(f["sampling"]["miss_threshold_m"] == 2.0 for f in files)
    text = quick["results"].read_text()
    lines = text.split("### `hc_go`")[1].split("\n### ")[0].splitlines()
    lead = next(line for line in lines if line.startswith("Sampled futures of the main cars"))
    assert "K = 20 per car" in lead and "above 2 m" in lead
    table = lines[lines.index(lead) + 2 :]
    assert table[0].startswith("| variant | major (go) minADE_20 | major (go) minFDE_20 |")
    row = next(line for line in table if line.startswith("| Ours | ")).split(" | ")
    digits = {"min_ade": 3, "min_fde": 3, "miss_rate": 2, "nll": 2}
    for k, (case, metric) in enumerate(
        (case, metric) for case in ("go", "stop") for metric in digits
    ):
        seeds = [f["main_agents"]["cases"][case][metric] for f in files]
        mean, std, d = np.mean(seeds), np.std(seeds, ddof=1), digits[metric]
        assert row[1 + k] == f"{mean:.{d}f} ± {std:.{d}f}"
    assert row[-1] == "2 |"
    consts = next(line for line in table if line.startswith("| Const-Vel | "))
    assert consts.endswith("| 1 |")  # the baselines sample too (CVM-S)
    runs = [r for r in quick["json"]["runs"] if (r["setting"], r["variant"]) == ("hc_go", "ours")]
    assert {r["sample_k"] for r in runs} == {20}
    aggregate = quick["json"]["aggregates"]["hc_go"]["ours"]["main_agents"]["major"]["min_fde"]
    per_seed = [f["main_agents"]["cases"]["go"]["min_fde"] for f in files]
    assert aggregate["mean"] == pytest.approx(np.mean(per_seed)) and aggregate["n"] == 2


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
    runs = len(quick["before"])  # every run of the first invocation has its eval.json
    assert f"{runs} runs (0 trained, 1 resumed, {runs - 1} reused" in second.stdout
    assert "0 datasets generated, 5 reused" in second.stdout
    after = quick["after"]
    assert set(after) == set(quick["before"])
    changed = [path for path, mtime in after.items() if quick["before"][path] != mtime]
    assert changed == [quick["redone"]]
    redone = json.loads(quick["redone"].read_text())
    for key in ("main_agents", "all_agents", "attention_accuracy", "best_epoch"):
        assert redone[key] == quick["redone_before"][key]  # resumed run: same result


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
        (["--report", "report.txt"], "must name a .md file"),
        (["--budget-minutes", "-1"], "--budget-minutes must not be negative"),
        (["--budget-minutes", "nan"], "--budget-minutes must not be negative"),
        (["--store", str(REPO_ROOT / "README.md")], "exists and is not a directory"),
        (["--store", "s", "--no-store"], "not allowed with argument"),
        (["--compare-presets", "agent_zero_cv,bogus"], "unknown compared preset 'bogus'"),
        (["--compare-presets", "agent"], "names 'agent', the report's own --preset"),
        (["--compare-presets", "agent_zero_cv,agent_zero_cv@main"], "names 'agent_zero_cv' twice"),
        (["--compare-presets", "paper@dm_r0.5"], "unknown setting 'dm_r0.5'"),
        (["--compare-presets", "agent", "--compare-variants", "ridge"], "compared variant 'ridge'"),
        (["--compile-graph-step", "maybe"], "invalid choice: 'maybe'"),
    ],
)
def test_bad_input_is_one_line_exit_2(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as exit_:
        reproduce.main(["--out-dir", str(tmp_path / "c"), *args])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert not (tmp_path / "c").exists()


def test_a_compiled_graph_step_without_a_compiler_is_one_line_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("CXX", "no-such-compiler-here")
    with pytest.raises(SystemExit) as exit_:
        reproduce.main(["--out-dir", str(tmp_path / "c"), "--compile-graph-step", "yes"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "needs a C++ compiler ('no-such-compiler-here'" in err
    assert not (tmp_path / "c").exists()


def test_no_arguments_mean_the_agent_preset_with_the_paper_preset_on_the_main_settings():
    """Issue 16's protocol: this project's model on every setting, the paper's literal model
    beside it on the main settings, 10 seeds of 200 epochs."""
    default = reproduce.protocol_from_args(reproduce.parse_args([]))
    assert (default.preset, default.seeds, default.epochs) == ("agent", 10, 200)
    assert [s.name for s in default.settings] == list(SETTINGS)
    assert default.compare_presets == ("paper",) and default.compare_variants == ("ours",)
    assert {s.name: default.presets_compared_on(s.name) for s in default.settings} == {
        name: ("paper",) if name in ("dm_r0.3", "hc_stop") else () for name in SETTINGS
    }
    paper = reproduce.protocol_from_args(reproduce.parse_args(["--preset", "paper"]))
    assert paper.preset == "paper" and paper.compare_presets == ()
    assert not default.compile_graph_step
    compiled = reproduce.parse_args(["--compile-graph-step", "yes"])
    assert reproduce.protocol_from_args(compiled).compile_graph_step
    quick = reproduce.protocol_from_args(reproduce.parse_args(["--quick"]))
    assert (quick.preset, quick.compare_presets, quick.seeds) == ("agent", ("paper",), 2)
    none = reproduce.protocol_from_args(reproduce.parse_args(["--compare-presets", ""]))
    assert none.compare_presets == ()
    both = reproduce.parse_args(["--compare-presets", "agent_zero_cv, paper@hc_go"])
    both = reproduce.protocol_from_args(both)
    assert both.compare_presets == ("agent_zero_cv", "paper")
    assert both.presets_compared_on("hc_go") == ("agent_zero_cv", "paper")
    assert both.presets_compared_on("hc_stop") == ("agent_zero_cv",)


def test_default_report_goes_under_the_output_directory(tmp_path, monkeypatch):
    """A fresh clone holds docs/RESULTS.md; the README's command must not collide with it."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "RESULTS.md").write_text("published\n")
    args = reproduce.parse_args(["--settings", "main", "--seeds", "5"])
    out_dir, report = reproduce.output_paths(args)
    assert (out_dir, report) == (Path("outputs/reproduce"), Path("outputs/reproduce/RESULTS.md"))
    args = reproduce.parse_args(["--quick", "--out-dir", "elsewhere"])
    assert reproduce.output_paths(args)[1] == Path("elsewhere/RESULTS.md")
    args = reproduce.parse_args(["--report", "docs/RESULTS.md", "--overwrite"])
    assert reproduce.output_paths(args)[1] == Path("docs/RESULTS.md")


def test_publishing_over_docs_needs_overwrite(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "RESULTS.md").write_text("published\n")
    with pytest.raises(SystemExit) as exit_:
        reproduce.main(["--settings", "main", "--report", "docs/RESULTS.md"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "docs/RESULTS.md already exists; pass --overwrite" in err
    assert not (tmp_path / "outputs").exists()


def test_results_beside_a_new_report_and_unusable_folders_are_refused_first(
    tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "results.json").write_text("precious\n")
    (tmp_path / "file.h5").write_text("data\n")
    for args, message in (
        (["--report", "mine/NEW.md"], "mine/results.json already exists; pass --overwrite"),
        (["--report", "file.h5/R.md"], "--report: file.h5 is a file, so file.h5 cannot be a"),
        (["--out-dir", "file.h5/cache"], "--out-dir: file.h5 is a file, so file.h5/cache"),
    ):
        with pytest.raises(SystemExit) as exit_:
            reproduce.main(["--quick", "--settings", "dm_3+10", "--variants", "const_vel", *args])
        assert exit_.value.code == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
    assert (tmp_path / "mine" / "results.json").read_text() == "precious\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file.h5", "mine"]


def wait_for_training(cache: Path, process: subprocess.Popen, timeout: float = 300.0) -> None:
    """Return once a run being trained has finished an epoch (its metrics.jsonl has a line)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if any(m.read_text().strip() for m in cache.glob("runs/*/ours/*/metrics.jsonl")):
            return
        if process.poll() is not None:
            pytest.fail(f"reproduce.py ended early: {process.stderr.read()[-2000:]}")
        time.sleep(0.05)
    process.kill()
    pytest.fail("no epoch finished in time")


@pytest.mark.parametrize(
    "how, jobs",
    [("ctrl-c to the process group", 2), ("sigterm to the parent", 1)],
)
def test_interrupt_stops_at_a_safe_point_and_the_rerun_resumes(tmp_path, how, jobs):
    cache, report = tmp_path / "cache", tmp_path / "report" / "RESULTS.md"
    args = ["--quick", "--settings", "hc_go", "--variants", "ours", "--seeds", str(jobs)]
    epochs = 10  # an epoch takes seconds: the signal comes long before the last one
    args += [
        "--epochs",
        str(epochs),
        "--jobs",
        str(jobs),
        "--out-dir",
        str(cache),
        "--report",
        str(report),
    ]
    process = subprocess.Popen(
        [sys.executable, str(REPO_ROOT / "tools" / "reproduce.py"), *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=tool_env(),
        start_new_session=True,  # its own process group, as a terminal would have it
    )
    wait_for_training(cache, process)
    if how.startswith("ctrl-c"):
        os.killpg(process.pid, signal.SIGINT)  # the parent and its workers, as a terminal does
    else:
        process.send_signal(signal.SIGTERM)  # the parent alone
    out, err = process.communicate(timeout=300)
    assert process.returncode == 130, err[-2000:]
    assert err.splitlines()[-1] == (
        "error: interrupted; finished runs are cached: run the same command again to resume"
    )
    assert "Traceback" not in err and "KeyboardInterrupt" not in err and out == ""
    assert [p for p in tmp_path.rglob("*") if ".tmp" in p.name] == []
    assert list(cache.rglob("eval.json")) == [] and not report.exists()
    assert not (cache / "invocations.jsonl").exists()
    checkpoints = list(cache.glob("runs/*/ours/*/last.pt"))
    assert checkpoints  # at least the run that finished an epoch
    for last in checkpoints:  # each stopped between epochs: its files agree
        lines = (last.parent / "metrics.jsonl").read_text().splitlines()
        done = [json.loads(line)["epoch"] for line in lines]
        assert 1 <= len(done) < epochs and done == list(range(1, len(done) + 1))
        assert read_checkpoint(last)["epoch"] == done[-1]
    resumed, _ = run_reproduce(*args)
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    trained, again = (
        int(n) for n in re.search(r"(\d+) trained, (\d+) resumed", resumed.stdout).groups()
    )
    assert again == len(checkpoints) and trained + again == jobs
    for result in cache.rglob("eval.json"):
        assert json.loads(result.read_text())["epochs"] == epochs
