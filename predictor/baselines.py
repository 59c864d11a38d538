"""Prediction baselines: constant velocity (no training) and ridge regression (fitted in seconds).

Both work on numpy arrays of the dataset format and need no torch. They are the bar every learned
variant must clear on every setting: a model that loses to them has a bug, not a result.

Ridge regression (`RidgeBaseline`) predicts each agent's future *offset from constant velocity* in
the agent's own frame (origin: its last observed position; x axis: its last observed heading),
from agent-centric features of its observed history:

- own motion: velocities [m/s] and accelerations [m/s^2] over the last `history_steps` steps;
- optionally one or more other agents (`neighbours`): their position relative to the agent at the
  last observed step and their velocities over the same steps, in the agent's frame, plus a flag
  saying the neighbour is present. `"nearest"` takes the `num_neighbours` closest agents at the
  last observed step; `"labelled"` takes the agents named by the ground-truth attention label (an
  oracle: the label is read from the whole scene, future included): the most attended one, then,
  where attention moves from car to car during a scene (a turning car reading one oncoming car
  after another), the others in the order it first attends to them, as many slots as the
  training data's agents attend to at most (`attended_agents`; one where labels never move);
  `"random"` takes as many other agents drawn at random (seeded), the control for
  `"labelled"` (with `random_role`, only agents of that role: a random *distractor*, where
  several cars matter and a random other car may be one correlated with a causal one, such as
  the next car of a stream of oncoming cars); `"shuffled"` takes the labelled
  agent's features of another scene (a seeded derangement of the scenes), a null control: the
  same features, with the same distribution, that carry nothing about this scene, so what they
  change is the cost of fitting features that carry nothing.

The *interaction gain* of a dataset is how much the labelled neighbour improves on the agent's own
history (`ridge` vs `ridge_labelled`, against `ridge_random`): a scenario whose labels matter
shows a clear gain with the labelled car and none with a random one.

Features are standardised with statistics of the training samples; the regularisation strength
is chosen by grouped k-fold cross-validation (folds never split a scene) with scikit-learn. With
`neighbour_scales` the neighbours' features get a penalty of their own, chosen by the same
cross-validation (banded ridge, Nunez-Elizalde et al., NeuroImage 2019): a block of features
that carries nothing can then be shrunk away without shrinking the own history with it. One
model is fitted per agent role (roles differ in behaviour: the synthetic main cars change lanes, the
distractors do not). Agents whose history is incomplete, and roles with fewer than two training
scenes, are predicted by constant velocity. The agent's heading is taken from the data where it
has one (`ridge_states` puts it in channel 2), else from its last observed displacement
(`displacement_heading`): pedestrian data, for one, records positions only.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from predictor.label_slots import attended_agents, attended_count, scene_labels
from predictor.registry import BASELINES, RIDGE_BASELINES  # noqa: F401 (re-exported)
from predictor.ridge_cv import fit_ridge_cv

if TYPE_CHECKING:  # annotations only: the baselines run on plain numpy arrays
    from trajectory_data.format import DatasetMeta, TrajectorySet

# the baselines' names and each ridge baseline's RidgeConfig fields: predictor.registry
NEIGHBOUR_MODES = ("none", "nearest", "labelled", "random", "shuffled")
# one regression per agent role; or, for the agents that carry an attention label, one per
# relation to the labelled agent (RELATION_AHEAD / RELATION_BEHIND), whatever their role; or one
# per role and scene case (an oracle gate: the case is read from the data, as the label is)
GROUPINGS = ("role", "relation", "case")
# RidgeConfig.neighbour_scales of a banded fit: factors on the neighbours' standardised
# features (a penalty alpha / scale^2 on them), 0 dropping them, 1 the shared penalty
BANDED_SCALES = (0.0, 0.1, 0.3, 1.0, 3.0)
CASE_STRIDE = 256  # group key of "case": case * CASE_STRIDE + role (roles are int8, < 128)
RELATION_AHEAD, RELATION_BEHIND = -1, -2  # group keys of `relation_groups` (roles are >= 0)


def constant_velocity(positions: np.ndarray, valid: np.ndarray, num_observed: int) -> np.ndarray:
    """Extrapolate each agent with its last observed per-step displacement.

    positions (n, T, N, 2) [m], valid (n, T, N). The velocity is p[T_obs-1] - p[T_obs-2] per step
    when the agent is present at both steps, else zero (the agent stands still). Returns the
    predicted positions of steps T_obs .. T-1, (n, T_pred, N, 2) float32.
    """
    num_steps = positions.shape[1]
    if not 1 <= num_observed < num_steps:
        raise ValueError(f"num_observed must be in [1, {num_steps - 1}], got {num_observed}")
    last = positions[:, num_observed - 1].astype(np.float64)  # (n, N, 2)
    if num_observed >= 2:
        both = valid[:, num_observed - 1] & valid[:, num_observed - 2]  # (n, N)
        step = last - positions[:, num_observed - 2]  # (n, N, 2)
        step = np.where(both[..., None], step, 0.0)  # (n, N, 2)
    else:
        step = np.zeros_like(last)
    ahead = np.arange(1, num_steps - num_observed + 1, dtype=np.float64)  # (T_pred,)
    pred = last[:, None] + ahead[None, :, None, None] * step[:, None]  # (n, T_pred, N, 2)
    return pred.astype(np.float32)


# [m] smallest standard deviation of the ridge baseline's residual Gaussian: where the training
# residuals have no spread at all (a perfectly linear scenario), an isotropic one this wide
RESIDUAL_MIN_STD_M = 1e-3


def zero_mean_gaussian(residuals: np.ndarray, min_std: float = RESIDUAL_MIN_STD_M) -> np.ndarray:
    """Lower Cholesky factor (D, D) of the zero-mean Gaussian fitted to residuals (m, D): their
    second moment R^T R / m (the maximum-likelihood covariance about zero), shrunk towards
    (trace / D) I by the Ledoit-Wolf amount (scikit-learn) where it is not positive definite
    (m <= D or collinear residuals); min_std^2 I where the residuals have no spread at all."""
    from sklearn.covariance import ledoit_wolf_shrinkage

    residuals = np.asarray(residuals, np.float64)
    count, dim = residuals.shape
    second = residuals.T @ residuals / max(count, 1)
    scale = float(np.trace(second)) / dim
    if scale <= min_std**2:
        return np.eye(dim) * min_std
    values = np.linalg.eigvalsh(second)
    if count <= dim or values.min() <= 1e-9 * scale:
        shrink = ledoit_wolf_shrinkage(residuals, assume_centered=True) if count > 1 else 1.0
        second = (1.0 - shrink) * second + shrink * scale * np.eye(dim)
    try:
        return np.linalg.cholesky(second)
    except np.linalg.LinAlgError:  # shrinkage too small to lift a zero eigenvalue
        return np.linalg.cholesky(second + min_std**2 * np.eye(dim))


@dataclass(frozen=True)
class RidgeConfig:
    """Settings of the ridge baseline (defaults: own history only, 12 steps, 5 folds)."""

    # observed steps whose velocities enter the features, at most num_observed - 1; 12 (2.4 s at
    # the scenarios' 0.2 s): on Double Merge (ratio 0.3) main-car test ADE 0.46 m with 8, 0.25 m
    # with 12
    history_steps: int = 12
    neighbours: str = "none"  # one of NEIGHBOUR_MODES (see the module docstring)
    num_neighbours: int = 1  # how many agents "nearest" takes
    alphas: tuple[float, ...] = tuple(float(a) for a in np.logspace(-3, 4, 15))  # CV grid
    folds: int = 5  # grouped cross-validation folds (fewer if there are fewer training scenes)
    seed: int = 0  # of the "random" neighbour draw and the "shuffled" derangement
    # one of GROUPINGS: "role" fits one regression per role; "relation" fits the labelled
    # agents' regressions per relation to their labelled agent instead (`relation_groups`). On
    # Double Merge a colour is the rear car in one case and the front car in the other, and
    # one map per colour cannot read the other car both ways: v1 ratio 0.3, labelled car,
    # main-car test ADE 1.369 m per role, 0.513 m per relation (docs/scenarios.md). "case"
    # fits one regression per role and case: what knowing the case is worth to a linear map
    # (Halting Car v1, whose follower reads the leader differently when it stops and when it
    # goes: docs/PREDICTOR.md)
    groups: str = "role"
    # factors on the neighbours' standardised features, chosen by cross-validation together with
    # alpha: (1.0,) shares one penalty between own and neighbour features; BANDED_SCALES gives
    # the neighbours a penalty of their own (0 drops them), so that on few scenes a neighbour
    # that carries nothing costs no accuracy (docs/scenarios.md: at 52 training scenes a random
    # car's features cost a few per cent with the shared penalty)
    neighbour_scales: tuple[float, ...] = (1.0,)
    # "random" draws only agents of this role index (None: any other agent)
    random_role: int | None = None

    def __post_init__(self) -> None:
        if not self.neighbour_scales or min(self.neighbour_scales) < 0:
            raise ValueError("neighbour_scales must be a non-empty list of numbers >= 0")
        if self.history_steps < 2:
            raise ValueError(f"history_steps must be at least 2, got {self.history_steps}")
        if self.neighbours not in NEIGHBOUR_MODES:
            raise ValueError(
                f"neighbours must be one of {', '.join(NEIGHBOUR_MODES)}, got {self.neighbours!r}"
            )
        if self.num_neighbours < 1:
            raise ValueError(f"num_neighbours must be at least 1, got {self.num_neighbours}")
        if not self.alphas or min(self.alphas) <= 0:
            raise ValueError("alphas must be a non-empty list of positive numbers")
        if self.folds < 2:
            raise ValueError(f"folds must be at least 2, got {self.folds}")
        if self.groups not in GROUPINGS:
            raise ValueError(f"groups must be one of {', '.join(GROUPINGS)}, got {self.groups!r}")

    @classmethod
    def named(cls, name: str) -> RidgeConfig:
        """The configuration behind a baseline name of `BASELINES` ("ridge", "ridge_nearest"...)."""
        if name not in RIDGE_BASELINES:
            raise ValueError(f"not a ridge baseline: {name!r}")
        return cls(**RIDGE_BASELINES[name])


@dataclass
class AgentFrames:
    """Each agent's frame at the last observed step: origin (n, N, 2), rotation (n, N, 2, 2)."""

    origin: np.ndarray
    rotation: np.ndarray  # world -> agent frame: rows (cos, sin), (-sin, cos) of the heading

    def to_local(self, points: np.ndarray, shift: bool = True) -> np.ndarray:
        """(n, N, ..., 2) world points (or vectors, shift=False) -> agent frame."""
        extra = points.ndim - 3
        origin = self.origin.reshape(self.origin.shape[:2] + (1,) * extra + (2,))
        rotation = self.rotation.reshape(self.rotation.shape[:2] + (1,) * extra + (2, 2))
        vectors = points - origin if shift else points
        return np.einsum("...ij,...j->...i", rotation, vectors)

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """(n, N, ..., 2) agent-frame points -> world."""
        extra = points.ndim - 3
        origin = self.origin.reshape(self.origin.shape[:2] + (1,) * extra + (2,))
        rotation = self.rotation.reshape(self.rotation.shape[:2] + (1,) * extra + (2, 2))
        return np.einsum("...ji,...j->...i", rotation, points) + origin


