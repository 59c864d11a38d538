"""Counterfactual ground truth: how much each car changes every other car's future.

For a scene (a plan), re-simulate it closed loop with car j removed (every expert reacting as it
does to a removed car: absent, a free road), the scene otherwise identical (same plan, same
initial states of the others), in two ways (`INFLUENCE_KINDS`):

- `episode`: j is removed for the whole episode (before the first step);
- `predicted`: j is present in the observed steps and removed from the first predicted step on
  (step `num_observed`, before the experts read the scene at that step).

    influence[k, i, j] = mean over the predicted steps t of |p_i(t) - p_i^(-j, k)(t)|   [m]

the average displacement (ADE) of car i between the factual rollout and the rollout without j,
over the steps where i is present in both; 0 on the diagonal, NaN where car i is present in no
predicted step of either rollout. `influence_matrices` returns (B, 2, N, N) float32.

Per time window (`windowed_influence`, for scenes where whom a car reacts to changes during the
episode): the predicted steps are cut into W windows of `window_steps` steps; for window w,
starting at step t_w, j is removed from step t_w on (as `predicted` does at `num_observed`) and
influence[w, i, j] is the ADE of car i over the steps of window w only: (B, W, N, N) float32.

Cost, and how it is kept low. One rollout per removed car and kind is 2N + 1 rollouts per scene
(45 for 22 cars), `method="exhaustive"`. The default, `method="grouped"`, screens first with
group removals: for each bit b of the car index, one rollout removes the cars whose bit b is 1
and one those whose bit b is 0 (2 ceil(log2 N) groups per kind). A car i that keeps every state
of every step, bit for bit, while a group holding j (and not i) is gone gets influence[i, j] = 0;
every other pair's column j is then computed by a rollout without j alone (exact). So a scene
costs 1 + 2 (2 ceil(log2 N) + c) rollouts, c the cars with any influence (1-2 here): 25 for the
shipped scenarios, all stepped as one batched world; per time window the same with W windows
in place of the 2 kinds, a car kept unchanged up to the window's end: 1 + W (2 ceil(log2 N) + c)
(0.15 s for 6 scenes of 22 cars with W = 5 on the 2-core development machine). The screen
assumes that removing a group does not leave a car exactly unchanged while removing one of its
members alone would change it (effects of two removed cars cancelling bit for bit); tests hold
grouped equal to exhaustive on every registered version.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from scenarios.base import Scenario, ScenarioPlan
from scenarios.expert import expert_for

INFLUENCE_KINDS: tuple[str, ...] = ("episode", "predicted")  # axis 1 of influence_matrices
EPISODE, PREDICTED = 0, 1
METHODS = ("grouped", "exhaustive")


def counterfactual_states(
    scenario: Scenario,
    plans: Sequence[ScenarioPlan],
    removed: np.ndarray,
    remove_at: np.ndarray | Sequence[int],
) -> tuple[np.ndarray, np.ndarray]:
    """Roll out `plans` (K scenes) with the expert, removing in scene k the cars `removed[k]`
    ((K, N) bool) before the experts read the scene at step `remove_at[k]` (0: the whole
    episode). Returns states (K, T, N, 4) float64 [x, y, heading, speed] and presence (K, T, N)
    bool at the recorded steps. A scene removing nobody is the factual rollout (`rollout`'s
    states, before their rounding to float32)."""
    config = scenario.config
    removed = np.asarray(removed, dtype=bool)
    remove_at = np.asarray(remove_at, dtype=np.int64)
    shape = (len(plans), scenario.num_cars)
    if removed.shape != shape or remove_at.shape != shape[:1]:
        raise ValueError(f"removed must be {shape} and remove_at ({shape[0]},)")
    expert = expert_for(scenario, plans)
    world = expert.make_world()
    states = np.empty((len(plans), config.num_steps, scenario.num_cars, 4))
    present = np.empty((len(plans), config.num_steps, scenario.num_cars), dtype=bool)
    for step in range(config.num_steps):
        now = removed & (remove_at == step)[:, None]
        if now.any():
            world.deactivate(now)
        expert.update(world)
        states[:, step] = world.state
        present[:, step] = world.active
        controls = expert.expert_actions(world)
        for _ in range(config.record_every):  # no collision checks: nothing here reads them
            world.step(controls)
    return states, present


def displacement(
    factual: np.ndarray,
    factual_present: np.ndarray,
    other: np.ndarray,
    other_present: np.ndarray,
    num_observed: int,
    stop: int | None = None,
) -> np.ndarray:
    """ADE [m] per car over the steps [num_observed, stop) (default: to the end, the predicted
    steps) between two rollouts' states (..., T, N, >=2) where the car is present in both; NaN
    where it never is."""
    steps = slice(num_observed, stop)
    both = factual_present[..., steps, :] & other_present[..., steps, :]
    step = factual[..., steps, :, :2] - other[..., steps, :, :2]
    distance = np.where(both, np.hypot(step[..., 0], step[..., 1]), 0.0)
    count = both.sum(axis=-2)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, distance.sum(axis=-2) / count, np.nan)


def screening_groups(num_cars: int) -> np.ndarray:
    """(G, N) bool: for each bit b of the car index, the cars with bit b set and those with it
    clear (G = 2 ceil(log2 N)); every ordered pair (i, j) has a group holding j and not i."""
    bits = max(1, int(np.ceil(np.log2(max(num_cars, 2)))))
    index = np.arange(num_cars)
    ones = np.array([(index >> bit) & 1 == 1 for bit in range(bits)])
    return np.concatenate([ones, ~ones])


def window_starts(num_observed: int, num_steps: int, window_steps: int) -> np.ndarray:
    """(W,) first step of each time window: the predicted steps [num_observed, num_steps) cut
    into W = ceil((num_steps - num_observed) / window_steps) windows of `window_steps` steps
    (the last one shorter where they do not divide)."""
    if not isinstance(window_steps, (int, np.integer)) or isinstance(window_steps, bool):
        raise ValueError(f"window_steps must be an integer, got {window_steps!r}")
    if window_steps < 1:
        raise ValueError(f"window_steps must be at least 1, got {window_steps}")
    return np.arange(num_observed, num_steps, window_steps, dtype=np.int64)


def influence_matrices(
    scenario: Scenario,
    plans: Sequence[ScenarioPlan],
    *,
    method: str = "grouped",
) -> np.ndarray:
    """(B, 2, N, N) float32 influence of car j on car i ([b, k, i, j], k indexing
    INFLUENCE_KINDS) for the scenes of `plans`, stepped as one batched world (see the module
    docstring for `method`, "grouped" or "exhaustive": the same matrices)."""
    config = scenario.config
    predicted = (config.num_observed, config.num_steps)
    return _removal_influence(
        scenario, plans, np.array([0, config.num_observed]), [predicted, predicted], method
    )


def windowed_influence(
    scenario: Scenario,
    plans: Sequence[ScenarioPlan],
    window_steps: int,
    *,
    method: str = "grouped",
) -> np.ndarray:
    """(B, W, N, N) float32 influence of car j on car i per time window ([b, w, i, j]): window w
    holds the predicted steps [t_w, t_w + window_steps) (`window_starts`); j is removed before
    the experts read step t_w (closed loop, as kind `predicted` at num_observed) and the ADE of
    i is taken over the steps of window w only. Step t_w itself is recorded before anyone
    reacts, so window_steps=1 gives zeros (NaN where i is absent); a window as long as the
    predicted span is kind `predicted`. All scenes, windows and removals are one batched world;
    `method` as for `influence_matrices`."""
    config = scenario.config
    starts = window_starts(config.num_observed, config.num_steps, window_steps)
    spans = [(int(s), min(int(s) + window_steps, config.num_steps)) for s in starts]
    return _removal_influence(scenario, plans, starts, spans, method)


def _removal_influence(
    scenario: Scenario,
    plans: Sequence[ScenarioPlan],
    starts: np.ndarray,
    spans: Sequence[tuple[int, int]],
    method: str,
) -> np.ndarray:
    """(B, K, N, N) float32: for each removal setting k, car j removed from step `starts[k]` and
    the ADE of car i over the steps [first, stop) = `spans[k]`; 0 on the diagonal."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    num_scenes, num_cars, num_settings = len(plans), scenario.num_cars, len(starts)
    if num_scenes == 0:
        return np.zeros((0, num_settings, num_cars, num_cars), dtype=np.float32)
    removals = np.eye(num_cars, dtype=bool) if method == "exhaustive" else None
    groups = removals if removals is not None else screening_groups(num_cars)
    num_groups = len(groups)
    # first pass: the factual rollout, then every group (singletons: exhaustive) of each setting
    per_scene_masks = np.concatenate(
        [np.zeros((1, num_cars), bool), np.tile(groups, (num_settings, 1))]
    )
    per_scene_at = np.concatenate([[0], np.repeat(np.asarray(starts, np.int64), num_groups)])
    copies = len(per_scene_masks)
    states, present = counterfactual_states(
        scenario,
        [plan for plan in plans for _ in range(copies)],
        np.tile(per_scene_masks, (num_scenes, 1)),
        np.tile(per_scene_at, num_scenes),
    )
    states = states.reshape(num_scenes, copies, *states.shape[1:])  # (B, 1 + KG, T, N, 4)
    present = present.reshape(num_scenes, copies, *present.shape[1:])  # (B, 1 + KG, T, N)
    factual, factual_present = states[:, :1], present[:, :1]
    runs = states[:, 1:].reshape(num_scenes, num_settings, num_groups, *states.shape[2:])
    runs_present = present[:, 1:].reshape(num_scenes, num_settings, num_groups, *present.shape[2:])
    ade = np.stack(
        [
            displacement(factual, factual_present, runs[:, k], runs_present[:, k], *spans[k])
            for k in range(num_settings)
        ],
        axis=1,
    )  # (B, K, G, N) of car i
    influence = np.full((num_scenes, num_settings, num_cars, num_cars), np.nan)
    if removals is not None:  # one rollout per removed car: ade[b, k, j, i]
        influence[:] = np.swapaxes(ade, 2, 3)
    else:
        same = np.stack(
            [
                (runs[:, k, :, :stop] == factual[:, :, :stop]).all(axis=(2, 4))
                & (runs_present[:, k, :, :stop] == factual_present[:, :, :stop]).all(axis=2)
                for k, (_, stop) in enumerate(spans)
            ],
            axis=1,
        )  # (B, K, G, N): car i kept every state up to the end of the span
        # pair (i, j) is screened out by a group holding j, not i, that left i unchanged
        screened = np.einsum("bkgi,gj->bkij", (same & ~groups[None, None]).astype(np.int64), groups)
        influence[screened > 0] = 0.0
        _fill_suspects(
            scenario, plans, influence, screened > 0, starts, spans, factual, factual_present
        )
    diagonal = np.arange(num_cars)
    influence[:, :, diagonal, diagonal] = 0.0
    return influence.astype(np.float32)


