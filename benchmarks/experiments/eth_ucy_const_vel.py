"""Experiment (issue 12): the importer's constant-velocity figures on real ETH/UCY data against an
independent computation from the raw text files.

Usage: python benchmarks/experiments/eth_ucy_const_vel.py ETH_UCY_ROOT IMPORTED_FOLDER

ETH_UCY_ROOT is the leave-one-out layout (`<scene>/test/*.txt`, `frame ped x y`);
IMPORTED_FOLDER holds `eth_ucy_<scene>.h5` written by `tools/import_data.py eth-ucy`. For each
scene, this script reads the test files with numpy alone (none of `pipeline.importers`): on each
file's grid of frame ids (step: the most common gap between consecutive distinct ids), every
pedestrian present at 20 consecutive grid frames is scored, the prediction being its last
observed position (frame 8) moved by its last observed displacement per step. ADE is the mean
over (window, pedestrian, predicted step), FDE the mean at the 12th step. The same figures from
`predictor.evaluation.evaluate_baseline("const_vel", ...)` on the imported file must match
(relative 1e-5; the file stores float32 positions). Not run by `make bench` (the data is the
user's download); docs/REAL_DATA.md has the figures. The last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

SCENES = ("eth", "hotel", "univ", "zara1", "zara2")
OBSERVED, PREDICTED = 8, 12


def file_errors(path: Path) -> np.ndarray:
    """Constant-velocity errors [m], shape (pedestrian windows, PREDICTED), of one raw file."""
    rows = np.loadtxt(path, ndmin=2)
    frames = np.unique(rows[:, 0])
    gaps, counts = np.unique(np.diff(frames), return_counts=True)
    step = gaps[np.argmax(counts)]
    where = {(frame, ped): (x, y) for frame, ped, x, y in rows}
    errors = []
    for frame, ped in sorted(where):
        track = [where.get((frame + k * step, ped)) for k in range(OBSERVED + PREDICTED)]
        if any(point is None for point in track):
            continue
        track = np.asarray(track)
        last, velocity = track[OBSERVED - 1], track[OBSERVED - 1] - track[OBSERVED - 2]
        predicted = last + np.arange(1, PREDICTED + 1)[:, None] * velocity
        errors.append(np.linalg.norm(predicted - track[OBSERVED:], axis=1))
    return np.asarray(errors).reshape(-1, PREDICTED)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("root", type=Path, help="ETH/UCY leave-one-out folder")
    parser.add_argument("imported", type=Path, help="folder of eth_ucy_<scene>.h5 files")
    args = parser.parse_args()
    from predictor.evaluation import evaluate_baseline

    figures, agree = {}, True
    print("scene    independent ADE/FDE [m]   evaluate.py ADE/FDE [m]   agent-steps")
    for scene in SCENES:
        errors = np.concatenate(
            [file_errors(p) for p in sorted((args.root / scene / "test").glob("*.txt"))]
        )
        ours = evaluate_baseline("const_vel", args.imported / f"eth_ucy_{scene}.h5", "test")
        scores = ours.scores["main_agents"]["overall"]
        independent = {
            "ade": float(errors.mean()),
            "fde": float(errors[:, -1].mean()),
            "count": errors.size,
        }
        same = (
            independent["count"] == scores["count"]
            and np.isclose(independent["ade"], scores["ade"], rtol=1e-5)
            and np.isclose(independent["fde"], scores["fde"], rtol=1e-5)
        )
        agree &= bool(same)
        figures[scene] = {
            "independent": independent,
            "evaluate": {k: scores[k] for k in ("ade", "fde", "count")},
        }
        print(
            f"{scene:8} {independent['ade']:.4f} / {independent['fde']:.4f}        "
            f"{scores['ade']:.4f} / {scores['fde']:.4f}        {scores['count']}"
            f" ({independent['count']}) {'same' if same else 'DIFFERENT'}"
        )
    mean = {
        k: float(np.mean([figures[s]["independent"][k] for s in SCENES])) for k in ("ade", "fde")
    }
    print(f"mean over the five scenes: ADE {mean['ade']:.4f} m, FDE {mean['fde']:.4f} m")
    print(json.dumps({"scenes": figures, "mean": mean, "agree": agree}))
    return 0 if agree else 1


if __name__ == "__main__":
    sys.exit(main())
