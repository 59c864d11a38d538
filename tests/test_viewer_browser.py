"""The viewer in a real browser (headless Chromium, tests/browser.py), on a 100-scene split of 22
cars: it draws every present car at the pixel the documented view transform puts it (computed
here from the dataset), the slider and the arrow keys move them, clicking a car shows its
attention with the predictions file's values, the scene list sorts worst first, and the page
asks for nothing but its own file (no network). Skipped, with the reason, where Chromium,
chromedriver or selenium is missing. How fast such a page opens is measured by
benchmarks/bench_viewer.py, not here."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from browser import chromium, open_page, pixel, requested, until
from conftest import make_meta, make_trajectory_set
from test_viewer import hand_scene_errors, make_files

from pipeline.viewer import write_viewer
from predictor.plots import role_color
from predictor.predictions import load_predictions
from trajectory_data.format import write_dataset
from trajectory_data.reader import read_meta, read_split

PAD_PX, MIN_EXTENT_M = 24, 10.0  # the view transform's constants (docs/VIEWER.md)


@pytest.fixture(scope="module")
def driver():
    with chromium() as browser:
        yield browser


@pytest.fixture(scope="module")
def hundred(tmp_path_factory) -> dict[str, Path]:
    """A 100-scene Halting Car test split of 22 cars, a tiny run's predictions, its page."""
    folder = tmp_path_factory.mktemp("viewer_browser")
    files = make_files(folder, num_test=50)
    files["page"] = folder / "view.html"
    write_viewer(files["data"], files["page"], predictions=files["ours"])
    return files


def view_transform(xy: np.ndarray, valid: np.ndarray, road: dict | None, width, height):
    """(T, N, 2) positions of one scene -> a function of world points to canvas pixels: the
    box of the scene's present positions (for a road, widened to the road's width), at least
    MIN_EXTENT_M on each side, fitted in the canvas less PAD_PX on every side, y up."""
    points = xy[valid].astype(np.float64)
    (x0, y0), (x1, y1) = points.min(axis=0), points.max(axis=0)
    if road is not None:
        y0, y1 = min(y0, 0.0), max(y1, road["num_lanes"] * road["lane_width_m"])

    def widen(lo, hi):
        return (lo, hi) if hi - lo >= MIN_EXTENT_M else ((lo + hi) / 2 - 5.0, (lo + hi) / 2 + 5.0)

    (x0, x1), (y0, y1) = widen(x0, x1), widen(y0, y1)
    k = min((width - 2 * PAD_PX) / (x1 - x0), (height - 2 * PAD_PX) / (y1 - y0))
    cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
    return lambda p: (width / 2 + (p[..., 0] - cx) * k, height / 2 - (p[..., 1] - cy) * k)


def rgb(color: str) -> tuple[int, int, int]:
    return tuple(int(color[i : i + 2], 16) for i in (1, 3, 5))


def canvas_size(driver) -> tuple[int, int]:
    width, height, backing = driver.execute_script(
        "const c = document.getElementById('scene-canvas');"
        "return [c.clientWidth, c.clientHeight, [c.width, c.height]];"
    )
    assert backing == [width, height]  # device pixel ratio 1: canvas pixels are CSS pixels
    return width, height


def state(driver) -> dict:
    return driver.execute_script("return window.viewer.state()")


def wait_state(driver, key: str, value) -> None:
    """Wait until the viewer's state has `key` == `value` (after a click or a key)."""
    script = "return JSON.stringify(window.viewer.state()[arguments[0]]) === arguments[1]"
    until(driver, script, key, json.dumps(value, separators=(",", ":")))


def set_slider(driver, step: int) -> None:
    """Move the time slider as a user's drag does: its value, then its input event."""
    driver.execute_script(
        "const s = document.getElementById('slider'); s.value = arguments[0];"
        "s.dispatchEvent(new Event('input'));",
        step,
    )