def _fill_suspects(
    scenario: Scenario,
    plans: Sequence[ScenarioPlan],
    influence: np.ndarray,
    screened: np.ndarray,
    starts: np.ndarray,
    spans: Sequence[tuple[int, int]],
    factual: np.ndarray,
    factual_present: np.ndarray,
) -> None:
    """Second pass of the grouped method: one rollout without j alone for every scene, setting
    and car j with an off-diagonal pair the screen left open; fills those columns (in place)."""
    num_cars = scenario.num_cars
    open_pairs = ~screened & ~np.eye(num_cars, dtype=bool)  # (B, K, N, N)
    scene, setting, car = np.nonzero(open_pairs.any(axis=2))  # columns j to roll out
    if len(scene) == 0:
        return
    removed = np.zeros((len(scene), num_cars), dtype=bool)
    removed[np.arange(len(scene)), car] = True
    states, present = counterfactual_states(
        scenario, [plans[b] for b in scene.tolist()], removed, np.asarray(starts)[setting]
    )
    for k in np.unique(setting).tolist():
        rows = setting == k
        influence[scene[rows], k, :, car[rows]] = displacement(
            factual[scene[rows], 0],
            factual_present[scene[rows], 0],
            states[rows],
            present[rows],
            *spans[k],
        )  # (K_k, N) of car i
