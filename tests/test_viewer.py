"""The viewer's page content, checked from Python: the arrays it carries are the dataset's and
the predictions' (unpacked from the written HTML), its per-scene scores are the project's
metrics (and a hand computation), the same inputs give the same bytes, and bad inputs get one
line (library and tools/view.py). What the browser draws: tests/test_viewer_browser.py."""

from __future__ import annotations

import json
import re
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import make_meta, make_trajectory_set, run_tool
from test_training import TINY_MODEL

from pipeline.generation import GenerateConfig, generate_dataset
from pipeline.viewer import ViewerError, make_viewer, write_viewer
from pipeline.viewer.content import SHOWN_SAMPLES
from pipeline.viewer.pack import dequantize_unit, pack, quantize_unit, unpack
from pipeline.viewer.scores import scene_scores
from predictor.evaluation import evaluate_baseline, evaluate_run
from predictor.forecasting import SampleSettings, score
from predictor.predictions import load_predictions
from predictor.presets import make_configs
from predictor.training import train
from trajectory_data.format import write_dataset
from trajectory_data.reader import read_meta, read_split


def make_files(folder: Path, num_test: int = 3, epochs: int = 1) -> dict[str, Path]:
    """A Halting Car v3 dataset (2 * num_test test scenes of 22 cars), a tiny run trained on it
    and two predictions files of its test split: the run's and constant velocity's."""
    folder.mkdir(parents=True, exist_ok=True)
    config = GenerateConfig.for_scenario(
        "halting_car_v3", num_major=4, num_minor=1, num_test=num_test, seed=0
    )
    data = generate_dataset(config, folder / "hc.h5", progress=False).path
    model_config, train_config = make_configs(
        "ours", TINY_MODEL, epochs=epochs, batch_size=3, seed=0, lr=3e-3
    )
    train(data, model_config, train_config, folder / "run", progress=False)
    files = {"data": Path(data), "run": folder / "run"}
    files["ours"] = folder / "ours.npz"
    evaluate_run(folder / "run", data, "test").predictions.save(files["ours"])
    files["const_vel"] = folder / "const_vel.npz"
    evaluate_baseline("const_vel", data, "test").predictions.save(files["const_vel"])
    return files


def page_content(html: str) -> tuple[dict, dict[str, np.ndarray]]:
    """The description and the arrays a written page carries."""
    spec = json.loads(re.search(r'id="viewer-data">(.*?)</script>', html, re.S).group(1))
    blob = re.search(r'id="viewer-blob">(.*?)</script>', html, re.S).group(1)
    return spec, unpack(spec["arrays"], blob)


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    return make_files(tmp_path_factory.mktemp("viewer"))


# ---- packing -----------------------------------------------------------------------------
def test_pack_round_trip_keeps_every_array_exactly_and_aligned():
    rng = np.random.default_rng(0)
    arrays = {
        "a": rng.normal(size=(3, 5, 2)).astype(np.float32),
        "b": rng.integers(0, 2, size=7).astype(np.uint8),  # 7 bytes: the next one is padded
        "c": rng.integers(-1, 20, size=(2, 3)).astype(np.int16),
        "d": rng.integers(0, 65535, size=9).astype(np.uint16),
        "e": rng.integers(-5, 5, size=3).astype(np.int8),
    }
    header, blob = pack(arrays)
    assert all(entry["offset"] % 8 == 0 for entry in header.values())
    back = unpack(header, blob)
    for name, array in arrays.items():
        assert back[name].dtype == array.dtype and np.array_equal(back[name], array), name
    with pytest.raises(TypeError, match="float64"):
        pack({"x": np.zeros(2)})


def test_quantised_weights_are_within_half_a_step_and_keep_nan():
    weights = np.array([0.0, 1.0, 0.5, 1 / 3, 0.0476, np.nan], dtype=np.float32)
    codes = quantize_unit(weights)
    assert codes.dtype == np.uint16 and codes[0] == 0 and codes[1] == 65534 and codes[5] == 65535
    back = dequantize_unit(codes)
    assert np.isnan(back[5]) and np.all(np.abs(back[:5] - weights[:5]) <= 0.5 / 65534 + 1e-9)