def press(driver, *keys: str) -> None:
    from selenium.webdriver.common.action_chains import ActionChains

    ActionChains(driver).send_keys(*keys).perform()


def cars_at(driver, to_pixel, xy: np.ndarray, present: np.ndarray, colors: list) -> list[bool]:
    """For each present agent, whether the canvas pixel at its centre has its role's colour."""
    cols, rows = to_pixel(xy)
    return [
        pixel(driver, "scene-canvas", cols[i], rows[i]) == rgb(colors[i])
        for i in np.flatnonzero(present)
    ]


def hide_overlays(driver, predictions: bool = True) -> None:
    """Layers that may cross another car's centre off: trails, numbers (keys h, f, p, n)."""
    layers = {"h": "history", "f": "future", "p": "prediction", "n": "numbers"}
    if not predictions:
        del layers["p"]
    press(driver, *layers)
    until(
        driver,
        "return arguments[0].every((n) => !document.getElementById('layer-' + n).checked)",
        list(layers.values()),
    )


def test_each_present_car_is_drawn_at_its_pixel_and_the_slider_moves_them(driver, hundred):
    open_page(driver, hundred["page"])
    data, meta = read_split(hundred["data"], "test"), read_meta(hundred["data"])
    road = {k: meta.config["scenario"][k] for k in ("num_lanes", "lane_width_m")}
    width, height = canvas_size(driver)
    scene = 3
    driver.find_element("css selector", f'#scenes tr[data-index="{scene}"]').click()
    wait_state(driver, "scene", scene)
    hide_overlays(driver)
    xy, valid = data.states[scene, ..., :2], data.valid[scene]
    to_pixel = view_transform(xy, valid, road, width, height)
    colors = [role_color(meta.role_names[r], r) for r in data.roles[scene]]
    step = 20
    set_slider(driver, step)
    assert state(driver)["scene"] == scene and state(driver)["step"] == step
    drawn = cars_at(driver, to_pixel, xy[step], valid[step], colors)
    assert len(drawn) == int(valid[step].sum()) == 22 and all(drawn)
    later = step + 10
    press(driver, *["\ue014"] * 10)  # ArrowRight ten times: one step each
    wait_state(driver, "step", later)
    assert all(cars_at(driver, to_pixel, xy[later], valid[later], colors))
    # where a car was and no car is now (none within 6 m), the canvas shows bare road
    gap = np.linalg.norm(xy[step][:, None] - xy[later][None, valid[later]], axis=-1).min(axis=1)
    left = np.flatnonzero(valid[step] & (gap > 6.0))
    assert len(left) >= 5
    cols, rows = to_pixel(xy[step])
    for i in left:
        assert pixel(driver, "scene-canvas", cols[i], rows[i]) == (70, 70, 74), i