def ridge_states(states: np.ndarray, state_names: tuple[str, ...]) -> np.ndarray:
    """(n, T, N, C) states named `state_names` -> what RidgeBaseline reads: x, y and, where the
    data has a "heading" channel, the heading (n, T, N, 2 or 3)."""
    channels = [0, 1] + ([state_names.index("heading")] if "heading" in state_names else [])
    return states[..., channels]


def displacement_heading(positions: np.ndarray, t0: int) -> np.ndarray:
    """(n, T, N, 2) positions -> (n, T, N) heading [rad] whose step t0 is the direction of the
    last displacement p[t0] - p[t0-1] (0 where the agent did not move); other steps are 0."""
    step = positions[:, t0] - positions[:, t0 - 1]  # (n, N, 2)
    heading = np.zeros(positions.shape[:3])
    heading[:, t0] = np.arctan2(step[..., 1], step[..., 0])
    return heading


def _frames(positions: np.ndarray, heading: np.ndarray, t0: int) -> AgentFrames:
    cos, sin = np.cos(heading[:, t0]), np.sin(heading[:, t0])  # (n, N)
    rotation = np.stack([np.stack([cos, sin], -1), np.stack([-sin, cos], -1)], -2)  # (n,N,2,2)
    return AgentFrames(positions[:, t0].astype(np.float64), rotation)