# ---- what the page carries -----------------------------------------------------------------
def test_the_page_carries_the_datasets_positions_and_the_predictions_attention(files, tmp_path):
    viewer = write_viewer(files["data"], tmp_path / "v.html", predictions=files["ours"])
    spec, arrays = page_content((tmp_path / "v.html").read_text())
    data, pred = read_split(files["data"], "test"), load_predictions(files["ours"])
    assert viewer.shown == spec["shown"] == data.n == 6 and spec["available"] == 6
    assert np.array_equal(arrays["xy"], data.states[..., :2])  # float32: bit for bit
    assert np.array_equal(arrays["heading"], data.states[..., 2])
    assert np.array_equal(arrays["valid"], data.valid) and np.array_equal(
        arrays["focal"], data.focal
    )
    assert np.array_equal(arrays["roles"], data.roles)
    assert np.array_equal(arrays["label"], data.attention)
    assert np.array_equal(arrays["interaction"], data.interaction)
    assert np.array_equal(arrays["pred"], pred.pred_mean)
    shown = dequantize_unit(arrays["attention"])
    assert np.nanmax(np.abs(shown - pred.attention)) <= 0.5 / 65534 + 1e-7
    assert np.array_equal(np.isnan(shown), np.isnan(pred.attention))
    # the predictions' first SHOWN_SAMPLES sampled futures (tools/evaluate.py samples 20)
    assert pred.num_samples == 20
    assert np.array_equal(arrays["samples"], pred.samples[:, :SHOWN_SAMPLES])
    assert "influence" not in arrays  # no predictions file holds one yet
    meta = read_meta(files["data"])
    scenario = meta.config["scenario"]
    assert spec["road"] == {k: scenario[k] for k in spec["road"]} and len(spec["road"]) == 5
    assert spec["role_names"] == ["main_green", "main_brown", "distractor"]
    assert spec["role_colors"][:2] == ["#2ca02c", "#8c564b"]
    assert spec["source"] == {
        "data": "hc.h5",
        "split": "test",
        "predictions": "ours.npz",
        "predictor": "ours",
        "run": None,
    }
    assert spec["scenes"]["row"] == list(range(6)) and spec["left_out"] is None


def hand_scene_errors(pred) -> tuple[list, list]:
    """ADE and FDE of the focal agents per scene, by loops over the definition."""
    ade, fde = [], []
    obs, steps = pred.num_observed, pred.true_xy.shape[1]
    for k in range(pred.n):
        errors, finals = [], []
        for i in np.flatnonzero(pred.focal[k]):
            if not pred.valid[k, obs - 1, i]:
                continue
            for t in range(obs, steps):
                if pred.valid[k, t, i]:
                    delta = pred.pred_mean[k, t - obs, i].astype(float) - pred.true_xy[k, t, i]
                    errors.append(np.hypot(*delta))
                    if t == steps - 1:
                        finals.append(errors[-1])
        ade.append(np.mean(errors) if errors else None)
        fde.append(np.mean(finals) if finals else None)
    return ade, fde


def test_per_scene_scores_are_the_metrics_of_each_scene_alone(files, tmp_path):
    spec, _ = page_content(make_viewer(files["data"], predictions=files["ours"]).text)
    pred = load_predictions(files["ours"])
    ade, fde = hand_scene_errors(pred)
    assert np.allclose(spec["scenes"]["ade"], ade, rtol=1e-6)
    assert np.allclose(spec["scenes"]["fde"], fde, rtol=1e-6)
    for k in range(pred.n):  # the evaluation's own numbers for a file of that one scene
        alone = score(pred.select([k]))
        assert spec["scenes"]["ade"][k] == pytest.approx(alone["main_agents"]["overall"]["ade"])
        accuracy = alone["attention_accuracy"]["overall"]["accuracy"]
        assert spec["scenes"]["accuracy"][k] == pytest.approx(accuracy)
    # the page's headline is the single prediction's (it shows no samples' scores)
    evaluation = evaluate_run(files["run"], files["data"], "test", sampling=SampleSettings(k=0))
    assert spec["headline"] == evaluation.headline()


def counted_pairs(pred) -> list[int]:
    """Per scene, the (step, agent) pairs the attention accuracy counts, by loops over its
    definition: fed-back steps in the interaction period, agents predicted, present, labelled."""
    obs, steps = pred.num_observed, pred.true_xy.shape[1]
    counts = []
    for k in range(pred.n):
        count = 0
        for t in range(obs, steps - 1):
            for i in range(pred.valid.shape[2]):
                present = pred.valid[k, t, i] and pred.valid[k, obs - 1, i]
                count += bool(
                    pred.interaction[k, t] and present and pred.attention_label[k, t, i] >= 0
                )
        counts.append(count)
    return counts