def test_clicking_a_car_shows_its_attention_values_from_the_predictions_file(driver, hundred):
    from selenium.webdriver.common.action_chains import ActionChains

    open_page(driver, hundred["page"])
    pred, meta = load_predictions(hundred["ours"]), read_meta(hundred["data"])
    road = {k: meta.config["scenario"][k] for k in ("num_lanes", "lane_width_m")}
    agent = 0  # the Halting Car follower: labelled to attend to the car ahead
    busy = np.argwhere(pred.interaction[:, :-1] & (pred.attention_label[:, :-1, agent] >= 0))
    scene, step = (int(v) for v in busy[len(busy) // 2])  # (scene, step) inside an interaction
    driver.find_element("css selector", f'#scenes tr[data-index="{scene}"]').click()
    wait_state(driver, "scene", scene)
    set_slider(driver, step)
    width, height = canvas_size(driver)
    to_pixel = view_transform(pred.true_xy[scene], pred.valid[scene], road, width, height)
    col, row = to_pixel(pred.true_xy[scene, step, agent])
    canvas = driver.find_element("id", "scene-canvas")
    ActionChains(driver).move_to_element_with_offset(
        canvas, int(col - width / 2), int(row - height / 2)
    ).click().perform()
    wait_state(driver, "selected", agent)
    label = int(pred.attention_label[scene, step, agent])
    shown_label = driver.find_element("id", "attention-label")
    assert int(shown_label.get_attribute("data-label")) == label
    assert shown_label.text.startswith(f"labelled: attends to agent {label} (")
    rows = driver.find_elements("css selector", "#attention-table tr")
    weight = {r: r.find_element("class name", "weight").text for r in rows}
    shown = {int(r.get_attribute("data-agent")): float(weight[r]) for r in rows}
    others = [j for j in range(22) if j != agent and pred.valid[scene, step, j]]
    assert sorted(shown) == others
    for j, value in shown.items():
        assert abs(value - pred.attention[scene, step, agent, j]) <= 0.0005 + 1e-5, j
    assert list(shown.values()) == sorted(shown.values(), reverse=True)
    marked = driver.find_elements("css selector", "#attention-table tr.labelled")
    assert [int(r.get_attribute("data-agent")) for r in marked] == [label]
    press(driver, "\ue00c")  # Escape clears the choice
    wait_state(driver, "selected", -1)
    assert driver.find_elements("css selector", "#attention-table tr") == []


def test_the_scene_list_sorts_worst_first_then_reverses(driver, hundred):
    open_page(driver, hundred["page"])
    ade, _ = hand_scene_errors(load_predictions(hundred["ours"]))
    assert len(driver.find_elements("css selector", "#scenes tbody tr")) == 100
    header = driver.find_element("css selector", '#scenes th[data-key="ade"]')
    header.click()
    wait_state(driver, "order", sorted(range(100), key=lambda k: (-ade[k], k)))  # worst first
    header.click()
    wait_state(driver, "order", sorted(range(100), key=lambda k: (ade[k], k)))
    driver.find_element("css selector", '#scenes th[data-key="index"]').click()
    wait_state(driver, "order", list(range(100)))
    press(driver, "\ue015", "\ue015")  # ArrowDown twice: the next scenes of the list
    wait_state(driver, "scene", 2)


def test_the_page_asks_for_nothing_but_its_own_file(driver, hundred):
    requested(driver)  # the earlier tests' requests
    open_page(driver, hundred["page"])
    assert requested(driver) == [hundred["page"].resolve().as_uri()]


def test_data_without_a_road_draws_dots_on_a_plain_ground(driver, tmp_path):
    meta = make_meta()
    sets = {s: make_trajectory_set(2, seed=k) for k, s in enumerate(("train", "val", "test"))}
    write_dataset(tmp_path / "plain.h5", meta, sets)
    write_viewer(tmp_path / "plain.h5", tmp_path / "plain.html")
    open_page(driver, tmp_path / "plain.html")
    assert driver.find_elements("id", "layer-prediction") == []  # nothing to switch
    hide_overlays(driver, predictions=False)
    test = sets["test"]
    width, height = canvas_size(driver)
    to_pixel = view_transform(test.states[0, ..., :2], test.valid[0], None, width, height)
    step = 5
    set_slider(driver, step)
    colors = [role_color(meta.role_names[r], r) for r in test.roles[0]]
    drawn = cars_at(driver, to_pixel, test.states[0, step, :, :2], test.valid[0, step], colors)
    assert len(drawn) == int(test.valid[0, step].sum()) and all(drawn)
    assert pixel(driver, "scene-canvas", 3, 3) == (244, 244, 244)  # the plain ground


def test_without_chromium_the_browser_tests_skip_naming_what_is_missing(monkeypatch):
    import browser

    monkeypatch.setattr(browser.shutil, "which", lambda name: None)
    with pytest.raises(pytest.skip.Exception, match="no chromium and chromedriver on PATH"):
        with browser.chromium():
            pass
