"""Experiment (issue 12): how far below constant velocity can simple own-motion predictors get on
ETH/UCY, and how far with hindsight?

Usage: python benchmarks/experiments/eth_ucy_headroom.py IMPORTED_FOLDER

IMPORTED_FOLDER holds `eth_ucy_<scene>.h5` written by `tools/import_data.py eth-ucy`. Every
predictor here extrapolates a focal pedestrian's last observed position along a velocity read
from its own observed track (no other pedestrian, no map):
- constant velocity: the last observed displacement per step (the field's CVM);
- tuned CV: the mean displacement over the last `n` observed steps times a speed factor `a`,
  with (n, a) chosen on the scene's own **validation** split (the other four scenes' held-out
  files, as the model's `best.pt` is chosen): a fair baseline;
- hindsight CV: the same family with (n, a) chosen on the **test** split itself: not a
  predictor but an upper bound on what this family (window length and speed shrinkage, one
  choice per scene) can gain over constant velocity.
Grid: n in 1..7, a in 0.50..1.20 by 0.01. ADE in metres over focal pedestrians and the 12
predicted steps, per scene and as the mean over scenes (the protocol's headline figure).
numpy only; a few seconds. Not run by `make bench` (the data is the user's download);
docs/REAL_DATA.md has the figures. The last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

SCENES = ("eth", "hotel", "univ", "zara1", "zara2")
WINDOWS = tuple(range(1, 8))  # observed displacements averaged into the velocity
FACTORS = np.round(np.arange(0.50, 1.2001, 0.01), 2)  # speed factors tried


def focal_tracks(path: Path, split: str) -> tuple[np.ndarray, int]:
    """Focal pedestrians' positions, shape (tracks, T, 2), and the number of observed steps."""
    from predictor.format_reader import read_meta, read_split

    meta, data = read_meta(path), read_split(path, split)
    windows, agents = np.nonzero(data.focal & data.valid.all(axis=1))
    return data.states[windows, :, agents, :2].astype(np.float64), meta.num_observed


def family_ade(tracks: np.ndarray, observed: int) -> np.ndarray:
    """ADE [m] of every (window n, factor a) of the family, shape (len(WINDOWS), len(FACTORS))."""
    last = tracks[:, observed - 1]
    future = tracks[:, observed:] - last[:, None]
    horizon = np.arange(1, future.shape[1] + 1)[:, None]
    table = np.empty((len(WINDOWS), len(FACTORS)))
    for row, n in enumerate(WINDOWS):
        velocity = (last - tracks[:, observed - 1 - n]) / n
        for col, factor in enumerate(FACTORS):
            predicted = factor * horizon * velocity[:, None]
            table[row, col] = np.linalg.norm(predicted - future, axis=-1).mean()
    return table


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("imported", type=Path, help="folder of eth_ucy_<scene>.h5 files")
    args = parser.parse_args()
    cv_col = int(np.flatnonzero(FACTORS == 1.0)[0])
    figures: dict[str, dict[str, float]] = {}
    print("scene    CV ADE   tuned on val (n, a) ADE   hindsight (n, a) ADE   [m]")
    for scene in SCENES:
        path = args.imported / f"eth_ucy_{scene}.h5"
        if not path.is_file():
            print(f"error: {path} not found", file=sys.stderr)
            return 2
        test_tracks, observed = focal_tracks(path, "test")
        val_table = family_ade(*focal_tracks(path, "val"))
        test_table = family_ade(test_tracks, observed)
        tuned = np.unravel_index(np.argmin(val_table), val_table.shape)
        best = np.unravel_index(np.argmin(test_table), test_table.shape)
        figures[scene] = {
            "const_vel": float(test_table[0, cv_col]),
            "tuned": float(test_table[tuned]),
            "tuned_n": WINDOWS[tuned[0]],
            "tuned_a": float(FACTORS[tuned[1]]),
            "hindsight": float(test_table[best]),
            "hindsight_n": WINDOWS[best[0]],
            "hindsight_a": float(FACTORS[best[1]]),
        }
        f = figures[scene]
        print(
            f"{scene:<8} {f['const_vel']:.3f}    ({f['tuned_n']}, {f['tuned_a']:.2f}) "
            f"{f['tuned']:.3f}          ({f['hindsight_n']}, {f['hindsight_a']:.2f}) "
            f"{f['hindsight']:.3f}"
        )
    means = {
        key: float(np.mean([figures[s][key] for s in SCENES]))
        for key in ("const_vel", "tuned", "hindsight")
    }
    cv = means["const_vel"]
    print(
        f"mean     {cv:.3f}    tuned {means['tuned']:.3f} ({means['tuned'] / cv - 1:+.1%})"
        f"    hindsight {means['hindsight']:.3f} ({means['hindsight'] / cv - 1:+.1%})"
    )
    print(json.dumps({"scenes": figures, "mean": means}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