def test_attention_accuracy_per_scene_is_one_for_the_label_and_zero_for_uniform(files):
    pred = load_predictions(files["ours"])
    label = pred.attention_label[:, :-1]  # (n, T-1, N): the label at the step attention is computed
    exact = np.full(pred.attention.shape, 0.0, dtype=np.float32)
    for k, t, i in zip(*np.nonzero(label >= 0), strict=True):
        exact[k, t, i, label[k, t, i]] = 1.0
    uniform = np.full(pred.attention.shape, 1.0 / 21, dtype=np.float32)
    counts = counted_pairs(pred)
    assert any(counts) and not all(counts)  # scenes with and without counted pairs
    for attention, value in ((exact, 1.0), (uniform, 0.0)):
        accuracy = scene_scores(replace(pred, attention=attention)).accuracy
        assert accuracy == [value if c else None for c in counts]


def test_a_baseline_has_no_attention_accuracy_and_the_page_says_so(files):
    spec, arrays = page_content(make_viewer(files["data"], predictions=files["const_vel"]).text)
    assert spec["scenes"]["accuracy"] == [None] * 6
    assert "attention accuracy n/a" in spec["headline"]
    assert (arrays["attention"] == 65535).all()


def test_no_predictions_shows_the_split_without_scores(files):
    spec, arrays = page_content(make_viewer(files["data"], split="val").text)
    assert spec["source"]["split"] == "val" and spec["scenes"]["ade"] is None
    assert "pred" not in arrays and "attention" not in arrays
    assert np.array_equal(arrays["xy"], read_split(files["data"], "val").states[..., :2])


def test_a_run_alone_is_evaluated_and_described(files):
    spec, arrays = page_content(make_viewer(files["data"], run=files["run"]).text)
    pred = load_predictions(files["ours"])
    assert np.array_equal(arrays["pred"], pred.pred_mean)
    assert spec["source"]["run"] == (
        f"run {files['run']}: ours (seed 0, 1 of 1 epochs, best epoch 1), trained on halting_car_v3"
    )


def test_same_inputs_give_the_same_bytes(files, tmp_path):
    write_viewer(files["data"], tmp_path / "a.html", predictions=files["ours"])
    write_viewer(files["data"], tmp_path / "b.html", predictions=files["ours"])
    assert (tmp_path / "a.html").read_bytes() == (tmp_path / "b.html").read_bytes()


def test_a_title_cannot_close_the_script_element(files):
    title = 'x</script><script>alert("no")</script> & <b>'
    html = make_viewer(files["data"], title=title).text
    spec, _ = page_content(html)
    assert spec["title"] == title and html.count("</script>") == 3


def test_thinning_keeps_the_first_scenes_and_says_so(files):
    viewer = make_viewer(files["data"], predictions=files["ours"], max_scenes=4)
    spec, arrays = page_content(viewer.text)
    assert (viewer.shown, viewer.available) == (4, 6) and arrays["xy"].shape[0] == 4
    assert spec["left_out"] == "shows the first 4 of 6 scenes; 2 left out (max_scenes 4)"
    assert viewer.summary("v.html") == (
        "v.html: 4 of 6 test scenes (the first 4; 2 left out), predictions of ours; "
        f"{len(viewer.text.encode()) / 1e6:.1f} MB"
    )


def test_too_much_data_is_refused_with_the_number_that_fits(files):
    whole = make_viewer(files["data"], predictions=files["ours"])
    _, arrays = page_content(whole.text)
    per_scene = sum(a.nbytes for a in arrays.values()) / 6
    limit = int(per_scene * 3.5)
    with pytest.raises(ViewerError, match=r"6 scenes of 22 agent slots .*\(at most 3 fit\)"):
        make_viewer(files["data"], predictions=files["ours"], limit=limit)
    assert (
        make_viewer(files["data"], predictions=files["ours"], max_scenes=3, limit=limit).shown == 3
    )


# ---- predictions of another dataset --------------------------------------------------------
def test_predictions_of_another_scenario_are_refused(files, tmp_path):
    config = GenerateConfig.for_scenario("double_merge_v1", num_major=2, num_minor=1, num_test=1)
    other = generate_dataset(config, tmp_path / "dm.h5", progress=False).path
    with pytest.raises(ViewerError, match="scenario halting_car_v3, the dataset's is double_merge"):
        make_viewer(other, predictions=files["ours"])


