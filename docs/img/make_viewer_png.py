"""The viewer screenshot of docs/VIEWER.md and the README (docs/img/viewer.png), by headless
Chromium (tests/browser.py's launcher).

    python docs/img/make_viewer_png.py DATA.h5 PRED.npz [--run RUN] [--out docs/img/viewer.png]

Writes the viewer of the predictions' split, opens it in a 1280 x 900 viewport, sorts the scene
list by ADE (worst first), opens the first scene of the major case in which agent 0 is labelled
during the interaction period after the observed steps, chooses agent 0 at the middle such step
(its attention edges, table and curve), zooms in twice around it and saves the window as a
256-colour PNG. --scene, --step, --agent and --zoom choose otherwise. The published one:
Halting Car v3's default dataset (`tools/generate.py --scenario halting_car_v3`), a run of the
`agent` preset trained for 20 epochs, its test predictions (`tools/evaluate.py
--save-predictions`).
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
from pathlib import Path

import numpy as np
from PIL import Image

REPO = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(REPO), str(REPO / "tests")]
from browser import find_chromium, launch, open_page, until  # noqa: E402

from pipeline.viewer import write_viewer  # noqa: E402
from predictor.predictions import load_predictions  # noqa: E402
from trajectory_data.reader import read_meta  # noqa: E402

VIEWPORT = (1280, 900)
# at `step`, choose `agent` and zoom by `factor` with it in the middle of the canvas
ZOOM = """
const [step, agent, factor] = arguments, v = window.viewer;
v.setStep(step);
v.select(agent);
const r = v.canvas.getBoundingClientRect();
const [x, y] = [v.x(v.scene, step, agent), v.y(v.scene, step, agent)];
const [c, row] = Viewer.toPixel(v.view(r.width, r.height), x, y);
v.zoomAt(factor, c, row);
v.pan = [v.pan[0] + r.width / 2 - c, v.pan[1] + r.height / 2 - row];
v.draw();
"""


def choose(pred, major: int, agent: int) -> tuple[int, int]:
    """(scene, step): the first scene of case `major` where `agent` is labelled in the interaction
    period after the observed steps, and the middle such step."""
    labelled = pred.interaction[:, :, None] & (pred.attention_label >= 0)
    for k in np.flatnonzero(pred.case == major):
        steps = [
            t for t in range(pred.num_observed, pred.true_xy.shape[1] - 1) if labelled[k, t, agent]
        ]
        if steps:
            return int(k), steps[len(steps) // 2]
    raise SystemExit(
        f"no major-case scene where agent {agent} is labelled after the observed steps"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data")
    parser.add_argument("predictions")
    parser.add_argument("--run")
    parser.add_argument("--out", default=str(REPO / "docs" / "img" / "viewer.png"))
    parser.add_argument("--agent", type=int, default=0)
    parser.add_argument("--scene", type=int)
    parser.add_argument("--step", type=int)
    parser.add_argument("--zoom", type=float, default=2.0, help="around the agent (default 2)")
    args = parser.parse_args()
    browser, driver_path, reason = find_chromium()
    if reason:
        raise SystemExit(reason)
    pred = load_predictions(args.predictions)
    major = pred.case_names.index(read_meta(args.data).major_case)
    scene, step = choose(pred, major, args.agent)
    scene = scene if args.scene is None else args.scene
    step = step if args.step is None else args.step
    width, height = VIEWPORT
    with tempfile.TemporaryDirectory() as folder, launch(browser, driver_path, VIEWPORT) as driver:
        metrics = {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False}
        driver.execute_cdp_cmd("Emulation.setDeviceMetricsOverride", metrics)  # the viewport
        page = Path(folder) / "view.html"
        write_viewer(args.data, page, predictions=args.predictions, run=args.run)
        open_page(driver, page)
        driver.find_element("css selector", '#scenes th[data-key="ade"]').click()
        row = driver.find_element("css selector", f'#scenes tr[data-index="{scene}"]')
        driver.execute_script(  # the row in the middle of the list, the page at its top
            "const panel = document.getElementById('scenes-panel');"
            "panel.scrollTop = arguments[0].offsetTop - panel.clientHeight / 2;"
            "window.scrollTo(0, 0);",
            row,
        )
        row.click()
        driver.execute_script(ZOOM, step, args.agent, args.zoom)
        until(driver, "return document.querySelectorAll('#attention-table tr').length > 0")
        shot = Image.open(io.BytesIO(driver.get_screenshot_as_png())).convert("RGB")
    shot.quantize(256, method=Image.Quantize.MEDIANCUT).save(args.out, optimize=True)
    print(f"wrote {args.out}: scene {scene}, step {step}, agent {args.agent}")


if __name__ == "__main__":
    main()
