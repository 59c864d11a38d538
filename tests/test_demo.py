"""tools/demo.py, the README's main job: one short run end to end, every output read back."""

from __future__ import annotations

import json

import numpy as np
import pytest
from browser import chromium, open_page, requested
from conftest import load_tool, run_tool
from test_viewer import page_content

from predictor.baselines import constant_velocity
from predictor.predictions import load_predictions
from trajectory_data.reader import read_meta, read_split


def test_demo_refuses_a_folder_it_did_not_write(tmp_path):
    demo = load_tool("demo.py")
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("the user's")
    completed = run_tool("demo.py", "--out", out, "--epochs", "1", timeout=120)
    assert completed.returncode == 2
    assert completed.stderr.strip().splitlines() == [
        f"error: --out {out} holds files the demo did not write; pass --overwrite to replace it"
    ]
    assert (out / "notes.txt").read_text() == "the user's"
    older = tmp_path / "older_demo"  # written before the marker: only the demo's own names
    older.mkdir()
    (older / "episode.png").write_bytes(b"old")
    assert demo.replace_output_folder(older, overwrite=False) is None
    assert sorted(p.name for p in older.iterdir()) == [".demo-output"]
    bad_seed = run_tool("demo.py", "--out", tmp_path / "new", "--seed", "-1", timeout=120)
    assert bad_seed.returncode == 2 and "seed" in bad_seed.stderr
    assert not (tmp_path / "new").exists()


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The demo of one epoch, into a folder an earlier demo left a stale file in."""
    out = tmp_path_factory.mktemp("demo") / "demo"
    out.mkdir()
    (out / ".demo-output").write_text("an earlier demo's")
    (out / "stale.txt").write_text("from an earlier run")
    completed = run_tool("demo.py", "--out", out, "--epochs", "3", timeout=600)
    assert completed.returncode == 0, completed.stderr
    return out, completed


def test_demo_writes_every_output_and_reports_both_predictors(demo):
    out, completed = demo
    last = completed.stdout.strip().splitlines()[-1]
    assert last.startswith("demo done in ") and last.endswith(f"results in {out}/")

    expected = {
        "episode.png",
        "episode.gif",
        "double_merge_v1.h5",
        "run_ours",
        "predictions.npz",
        "eval_const_vel.json",
        "samples.png",
        "predictions.png",
        "attention.png",
        "view.html",
        ".demo-output",
    }
    assert {p.name for p in out.iterdir()} == expected  # the stale file went with the old run
    for name in ("episode.png", "samples.png", "predictions.png", "attention.png"):
        assert (out / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert (out / "episode.gif").read_bytes()[:6] == b"GIF89a"
    assert_frames_explain_themselves(out / "episode.gif")

    data = out / "double_merge_v1.h5"
    meta, test = read_meta(data), read_split(data, "test")
    assert test.n == 20  # the demo's 10 test trajectories per case
    predictions = load_predictions(out / "predictions.npz")
    assert predictions.predictor == "ours" and predictions.n == test.n
    np.testing.assert_array_equal(predictions.true_xy, test.states[..., :2])

    # the baseline's main-car ADE, computed here from the test split (every car is present)
    assert test.valid.all()
    truth = test.states[:, meta.num_observed :, :, :2]
    pred = constant_velocity(test.states[..., :2], test.valid, meta.num_observed)
    error = np.linalg.norm(pred - truth, axis=-1)[:, :, :2]  # (n, T_pred, 2): the main cars
    ade = float(error[test.valid[:, meta.num_observed :, :2]].mean())
    const_vel = json.loads((out / "eval_const_vel.json").read_text())
    assert np.isclose(const_vel["main_agents"]["overall"]["ade"], ade, rtol=1e-5)
    assert f"vs {ade:.2f} m (constant velocity)" in last

    # the default preset learns: after 3 epochs it beats constant velocity on the main cars and
    # on all cars, and attends most to the labelled car in at least half of the labelled steps
    ours = json.loads((out / "run_ours" / "eval.json").read_text())
    everyone = np.linalg.norm(pred - truth, axis=-1)[test.valid[:, meta.num_observed :]].mean()
    assert np.isclose(const_vel["all_agents"]["overall"]["ade"], everyone, rtol=1e-5)
    assert ours["main_agents"]["overall"]["ade"] < ade
    assert ours["all_agents"]["overall"]["ade"] < everyone
    assert ours["attention_accuracy"]["overall"]["accuracy"] >= 0.5


def test_demo_writes_a_viewer_of_its_test_split_and_predictions(demo):
    out, completed = demo
    spec, arrays = page_content((out / "view.html").read_text())
    data, predictions = out / "double_merge_v1.h5", load_predictions(out / "predictions.npz")
    test = read_split(data, "test")
    assert spec["shown"] == spec["available"] == test.n == 20
    assert np.array_equal(arrays["xy"], test.states[..., :2])
    assert np.array_equal(arrays["pred"], predictions.pred_mean)
    assert spec["source"]["predictions"] == "predictions.npz"
    assert spec["source"]["run"].startswith(f"run {out / 'run_ours'}: ours (")
    assert f"{out / 'view.html'}: 20 of 20 test scenes, predictions of ours;" in completed.stdout


def test_the_demos_viewer_opens_from_disk_and_loads_nothing_else(demo):
    out, _ = demo
    with chromium() as driver:
        requested(driver)  # what the fresh browser did before: not the page's
        open_page(driver, out / "view.html")
        # the page's own file is all it asks for: no script, style, font or image requests
        assert requested(driver) == [(out / "view.html").resolve().as_uri()]
        assert len(driver.find_elements("css selector", "#scenes tbody tr")) == 20


def assert_frames_explain_themselves(gif) -> None:
    """Every frame of the demo's GIF has a title strip with text above the road and a legend
    strip below it with a swatch of each car colour (to the GIF palette's rounding)."""
    import imageio.v3 as iio

    from carlo_lite.render import ROLE_COLORS
    from pipeline.frames import STRIP_COLOR, STRIP_PX

    frames = iio.imread(gif)
    assert frames.shape[1:] == (160 + 2 * STRIP_PX, 640, 3)  # the demo renders 640 x 160
    for frame in frames:
        title, legend = frame[:STRIP_PX].astype(int), frame[-STRIP_PX:].astype(int)
        assert (np.abs(title - STRIP_COLOR).sum(axis=-1) > 60).sum() > 100  # the title's text
        for color in ROLE_COLORS.values():
            near = np.abs(legend - np.array(color)).max(axis=-1) <= 2  # the strip is 248
            assert near.sum() >= 50, color