def test_predictions_of_another_split_or_other_scenes_are_refused(files, tmp_path):
    with pytest.raises(ViewerError, match="it holds the test split, not val"):
        make_viewer(files["data"], predictions=files["ours"], split="val")
    config = GenerateConfig.for_scenario(
        "halting_car_v3", num_major=4, num_minor=1, num_test=3, seed=1
    )
    reseeded = generate_dataset(config, tmp_path / "hc1.h5", progress=False).path
    with pytest.raises(ViewerError, match=r"its scene 0 \(split row 0\) has other positions"):
        make_viewer(reseeded, predictions=files["ours"])


def test_predictions_of_another_shape_are_refused(files, tmp_path):
    pred = load_predictions(files["ours"])
    fewer = replace(
        pred,
        pred_mean=pred.pred_mean[:, :, :21],
        true_xy=pred.true_xy[:, :, :21],
        valid=pred.valid[:, :, :21],
        focal=pred.focal[:, :21],
        roles=pred.roles[:, :21],
        attention=pred.attention[:, :, :21, :21],
        attention_label=np.clip(pred.attention_label[:, :, :21], -1, 20),
        samples=pred.samples[..., :21, :],
    )
    fewer.save(tmp_path / "fewer.npz")
    with pytest.raises(ViewerError, match=r"are \(60, 21, 12, 0.3\), the dataset's \(60, 22, 12"):
        make_viewer(files["data"], predictions=tmp_path / "fewer.npz")


def test_a_run_of_another_variant_than_the_predictions_is_refused(files):
    with pytest.raises(ViewerError, match="holds predictions of const_vel, but run .* of ours"):
        make_viewer(files["data"], predictions=files["const_vel"], run=files["run"])


# ---- real data: no road ----------------------------------------------------------------------
def test_data_without_a_road_gets_none(tmp_path):
    meta = make_meta()
    sets = {s: make_trajectory_set(2, seed=k) for k, s in enumerate(("train", "val", "test"))}
    write_dataset(tmp_path / "plain.h5", meta, sets)
    spec, arrays = page_content(make_viewer(tmp_path / "plain.h5").text)
    assert spec["road"] is None and np.array_equal(arrays["xy"], sets["test"].states[..., :2])


# ---- the tool --------------------------------------------------------------------------------
def test_the_tool_writes_the_page_and_refuses_to_replace_it(files, tmp_path):
    out = tmp_path / "deep" / "view.html"
    args = [str(files["data"]), "--predictions", str(files["ours"]), "--out", str(out)]
    done = run_tool("view.py", *args)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith(f"{out}: 6 of 6 test scenes, predictions of ours; ")
    assert page_content(out.read_text())[0]["shown"] == 6
    again = run_tool("view.py", *args)
    assert again.returncode == 2 and again.stderr.count("\n") == 1
    assert "already exists; pass --overwrite" in again.stderr
    assert run_tool("view.py", *args, "--overwrite", "--max-scenes", "2").returncode == 0
    thinned = run_tool("view.py", *args[:-1], str(tmp_path / "t.html"), "--max-scenes", "2")
    assert "(the first 2; 4 left out)" in thinned.stdout


@pytest.mark.parametrize(
    "case",
    [
        "missing data",
        "missing predictions",
        "other split",
        "other dataset",
        "not html",
        "zero scenes",
        "not npz",
    ],
)
def test_the_tool_answers_bad_input_with_one_line_and_status_2(files, tmp_path, case):
    data, pred, out = str(files["data"]), str(files["ours"]), str(tmp_path / "v.html")
    (tmp_path / "bad.npz").write_text("not an archive")
    other = tmp_path / "other.h5"  # a dataset of another scenario than the predictions'
    write_dataset(other, make_meta(), {s: make_trajectory_set(2, seed=1) for s in ("test",)})
    argv, message = {
        "missing data": ([str(tmp_path / "no.h5"), "--out", out], "does not exist"),
        "missing predictions": (
            [data, "--predictions", str(tmp_path / "no.npz"), "--out", out],
            "predictions file",
        ),
        "other split": ([data, "--predictions", pred, "--split", "train", "--out", out], "train"),
        "other dataset": (
            [str(other), "--predictions", pred, "--out", out],
            f"{pred} does not belong to {other}: scenario halting_car_v3, the dataset's is "
            "unit_test",
        ),
        "not html": ([data, "--out", str(tmp_path / "v.png")], "must end in .html"),
        "zero scenes": ([data, "--max-scenes", "0", "--out", out], "at least 1"),
        "not npz": ([data, "--predictions", str(tmp_path / "bad.npz"), "--out", out], "npz"),
    }[case]
    done = run_tool("view.py", *argv, "--no-progress")
    assert done.returncode == 2, done.stderr
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("error: ")
    assert message in done.stderr and done.stdout == "" and not Path(out).exists()


