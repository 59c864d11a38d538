"""Configuration of the smooth-attention predictor: model sizes, training settings, variants.

Every experiment variant of the paper is configuration of one model (`VARIANTS`, from the
registry of predictors, `predictor.registry`, which adds a variant as one entry):

| variant     | attention                         | sequence loss | smoothness (beta2) |
|-------------|-----------------------------------|---------------|--------------------|
| `ours`      | learned                           | yes           | 0.01               |
| `nonsmooth` | learned                           | yes           | 0                  |
| `s_attn`    | learned                           | no            | 0                  |
| `average`   | uniform over present other agents | yes           | 0                  |
| `correct`   | oracle labels (uniform if none)   | yes           | 0                  |

`const_vel` is a baseline without training (`predictor.baselines`), not a variant.
For `average` and `correct` the attention has no parameters, so a smoothness term would be a
constant without gradient; it is fixed to 0.

Each field's comment is its documentation: `predictor.settings` builds the command line's
settings tree from it. Named presets and the composition of a preset with a variant
(`make_configs`): predictor.presets. How configs are stored in checkpoints and run
directories, and read back: predictor.stored_config.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, fields, replace
from typing import Any

from predictor.registry import VARIANTS, Variant  # noqa: F401 (re-exported)

ATTENTION_MODES = ("learned", "uniform", "oracle")
MEAN_PRIORS = ("velocity", "position")
FRAMES = ("scene", "agent")
OFFSET_SCALES = ("step", "deviation")
ROLLOUT_PRIORS = ("previous", "anchored")
ROLES_FROM_DATA = -1  # ModelConfig.num_roles: one role input per role name of the training data
LR_SCHEDULES = ("constant", "cosine")
ROLLOUT_FEEDS = ("sample", "mean")
MEAN_LOSSES = ("nll", "displacement")
NEIGHBOURS = ("all", "radius", "knn")  # ModelConfig.neighbours (predictor.graph)
ATTENDED_FITS = ("mean", "edges", "edge_relations")  # ModelConfig.attended_fit
# ModelConfig switches that need frame "agent" when not at their defaults (the paper's scene frame)
AGENT_FRAME_ONLY = (
    "standardise",
    "edge_velocity",
    "offset_scale",
    "rollout_prior",
)
# ModelConfig switches of the highway (predictor.highway), all off at their defaults: a variant
# without the anchored rollout the highway sits in resets them (predictor.presets.make_configs)
HIGHWAY_SWITCHES = (
    "highway_steps",
    "highway_attended",
    "attended_refit",
    "attended_fit",
    "highway_relation",
    "highway_head_groups",
    "highway_zero_at_cv",
    "highway_min_std",
)


DEVICE = re.compile(r"cpu|cuda(:\d+)?")  # TrainConfig.device
MAX_SEED = 2**63 - 1  # seeds are int64 (torch.manual_seed, the checkpoint's config)


def require_finite(config: object) -> None:
    """ValueError naming the first float field of a config dataclass that is NaN or infinite
    (an infinite learning rate or gain trains NaN weights instead of failing)."""
    for item in fields(config):  # type: ignore[arg-type]
        value = getattr(config, item.name)
        if isinstance(value, float) and not math.isfinite(value):
            raise ValueError(f"{type(config).__name__}.{item.name} must be finite, got {value}")


@dataclass(frozen=True)
class Rule:
    """What values a config field allows: `holds(value, config)`, described by `text` (which may
    name other fields as {config.NAME}); `choices` for a field with a fixed set of values."""

    text: str
    holds: Callable[[Any, Any], bool]
    choices: tuple | None = None

    def describe(self, config: Any = None) -> str:
        """The rule as a user reads it ("one of ('scene', 'agent')", ">= 1", ...)."""
        if config is None:  # the rule alone: "> min_std_m", not "> min_std_m ({...})"
            return re.sub(r" \(\{config\.\w+\}\)", "", self.text)
        return self.text.format(config=config)


def one_of(values: tuple) -> Rule:
    return Rule(f"one of {values}", lambda value, _: value in values, values)


def at_least(low: float) -> Rule:
    return Rule(f">= {low:g}", lambda value, _: value >= low)


def above(low: float) -> Rule:
    return Rule(f"> {low:g}", lambda value, _: value > low)


def check_rules(config: Any, rules: dict[str, Rule]) -> None:
    """ValueError naming the first field of a config dataclass that breaks its rule."""
    kind = type(config).__name__
    for name, rule in rules.items():
        value = getattr(config, name)
        if not rule.holds(value, config):
            shown = repr(value) if rule.choices is not None else value
            raise ValueError(f"{kind}.{name} must be {rule.describe(config)}, got {shown}")


def check_needs(
    config: Any, needs: dict[str, tuple[tuple[str, Callable[[Any], bool]], ...]]
) -> None:
    """ValueError naming the first field that is not at its default while what it needs (a
    description and a test of the config) does not hold."""
    defaults = {item.name: item.default for item in fields(config)}
    for name, requirements in needs.items():
        value = getattr(config, name)
        if value == defaults[name]:
            continue
        for requirement, holds in requirements:
            if not holds(config):
                shown = "" if isinstance(value, bool) else f"={value!r}"
                raise ValueError(f"{type(config).__name__}.{name}{shown} needs {requirement}")


@dataclass(frozen=True)
class ModelConfig:
    """Sizes and input scaling of `SmoothAttentionPredictor`.

    Defaults are chosen so that a full paper-length training run (200 epochs of ~52 scenes with
    22 agents, 462 edges per scene) takes under ten minutes on one CPU thread (see
    benchmarks/bench_training.py); the edge RNN over the N*(N-1) edges of the complete graph
    dominates the cost (a sparse `neighbours` graph makes it ~N*k; benchmarks/bench_graph.py).

    Inputs are 2-D positions in metres. Inside the model they are expressed relative to a
    per-scene origin (the mean position of the agents present at the last observed step) and
    divided by `position_scale_m`; offsets between agents are divided by `interaction_scale_m`
    and per-step displacements by `step_scale_m`. See predictor/model/head.py for the output
    parametrisation (mean prior, std floor, initial std and gain).
    """

    embed_dim: int = 16  # output width of F_embed, F_self and F_interact
    edge_hidden: int = 16  # hidden width of the edge RNN G_interact and self RNN G_self
    node_hidden: int = 32  # hidden width of the node RNN G_pred
    attn_dim: int = 8  # output width of F_attn (space of the attention inner product)
    position_scale_m: float = 100.0  # [m] positions relative to the scene origin are divided by it
    interaction_scale_m: float = 10.0  # [m] offsets s_j - s_i between agents are divided by it
    step_scale_m: float = 2.0  # [m] per-step displacement scale (~ speed * dt = 10 m/s * 0.2 s)
    min_std_m: float = 0.001  # [m] floor of the predicted standard deviations (Cholesky diagonal)
    init_std_m: float = 0.1  # [m] standard deviations predicted at initialisation
    log_std_gain: float = 10.0  # std = min + (init - min) * exp(gain * F_pred output)
    mean_prior: str = "velocity"  # mean = prior + offset; prior p^t + (p^t - p^{t-1}) or p^t
    attention_mode: str = "learned"  # "learned" (F_attn), "uniform" (average) or "oracle"
    chunk_steps: int = 8  # teacher-forced steps per LSTM call; affects speed only, not results
    # --- what the paper leaves open (defaults = the paper's literal model; see PRESETS) ---
    # "agent": every agent's inputs in its own frame (origin and heading = position and last
    # displacement at its last observed step), so a lane change is the same signal wherever and
    # whichever way a car drives; "scene": world axes around the scene origin / position_scale_m
    # (a lane is 0.035 input units there, the lane-change acceleration about 0.005).
    frame: str = "scene"
    # Standardise the agent-frame inputs with means/stds of the training split (stored in the
    # checkpoint as buffers), instead of the car-specific constants *_scale_m. Agent frame only.
    standardise: bool = False
    # Relative velocity v_j - v_i (agent i's frame) on the edges next to the relative position:
    # whether another car closes in is invisible from one relative position. Agent frame only.
    edge_velocity: bool = False
    # "deviation": the mean offset from the prior is in the agent's frame and scaled by the
    # training split's RMS one-step deviation from constant velocity (millimetres), so an output
    # of order 1 is a typical manoeuvre and output noise does not integrate into metres of drift;
    # "step": world axes times step_scale_m (paper). Agent frame only.
    offset_scale: str = "step"
    # The covariance outputs come from a head of their own (F_cov) that reads the node features
    # through a stop-gradient, so the likelihood trains only that head and the shared network
    # learns from the mean's loss alone (gradients are clipped per part, see training).
    # With the paper's joint NLL the gradients of the ~1 mm stds of constant-speed cars are
    # thousands of times those of the manoeuvring cars' means (measured global norm ~4000 vs ~2).
    detach_covariance: bool = False
    # The prior of the rollout's means: "previous" (paper): the one-step prior
    # p^t + (p^t - p^{t-1}) of the fed-back positions, so the output is a per-step acceleration
    # and any bias in it integrates twice (k(k+1)/2 times the bias after k steps); "anchored":
    # p^t + v^{T_obs-1}, the velocity at the last observed step, and the output, from a head of
    # its own (F_roll), is the velocity change since then, scaled by its training-split RMS
    # (`anchor_std`): a car that ends a lane change needs a constant output, not a precisely
    # timed pair of impulses, and a bias drifts linearly. Zero output is constant velocity from
    # the last observation either way. Agent frame only.
    rollout_prior: str = "previous"
    # Each agent's role (the data's `roles`, e.g. main_green / main_brown / distractor) as a
    # one-hot input of its own node (F_embed, F_self), never of the edges, so the attention must
    # still find the relevant car from its motion. The field-standard agent-type input: the
    # ridge baseline fits one regression per role, and pooling the two main roles into one
    # raised its main-car ADE from 0.255 to 0.382 m (Double Merge ratio 0.3, test split).
    # 0: no role input; ROLES_FROM_DATA (-1): as many as the training data's role names, set
    # when training starts (the checkpoint stores the number).
    num_roles: int = 0
    # With num_roles > 0, whether the roles are also inputs of the network (F_embed, F_self);
    # off, they only choose the highway's map per role. The synthetic files' roles are colours
    # (Double Merge: main_green, main_brown), and which colour is ahead is the case, so in the
    # rare case a role input carries the common case's behaviour.
    role_input: bool = True
    # Factor on the learned attention scores <W^T F_attn(o_ii), o_ij> before the softmax. With
    # ~21 other cars the attention starts near-uniform, where a score's gradient is scaled by
    # its weight (~1/21); a gain makes the same parameter step move the scores further (as
    # log_std_gain does for the stds). 1: the paper's scores.
    attention_gain: float = 1.0
    # A linear autoregressive highway (predictor.highway, as LSTNet's): a ridge map from the
    # agent's last `highway_steps` observed velocities (agent frame) to its velocity changes
    # over the rollout, fitted in closed form on the training split and added to the anchored
    # rollout's prior; the network learns what the agent's own history does not explain (alone
    # it never learnt to extrapolate a manoeuvre; docs/PREDICTOR.md). 0: off. Needs
    # rollout_prior "anchored".
    highway_steps: int = 0
    # Predicted steps the highway covers (later steps repeat its last velocity change); the
    # scenarios predict 45 steps.
    highway_horizon: int = 45
    # The highway also reads the attended agents (predictor.highway.neighbour_features): a
    # linear map per role from sum_j theta_ij z_ij to velocity changes, z_ij agent j's relative
    # position and velocities (i's frame, standardised), theta the attention at the last
    # observed step; the attention then gets the gradient of a linear model of the attended
    # car, where ridge's gain from the labelled car lies. Needs highway_steps.
    highway_attended: bool = False
    # The attended map (jointly with the own-history map) refitted in closed form at the start
    # of every epoch instead of learnt by gradient (ridge, cross-fitted as the highway), with
    # the current attention at the last observed step on the training scenes: within an epoch
    # the attention gets the gradient of the best linear read-out of what it attends to (learnt
    # from zero, the map read the uniform average). Needs highway_attended.
    attended_refit: bool = False
    # What attended_refit regresses on: "mean", the attention-weighted mean sum_j theta_ij z_ij
    # of the edge features, which reads whatever attention it was fitted with (under uniform
    # attention it rescaled the leader's 1/21 share, so focusing gained nothing); "edges", each
    # edge (own_i, z_ij) as a row of its own with weight theta_ij (predictor.moment_ridge), a
    # per-neighbour reading, so attending to the car that explains the future lowers the loss;
    # "edge_relations", "edges" with each edge read by the map of its own relation (ahead of or
    # behind the agent), the relations' readings mixed by their share of the attention
    # (predictor.highway.edge_relations). Needs attended_refit ("edge_relations":
    # highway_relation).
    attended_fit: str = "mean"
    # The highway's maps (own and attended) chosen per role *and* per relation to the attended
    # agents, ahead of the agent or behind it (the sign of sum_j theta_ij x_ij in the agent's
    # frame; per edge under attended_fit "edge_relations"), twice the maps: a follower reads
    # its leader differently from how a leader reads its follower, and Double Merge's colours
    # are ahead in one case and behind in the other. Needs attended_refit.
    highway_relation: bool = False
    # Under attended_fit "edge_relations", the edges are also split by the attended agent's
    # role group, each (group, attended group, relation) with maps of its own, as
    # heterogeneous-graph models keep one encoder per edge type: otherwise the map that reads
    # the other main car is diluted by the distractors on the same side. One kind (as off)
    # without roles.
    highway_head_groups: bool = False
    # With attended_refit: each highway map is also fitted in a form that is zero at constant
    # velocity (the own history's velocities minus the last one and its accelerations, no
    # intercept, uncentred; predictor.highway.constant_velocity_transform) and the one with
    # the lower cross-validated error on the training scenes is kept, per map. The affine map
    # fitted on both of Halting Car v1's cases predicts part of the `stop` case's braking for
    # a leader that drives on at constant speed (0.810 m off in the `go` case, where constant
    # velocity is exact; docs/PREDICTOR.md), and Ours inherited it (all-car ADE 0.049 against
    # constant velocity's 0.043 m).
    highway_zero_at_cv: bool = False
    # [m/step] With attended_refit: the least standard deviation by which the highway's refit
    # scales a feature (0: scikit-learn's StandardScaler). Positions are float32, so the
    # velocities of a car at constant speed a few hundred metres out differ by rounding
    # (~8e-6 m/step, Halting Car v1's leader); standardised, that rounding became a
    # unit-variance feature with coefficients up to 1.3e4, and the `go` case's leader was
    # predicted 0.34 m off by the highway alone even in the zero-at-constant-velocity form.
    highway_min_std: float = 0.0
    # A learnt bias per pair of roles (attending, attended) added to the learned attention's
    # scores: "this kind of agent attends to that kind" is one parameter whose gradient sums
    # over every such pair in the data, not a pattern the edge LSTM's states must carry.
    # Ignored without roles (one kind, whose bias the softmax cancels) and by fixed attention.
    role_attention_bias: bool = False
    # Learned attention logits plus -log(number of the attending agent's present neighbours
    # with the attended agent's role): each role among the neighbours starts with one share,
    # so uniform scores put 1/2, not 1/21, on the one other main car among 20 distractors and
    # the refitted maps read it from the first epoch; the scores can still learn to leave it.
    # A fixed prior, not a parameter. Ignored without roles and by fixed attention.
    role_balanced_attention: bool = False
    # --- the neighbour graph (predictor.graph; fixed per window, edges only between agents
    # that are present; the edge RNN and the attention cost O(edges)) ---
    # "all": every other agent (the paper's complete graph, N(N-1) edges); "radius": the agents
    # within neighbour_radius_m; "knn": the neighbour_k nearest. Radius and kNN measure distances
    # at each agent's last observed step (docs/PREDICTOR.md), so a crowd of N agents costs
    # ~N k edges instead of N(N-1). "all" is the default: the paper's model, and on the
    # synthetic car scenarios the attended car is not always among the nearest (below).
    neighbours: str = "all"
    # [m] radius of "radius". 50 m: in the default Double Merge v1 and Halting Car v1 files
    # every labelled (attended) car is within 44.5 m of the attending car at the last observed
    # step (Double Merge at most 21.0 m, Halting Car at most 44.5 m; 495 labelled pairs).
    neighbour_radius_m: float = 50.0
    # neighbours of "knn". 16: in those files the labelled car is at most the 15th nearest
    # (Halting Car v1; at most the 8th in Double Merge v1), so 16 keeps every labelled pair.
    # Pedestrian crowds want far fewer (e.g. 8, or a radius of a few metres).
    neighbour_k: int = 16
    # --- the predictive distribution ---
    # Trajectory modes: M > 1 adds a mixture of M whole futures around the rollout, trained by
    # the mixture's likelihood of each agent's future (predictor.model.modes), so that samples
    # and best-of-K scores can cover distinct outcomes; 1: the paper's one Gaussian per step.
    # Needs rollout_prior "anchored" (its velocity unit).
    modes: int = 1

    def __post_init__(self) -> None:
        require_finite(self)
        check_rules(self, MODEL_RULES)
        check_needs(self, MODEL_NEEDS)


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings (paper: Adam, lr 1e-3, batch 8, 200 epochs, beta1 = beta2 = 0.01).

    Loss terms are means over the items they sum (present agent-steps, or present agent
    transitions for the smoothness term); see `predictor.losses`.
    """

    variant: str = "ours"  # one of VARIANTS
    seed: int = 0  # seeds model initialisation, batch order and rollout samples
    epochs: int = 200  # passes over the training split (>= 1: a run without one has no model)
    batch_size: int = 8  # scenes per optimiser step
    lr: float = 1e-3  # Adam learning rate
    beta1: float = 0.01  # weight of the variance penalties
    beta2: float = 0.01  # weight of the attention total-variation (smoothness) penalties
    tau: float = 1e-3  # [m] standard deviations above tau are penalised by the variance loss
    sequence_loss: bool = True  # add the losses of the sampled, fed-back rollout
    # clip the gradient norm (0 disables; not in the paper), of each of the model's
    # parameter_groups() separately
    grad_clip_norm: float = 10.0
    eval_every: int = 1  # validation ADE every k epochs (and after the last)
    threads: int = 1  # torch.set_num_threads
    # "cosine": lr decays from `lr` to lr * lr_final_ratio over all optimiser steps (per step),
    # so a long run ends with small, low-noise steps; "constant": the paper's fixed lr.
    lr_schedule: str = "constant"
    lr_final_ratio: float = 0.01  # final lr / lr of the cosine schedule
    # What the sequence loss's rollout feeds back: "sample" (paper: reparameterised samples,
    # whose noise the model then learns to undo) or "mean" (the predicted means, as at test
    # time, so the loss scores exactly the prediction that is evaluated).
    rollout_feed: str = "sample"
    # What trains the predicted means: "nll" (paper: the Gaussian NLL trains means and
    # covariances together) or "displacement": the means by their mean displacement error [m]
    # (one-step and rollout; the rollout's is the ADE that is evaluated), the covariances by the
    # NLL around the detached means. Under NLL an agent's mean gradient scales with 1/sigma^2,
    # so the ~1 mm stds of the many constant-speed cars outweigh the manoeuvring cars' errors.
    mean_loss: str = "nll"
    # Leave out of the one-step loss the predictions made without a previous position (a
    # track's first step): their ~2 m miss is unlearnable and swamps the mm-sized errors.
    one_step_needs_previous: bool = False
    # Weight of the main agents' agent-steps in the per-agent loss terms (others: 1; each term
    # stays a weighted mean). The metric and the choice of best.pt score only the main agents,
    # 2 of 22 cars in the synthetic scenarios, whose manoeuvres are the hard part; the
    # distractors' near-constant motion otherwise holds ~90 % of every term. 1: paper.
    main_agent_weight: float = 1.0
    # [m] where the variance penalty exp(sigma) turns into its tangent (linear in sigma, C1), so
    # that it and its gradient stay bounded (`predictor.losses.variance_penalty`): 10 m bounds a
    # std's gradient by exp(10) ~ 2.2e4. 0: the paper's exp, counting stds above 50 m as 50 m (the
    # runs recorded so far, whose stds reach tens of metres: a cap would change them).
    penalty_linear_from_m: float = 0.0
    # Batch scenes of similar agent count together
    # (trajectory_data.torch_dataset.BucketBatchSampler), each padded only to its batch's largest
    # count: on ETH/UCY a split's windows have 1-57 pedestrians (mean 11), and a batch padded to the
    # largest pays for every padded slot. On by default: it draws the same random numbers as plain
    # batching, so where every scene has the same agent count (the synthetic scenarios: 22 cars) the
    # batches are identical.
    bucket_batches: bool = True
    # Train through `torch.compile` of the model's graph step (SmoothAttentionPredictor._run,
    # LSTMs traced): the same mathematics to float rounding, a ~1.5x faster agent-preset step
    # on this project's CPU (benchmarks/README.md), after a one-off compilation of minutes per
    # process (inductor caches it on disk). Needs a C++ compiler; validation and evaluation stay
    # eager. Off: eager, the runs recorded so far.
    compile_graph_step: bool = False
    # Where training runs: "cpu", or "cuda" / "cuda:N" where torch finds a CUDA device (refused in
    # one line where it does not). The same mathematics to float rounding; checkpoints are read
    # onto the CPU, and evaluation runs there. How a run is computed, not what: not in its key.
    device: str = "cpu"

    def __post_init__(self) -> None:
        require_finite(self)
        if self.variant not in VARIANTS:
            raise ValueError(f"unknown variant {self.variant!r}; choose from {sorted(VARIANTS)}")
        check_rules(self, TRAIN_RULES)
        spec = VARIANTS[self.variant]
        if not spec.smooth and self.beta2 != 0:
            raise ValueError(f"variant {self.variant!r} has no smoothness term; beta2 must be 0")
        if self.sequence_loss != spec.sequence_loss:
            raise ValueError(f"variant {self.variant!r} fixes sequence_loss={spec.sequence_loss}")