@dataclass
class RidgeBaseline:
    """Ridge regression on agent-centric history features, one model per agent role.

    `fit` on a training split, then `predict` any split of the same scenario (same dt and
    number of observed steps).
    """

    config: RidgeConfig = field(default_factory=RidgeConfig)
    dt: float = 0.1  # seconds per step of the data it was fitted on
    num_observed: int = 0
    models: dict = field(default_factory=dict)  # role index -> fitted scikit-learn estimator
    alpha: dict = field(default_factory=dict)  # role index -> chosen regularisation strength
    # role index -> Cholesky factor (T_pred*2, T_pred*2) of its training residuals' Gaussian,
    # in the agent frame, steps x (along, across) flattened (`zero_mean_gaussian`)
    residual_chol: dict = field(default_factory=dict)
    # Cholesky factor (T_pred, T_pred) of constant velocity's errors over the steps, per axis
    # (an isotropic Gaussian), for the agents constant velocity predicts (`sample`)
    fallback_chol: np.ndarray | None = None
    # neighbour slots of "labelled", "random" and "shuffled": the most distinct agents any agent
    # of the training data attends to (set by `fit`)
    label_slots: int = 1
    # per feature, the training mean over the rows where that neighbour slot was present: what an
    # absent neighbour's features read as (its presence flag stays 0), so that a slot that was
    # always filled in training does not extrapolate wildly when empty (set by `fit`)
    absent_fill: np.ndarray | None = None

    def fit(
        self,
        states: np.ndarray,
        valid: np.ndarray,
        attention: np.ndarray,
        roles: np.ndarray,
        num_observed: int,
        dt: float,
        case: np.ndarray | None = None,
    ) -> RidgeBaseline:
        """Fit on n training scenes: states (n, T, N, 2 or more: x, y and optionally the heading,
        see `ridge_states`), valid/attention (n, T, N), roles (n, N), case (n,) (needed by
        groups "case" only).

        Samples are the (scene, agent) pairs present over the whole history window and future.
        """
        self._check(states, num_observed)
        self.dt, self.num_observed = float(dt), int(num_observed)
        self.label_slots = max(1, attended_count(attention).max(initial=0))
        self.absent_fill = None
        features, usable, frames = self.features(states, valid, attention, roles)
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns: no slot filled
            self.absent_fill = np.nan_to_num(np.nanmean(features[usable], axis=0))
        features = self._fill_absent(features)
        target = self._target(states[..., :2], valid, frames)  # (n, N, T_pred * 2)
        roles = self.group_keys(states, attention, roles, case)
        complete = usable & valid[:, num_observed:].all(axis=1)  # (n, N)
        scene = np.broadcast_to(np.arange(len(states))[:, None], complete.shape)
        self.models, self.alpha, self.residual_chol = {}, {}, {}
        for role in np.unique(roles[complete]):
            rows = complete & (roles == role)
            if len(np.unique(scene[rows])) < 2:
                continue  # too few scenes to choose alpha: this role keeps constant velocity
            model, alpha = fit_ridge_cv(
                features[rows],
                target[rows],
                scene[rows],
                self.config.alphas,
                self.config.folds,
                block=(self.own_features, self.config.neighbour_scales),
            )
            self.models[int(role)], self.alpha[int(role)] = model, alpha
            residuals = target[rows] - model.predict(features[rows])  # (m, T_pred * 2)
            self.residual_chol[int(role)] = zero_mean_gaussian(residuals)
        self.fallback_chol = None
        if complete.any():  # constant velocity's errors, each axis of each agent one row
            errors = target[complete].reshape(-1, target.shape[-1] // 2, 2)  # (m, T_pred, 2)
            self.fallback_chol = zero_mean_gaussian(
                errors.transpose(0, 2, 1).reshape(-1, errors.shape[1])
            )
        return self

    def fit_set(self, data: TrajectorySet, meta: DatasetMeta) -> RidgeBaseline:
        """`fit` on the scenes of `data`, a split of a file described by `meta`."""
        states = ridge_states(data.states, meta.state_names)
        return self.fit(
            states, data.valid, data.attention, data.roles, meta.num_observed, meta.dt, data.case
        )

    def predict_set(self, data: TrajectorySet, meta: DatasetMeta) -> np.ndarray:
        """`predict` the scenes of `data`, a split of a file described by `meta`."""
        states = ridge_states(data.states, meta.state_names)
        return self.predict(states, data.valid, data.attention, data.roles, data.case)

    def predict(
        self,
        states: np.ndarray,
        valid: np.ndarray,
        attention: np.ndarray,
        roles: np.ndarray,
        case: np.ndarray | None = None,
    ) -> np.ndarray:
        """Predicted positions of steps T_obs .. T-1, (n, T_pred, N, 2) float32 [m]."""
        if not self.num_observed:
            raise ValueError("the ridge baseline must be fitted before it predicts")
        self._check(states, self.num_observed)
        positions = states[..., :2]
        pred = constant_velocity(positions, valid, self.num_observed).astype(np.float64)
        features, usable, frames = self.features(states, valid, attention, roles)
        features = self._fill_absent(features)
        roles = self.group_keys(states, attention, roles, case)
        local = np.zeros(usable.shape + (pred.shape[1], 2))  # (n, N, T_pred, 2) offsets
        for role, model in self.models.items():
            rows = usable & (roles == role)
            if rows.any():
                local[rows] = model.predict(features[rows]).reshape(-1, pred.shape[1], 2)
        cv_local = frames.to_local(pred.transpose(0, 2, 1, 3))  # (n, N, T_pred, 2)
        world = frames.to_world(cv_local + local).transpose(0, 2, 1, 3)  # (n, T_pred, N, 2)
        use = usable[:, None, :, None]
        return np.where(use, world, pred).astype(np.float32)

    # ---- features and targets ---------------------------------------------------------------
    @property
    def own_features(self) -> int:
        """Number of own-motion features (velocities and accelerations); neighbours' follow."""
        return 2 * self.history + 2 * (self.history - 1)

    @property
    def history(self) -> int:
        """Steps of history used: `config.history_steps`, at most num_observed - 1."""
        return min(self.config.history_steps, self.num_observed - 1)

    def group_keys(
        self,
        states: np.ndarray,
        attention: np.ndarray,
        roles: np.ndarray,
        case: np.ndarray | None,
    ) -> np.ndarray:
        """Each agent's regression (n, N), by `config.groups`."""
        if self.config.groups == "role":
            return roles
        if self.config.groups == "relation":
            return relation_groups(states, attention, roles, self.num_observed)
        if case is None:
            raise ValueError('groups "case" needs the case of every scene')
        return np.asarray(case, np.int64)[:, None] * CASE_STRIDE + roles.astype(np.int64)

    @staticmethod
    def _check(states: np.ndarray, num_observed: int) -> None:
        if not 3 <= num_observed < states.shape[1]:
            raise ValueError(
                "the ridge baseline needs at least 3 observed steps and one predicted step; "
                f"got {num_observed} observed of {states.shape[1]}"
            )

    def features(
        self,
        states: np.ndarray,
        valid: np.ndarray,
        attention: np.ndarray,
        roles: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, AgentFrames]:
        """(n, N, F) features, (n, N) usable mask (whole history present), agent frames;
        `roles` (n, N) is needed by `config.random_role` only."""
        t0, history = self.num_observed - 1, self.history
        window = slice(t0 - history, t0 + 1)  # history + 1 positions -> history velocities
        positions, frames = frames_at(states, t0)
        track = positions[:, window].transpose(0, 2, 1, 3)  # (n, N, H+1, 2) world
        present = valid[:, window].all(axis=1)  # (n, N)
        own = frames.to_local(track)  # (n, N, H+1, 2)
        velocity = np.diff(own, axis=2) / self.dt  # (n, N, H, 2)
        if states.shape[-1] <= 2:
            # the frame's x axis is the last velocity, so its lateral component is zero but for
            # rounding, which standardising would blow up into a unit-variance noise feature
            velocity[:, :, -1, 1] = 0.0
        acceleration = np.diff(velocity, axis=2) / self.dt  # (n, N, H-1, 2)
        n, num_agents = present.shape
        parts = [velocity.reshape(n, num_agents, -1), acceleration.reshape(n, num_agents, -1)]
        for other in self._neighbours(positions[:, t0], present, attention, roles):
            feats = self._neighbour_features(track, present, other, frames)
            if self.config.neighbours == "shuffled":
                feats = feats[scene_derangement(n, self.config.seed)]
            parts.append(feats)
        return np.concatenate(parts, axis=-1), present, frames

    def _neighbours(
        self,
        last: np.ndarray,
        present: np.ndarray,
        attention: np.ndarray,
        roles: np.ndarray | None = None,
    ) -> list[np.ndarray]:
        """Per neighbour slot, (n, N) index of the other agent (-1: none)."""
        mode = self.config.neighbours
        if mode == "none":
            return []
        if mode in ("labelled", "shuffled"):
            return list(attended_agents(attention, self.label_slots))
        num_agents = last.shape[1]
        unusable = ~present[:, None, :] | np.eye(num_agents, dtype=bool)[None]  # (n, N, N)
        if mode == "random" and self.config.random_role is not None:
            if roles is None:
                raise ValueError("random_role needs the agents' roles")
            unusable = unusable | (np.asarray(roles) != self.config.random_role)[:, None, :]
        if mode == "random":  # uniform draws among the usable, without repeats
            draw = np.random.default_rng(self.config.seed).random(unusable.shape)
            score = np.where(unusable, np.inf, draw)
            order = np.argsort(score, axis=-1, kind="stable")  # (n, N, N)
            slots = []
            for k in range(min(self.label_slots, num_agents)):
                index = order[..., k]  # (n, N)
                found = np.take_along_axis(score, index[..., None], -1)[..., 0] < np.inf
                slots.append(np.where(found, index, -1))
            return slots
        distance = np.linalg.norm(last[:, :, None] - last[:, None, :], axis=-1)  # (n, N, N)
        distance = np.where(unusable, np.inf, distance)
        order = np.argsort(distance, axis=-1, kind="stable")  # (n, N, N)
        slots = []
        for k in range(self.config.num_neighbours):
            if k >= num_agents:  # more slots than agents: the rest stay empty
                slots.append(np.full(present.shape, -1))
                continue
            finite = np.take_along_axis(distance, order[..., k : k + 1], -1)[..., 0] < np.inf
            slots.append(np.where(finite, order[..., k], -1))
        return slots

    def _fill_absent(self, features: np.ndarray) -> np.ndarray:
        """`features` with an absent neighbour's values (NaN) read as `absent_fill`."""
        missing = np.isnan(features)
        if not missing.any():
            return features
        fill = np.broadcast_to(self.absent_fill, features.shape)
        return np.where(missing, fill, features)

    def _neighbour_features(
        self, track: np.ndarray, present: np.ndarray, other: np.ndarray, frames: AgentFrames
    ) -> np.ndarray:
        """(n, N, 2H + 3): relative position at T_obs-1, velocities, presence flag; an absent
        neighbour's values are NaN (`_fill_absent` reads them as the training mean) and its
        presence flag 0."""
        n, num_agents = other.shape
        index = np.clip(other, 0, num_agents - 1)
        scenes = np.arange(n)[:, None]
        theirs = track[scenes, index]  # (n, N, H+1, 2) world
        here = (other >= 0) & present[scenes, index]  # (n, N)
        local = frames.to_local(theirs)  # in the attending agent's frame
        velocity = np.diff(local, axis=2) / self.dt  # (n, N, H, 2)
        feats = np.concatenate(
            [local[:, :, -1], velocity.reshape(n, num_agents, -1), np.ones((n, num_agents, 1))],
            axis=-1,
        )
        feats = np.where(here[..., None], feats, np.nan)
        feats[..., -1] = here
        return feats

    def _target(self, positions: np.ndarray, valid: np.ndarray, frames: AgentFrames) -> np.ndarray:
        """(n, N, T_pred * 2): the future offset from constant velocity, in the agent's frame."""
        future = positions[:, self.num_observed :].astype(np.float64)  # (n, T_pred, N, 2)
        cv = constant_velocity(positions, valid, self.num_observed).astype(np.float64)
        offset = frames.to_local((future - cv).transpose(0, 2, 1, 3), shift=False)
        return offset.reshape(offset.shape[0], offset.shape[1], -1)


def frames_at(states: np.ndarray, t0: int) -> tuple[np.ndarray, AgentFrames]:
    """Positions (n, T, N, 2) float64 and each agent's frame at step t0: origin its position,
    x axis its heading (the states' third channel where given, else its last displacement)."""
    positions = states[..., :2].astype(np.float64)
    if states.shape[-1] > 2:
        heading = states[..., 2].astype(np.float64)
    else:
        heading = displacement_heading(positions, t0)
    return positions, _frames(positions, heading, t0)


def relation_groups(
    states: np.ndarray, attention: np.ndarray, roles: np.ndarray, num_observed: int
) -> np.ndarray:
    """Regression groups (n, N) of `RidgeConfig.groups` "relation": an agent with a labelled
    agent (`scene_labels`) gets RELATION_AHEAD if that agent is ahead of it at the last
    observed step (positive x in its frame, as the baseline's features), RELATION_BEHIND if
    not; every other agent keeps its role. states as `RidgeBaseline.fit` reads them."""
    t0 = num_observed - 1
    positions, frames = frames_at(states, t0)
    labels = scene_labels(attention)  # (n, N)
    labelled = labels >= 0
    scenes = np.arange(len(labels))[:, None]
    theirs = positions[:, t0][scenes, np.where(labelled, labels, 0)]  # (n, N, 2) world
    ahead = frames.to_local(theirs)[..., 0] > 0  # (n, N)
    relation = np.where(ahead, RELATION_AHEAD, RELATION_BEHIND)
    return np.where(labelled, relation, roles.astype(np.int64))


def scene_derangement(n: int, seed: int) -> np.ndarray:
    """A seeded permutation of n >= 2 scenes that moves every scene: scene i takes the
    features of scene `result[i]` != i (one random cycle through all of them)."""
    if n < 2:
        raise ValueError(f"a derangement needs at least two scenes, got {n}")
    order = np.random.default_rng(seed).permutation(n)
    result = np.empty(n, dtype=np.int64)
    result[order] = np.roll(order, -1)
    return result