def test_the_tool_refuses_a_page_too_large_and_thins_it_on_request(tmp_path):
    """128 scenes of 120 agents, 20 steps: per scene 547 200 bytes of uint16 attention (19 x
    120 x 120) and 47 780 of the rest (positions 19 200, heading 9 600, predictions 11 520,
    labels 4 800, valid 2 400, roles, focal, interaction), 72.6 MiB in all: refused with the
    option that thins it, 112 scenes fit in 64 MiB; with it, written, the left-out named."""
    meta = make_meta(num_observed=8, num_predicted=12)
    test = make_trajectory_set(128, num_steps=20, num_agents=120, seed=3)
    sets = {"train": make_trajectory_set(1, 20, 120), "val": make_trajectory_set(1, 20, 120)}
    write_dataset(tmp_path / "big.h5", meta, {**sets, "test": test})
    pred = evaluate_baseline(
        "const_vel", tmp_path / "big.h5", "test", sampling=SampleSettings(k=0)
    ).predictions  # no samples: the sizes above
    pred.save(tmp_path / "big.npz")
    argv = [str(tmp_path / "big.h5"), "--predictions", str(tmp_path / "big.npz")]
    done = run_tool("view.py", *argv, "--out", str(tmp_path / "v.html"), "--no-progress")
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert "128 scenes of 120 agent slots make about 72.6 MB of arrays" in done.stderr
    assert "keep the first scenes with --max-scenes (at most 112 fit)" in done.stderr
    fit = 112
    argv += ["--out", str(tmp_path / "v.html"), "--max-scenes", str(fit)]
    done = run_tool("view.py", *argv)
    assert done.returncode == 0, done.stderr
    assert f"(the first {fit}; {128 - fit} left out)" in done.stdout


# ---- a junction: the layout's lanes as polygons ---------------------------------------------
def test_a_junction_dataset_carries_its_lanes_as_polygons(tmp_path):
    """Left turn v0: 4 arms of 200 m beyond a box of half width 3.5 + 4 m, lanes 3.5 m wide,
    traffic on the right. The south approach `in_south` runs north along x = 1.75 from
    y = -207.5 to the box edge at y = -7.5: its outline is x = 0 (left edge) and x = 3.5."""
    config = GenerateConfig.for_scenario(
        "left_turn_v0", num_major=1, num_minor=1, num_test=1, seed=0
    )
    data = generate_dataset(config, tmp_path / "lt.h5", progress=False).path
    spec, arrays = page_content(make_viewer(data).text)
    road = spec["road"]
    assert set(road) == {"car_length_m", "car_width_m", "lanes"}
    assert (road["car_length_m"], road["car_width_m"]) == (4.5, 1.8)
    assert len(road["lanes"]) == 4 * 2 + 4 * 3  # in and out per arm, 3 turns per approach
    assert [0.0, -207.5, 0.0, -7.5, 3.5, -7.5, 3.5, -207.5] in road["lanes"]
    # every car's position at every step lies inside the union of the polygons' boxes
    points = np.concatenate([np.reshape(flat, (-1, 2)) for flat in road["lanes"]])
    xy = arrays["xy"][arrays["valid"].astype(bool)]
    assert (xy.min(axis=0) >= points.min(axis=0) - 1e-3).all()
    assert (xy.max(axis=0) <= points.max(axis=0) + 1e-3).all()


def test_a_junction_road_is_rebuilt_from_the_stored_configuration():
    """Arms of 120 m instead of 200: the lanes' square-cut far ends lie 120 + 7.5 m from the
    centre, so the outline spans [-127.5, 127.5] both ways."""
    from pipeline.viewer.roads import road_of
    from scenarios import version

    stored = version("left_turn_v0").config(arm_length_m=120.0).to_dict()
    meta = replace(make_meta(), scenario="left_turn_v0", config={"scenario": stored})
    points = np.concatenate([np.reshape(flat, (-1, 2)) for flat in road_of(meta)["lanes"]])
    np.testing.assert_allclose(points.min(axis=0), [-127.5, -127.5])
    np.testing.assert_allclose(points.max(axis=0), [127.5, 127.5])
    straight = replace(make_meta(), scenario="double_merge_v0", config={"scenario": {}})
    assert road_of(straight) is None  # nothing recorded: no road
