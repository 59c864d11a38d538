"""Experiment (issue 10): an own-history map that is zero at constant velocity, against the
affine map of the ridge baseline and the model's highway.

Usage: python benchmarks/experiments/zero_at_cv.py FILE.h5 [FILE.h5 ...] [--scale-floor 0.01]

The ridge baseline (`predictor.baselines.RidgeBaseline`, own history only) and the highway
regress an agent's future offset from constant velocity on its last observed velocities and
accelerations, standardised, with an intercept ("affine"). Fitted on both cases of a scenario,
such a map predicts a nonzero offset for a car whose history is constant: in Halting Car v1
`go` major the leader drives at constant speed in the `go` case, and the map fitted on both
cases puts it 0.8 m off. The "zero_at_cv" form reads the velocities minus the last one and the
accelerations, scaled but not centred, with no intercept, so a constant-velocity history maps
to exactly zero; it cannot learn a base rate (a follower that brakes on average) either.

Per file and main role, both forms are fitted with the baseline's alpha grid and grouped
5-fold cross-validation on the train split; printed: test ADE [m] per case, the
cross-validated mean squared error, and the form with the lower one (the choice a fit per role
could make without seeing the test split).

--scale-floor: the features' standardising scales are at least this (m/s for velocities,
m/s^2 for accelerations, `predictor.baselines`' units); 0 is scikit-learn's StandardScaler.
Positions are stored as float32, so a feature that is constant up to rounding (a leader's
accelerations before it brakes: standard deviation ~1e-4 m/s^2) is otherwise blown up to unit
variance, and the map reads the rounding. Not run by `make bench`; docs/PREDICTOR.md has the
figures. The last line of stdout is one JSON object.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from sklearn.linear_model import Ridge
from sklearn.model_selection import GridSearchCV, GroupKFold
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from threadpoolctl import threadpool_limits

from predictor.baselines import RidgeBaseline, RidgeConfig, ridge_states
from predictor.format_reader import read_dataset

FORMS = ("affine", "zero_at_cv")
MAIN_ROLES = 2  # the synthetic files' first two roles are the main cars


class FlooredScaler(StandardScaler):
    """StandardScaler whose scales are at least `floor` (0: scikit-learn's)."""

    def __init__(self, *, with_mean: bool = True, floor: float = 0.0) -> None:
        super().__init__(with_mean=with_mean)
        self.floor = floor

    def fit(self, x, y=None, sample_weight=None):  # noqa: D102 (scikit-learn's signature)
        super().fit(x, y, sample_weight)
        self.scale_ = np.maximum(self.scale_, self.floor)
        return self


def own_history(baseline: RidgeBaseline, data, meta, form: str):
    """Features (n, N, F), targets (n, N, T_pred * 2) and usable mask (n, N) of one split."""
    states = ridge_states(data.states, meta.state_names)
    features, usable, frames = baseline._features(states, data.valid, data.attention)
    if form == "zero_at_cv":
        n, num_agents = usable.shape
        steps = baseline.history
        velocity = features[..., : 2 * steps].reshape(n, num_agents, steps, 2)
        change = (velocity - velocity[:, :, -1:])[:, :, :-1].reshape(n, num_agents, -1)
        features = np.concatenate([change, features[..., 2 * steps :]], axis=-1)
    target = baseline._target(states[..., :2], data.valid, frames)
    return features, target, usable


def compare(path: Path, floor: float) -> list[dict]:
    """Both forms per main role of one file: test ADE per case, CV error, the CV choice."""
    meta, splits = read_dataset(path)
    train, test = splits["train"], splits["test"]
    baseline = RidgeBaseline(RidgeConfig(), dt=meta.dt, num_observed=meta.num_observed)
    rows = []
    for role in range(MAIN_ROLES):
        row: dict = {"file": path.name, "role": meta.role_names[role]}
        for form in FORMS:
            x, y, usable = own_history(baseline, train, meta, form)
            fit = usable & train.valid[:, meta.num_observed :].all(axis=1) & (train.roles == role)
            scenes = np.broadcast_to(np.arange(len(x))[:, None], fit.shape)[fit]
            centred = form == "affine"
            search = GridSearchCV(
                make_pipeline(
                    FlooredScaler(with_mean=centred, floor=floor), Ridge(fit_intercept=centred)
                ),
                {"ridge__alpha": list(baseline.config.alphas)},
                cv=GroupKFold(n_splits=baseline.config.folds),
                scoring="neg_mean_squared_error",
            )
            with threadpool_limits(limits=1):
                search.fit(x[fit], y[fit], groups=scenes)
            tx, ty, test_usable = own_history(baseline, test, meta, form)
            ade = {}
            for case in np.unique(test.case):
                rows_of = test_usable & (test.roles == role) & (test.case[:, None] == case)
                error = search.best_estimator_.predict(tx[rows_of]) - ty[rows_of]
                ade[meta.case_names[case]] = float(
                    np.linalg.norm(error.reshape(len(error), -1, 2), axis=-1).mean()
                )
            row[form] = {"test_ade": ade, "cv_mse": float(-search.best_score_)}
        row["cv_choice"] = min(FORMS, key=lambda form: row[form]["cv_mse"])
        rows.append(row)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", type=Path, help="trajectory files (HDF5)")
    parser.add_argument(
        "--scale-floor",
        type=float,
        default=0.01,
        help="least standardising scale of a feature (default 0.01; 0: StandardScaler's)",
    )
    args = parser.parse_args()
    rows = [row for path in args.files for row in compare(path, args.scale_floor)]
    for row in rows:
        forms = " | ".join(
            f"{form} "
            + " / ".join(f"{case} {v:.3f}" for case, v in row[form]["test_ade"].items())
            + f" (cv {row[form]['cv_mse']:.3f})"
            for form in FORMS
        )
        print(f"{row['file']}  {row['role']}: {forms} -> {row['cv_choice']}")
    print(json.dumps({"scale_floor": args.scale_floor, "rows": rows}))


if __name__ == "__main__":
    main()