def _is_agent(config: ModelConfig) -> bool:
    return config.frame == "agent"


# The allowed values of each field (a field without a rule takes any value of its type).
MODEL_RULES: dict[str, Rule] = {
    "frame": one_of(FRAMES),
    "offset_scale": one_of(OFFSET_SCALES),
    "rollout_prior": one_of(ROLLOUT_PRIORS),
    "mean_prior": one_of(MEAN_PRIORS),
    "attention_mode": one_of(ATTENTION_MODES),
    "neighbours": one_of(NEIGHBOURS),
    "attended_fit": one_of(ATTENDED_FITS),
    **{name: at_least(1) for name in ("embed_dim", "edge_hidden", "node_hidden", "attn_dim")},
    "chunk_steps": at_least(1),
    **{
        name: above(0)
        for name in ("position_scale_m", "interaction_scale_m", "step_scale_m", "min_std_m")
    },
    "attention_gain": above(0),
    "log_std_gain": above(0),
    "init_std_m": Rule("> min_std_m ({config.min_std_m})", lambda v, c: v > c.min_std_m),
    "num_roles": at_least(ROLES_FROM_DATA),
    "neighbour_radius_m": above(0),
    "neighbour_k": at_least(1),
    "highway_steps": Rule("0 or >= 2", lambda v, _: v == 0 or v >= 2),
    "highway_horizon": at_least(1),
    "highway_min_std": at_least(0),
    "modes": at_least(1),
}
# What a field needs when it is not at its default: (description, test of the config) pairs.
MODEL_NEEDS: dict[str, tuple[tuple[str, Callable[[Any], bool]], ...]] = {
    **{name: (("frame='agent'", _is_agent),) for name in AGENT_FRAME_ONLY},
    "highway_steps": (("rollout_prior='anchored'", lambda c: c.rollout_prior == "anchored"),),
    "highway_attended": (("highway_steps", lambda c: c.highway_steps > 0),),
    "attended_refit": (("highway_attended", lambda c: c.highway_attended),),
    "attended_fit": (
        ("attended_refit", lambda c: c.attended_refit),
        (
            "highway_relation",
            lambda c: c.highway_relation or c.attended_fit != "edge_relations",
        ),
    ),
    "highway_relation": (("attended_refit", lambda c: c.attended_refit),),
    "highway_zero_at_cv": (("attended_refit", lambda c: c.attended_refit),),
    "highway_min_std": (("attended_refit", lambda c: c.attended_refit),),
    "highway_head_groups": (
        ("attended_fit='edge_relations'", lambda c: c.attended_fit == "edge_relations"),
    ),
    "modes": (("rollout_prior='anchored'", lambda c: c.rollout_prior == "anchored"),),
}
TRAIN_RULES: dict[str, Rule] = {
    "lr_schedule": one_of(LR_SCHEDULES),
    "rollout_feed": one_of(ROLLOUT_FEEDS),
    "mean_loss": one_of(MEAN_LOSSES),
    "seed": Rule(f"in [0, {MAX_SEED}]", lambda v, _: 0 <= v <= MAX_SEED),
    "epochs": at_least(1),
    "batch_size": at_least(1),
    "lr": above(0),
    "beta1": at_least(0),
    "beta2": at_least(0),
    "tau": at_least(0),
    "grad_clip_norm": at_least(0),
    "eval_every": at_least(1),
    "threads": at_least(1),
    "lr_final_ratio": Rule("in [0, 1]", lambda v, _: 0 <= v <= 1),
    "main_agent_weight": above(0),
    "penalty_linear_from_m": at_least(0),
    "device": Rule("'cpu', 'cuda' or 'cuda:N'", lambda v, _: DEVICE.fullmatch(v) is not None),
}


def resolve_roles(config: ModelConfig, role_names: tuple[str, ...] | list[str]) -> ModelConfig:
    """`config` with num_roles = ROLES_FROM_DATA replaced by the number of role names of the
    training data; ValueError if a fixed number does not match them."""
    if config.num_roles == ROLES_FROM_DATA:
        if not role_names:
            raise ValueError("the model reads agent roles; the training data names none")
        return replace(config, num_roles=len(role_names))
    if config.num_roles > 0 and config.num_roles != len(role_names):
        raise ValueError(
            f"the model reads {config.num_roles} agent roles; the data has {len(role_names)}"
        )
    return config


def build_config(cls: type, values: dict[str, Any], complete: bool = False) -> Any:
    """cls(**values); unknown keys are an error, and so are missing ones when `complete`."""
    names = {f.name for f in fields(cls)}
    unknown = sorted(set(values) - names)
    if unknown:
        raise ValueError(f"unknown {cls.__name__} field(s): {', '.join(unknown)}")
    missing = sorted(names - set(values))
    if complete and missing:
        raise ValueError(
            f"{cls.__name__} lacks field(s) {', '.join(missing)} (written by an older version?)"
        )
    return cls(**values)
