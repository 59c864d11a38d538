"""The smooth-attention trajectory predictor (Cao et al., ICRA 2022, Sec. "Method"), composed
of parts.

A directed graph with self-loops over the N agents of a scene (the paper's: complete):

- edge (i, j), i != j:  x_ij = F_interact(concat(s_i, s_j)),  o_ij = G_interact(x_ij)  (LSTM)
- self-loop (i, i):     x_ii = F_self(concat(s_i^{t-1}, s_i^t)), o_ii = G_self(x_ii)   (LSTM)
- attention:            theta_ij = softmax over present neighbours j of <F_attn(o_ii), F_attn(o_ij)>
- node:                 o_i = G_pred(F_embed(s_i), sum_j theta_ij o_ij, o_ii)            (LSTM)
- output:               (mu_i, Sigma_i) of the next position = F_pred(o_i)

Each stage is an nn.Module part in a module of this package; the config chooses which parts are
built and of what kind, and each part keeps the settings it reads:

| part        | module            | job                                                         |
|-------------|-------------------|-------------------------------------------------------------|
| `encoder`   | encoders          | F_embed, F_self, F_interact on scene- or agent-frame inputs |
|             |                   | (`frame`), with the agent frame's input statistics          |
| `recurrent` | recurrent         | G_self and G_interact                                       |
| `attention` | attention         | learned, uniform or oracle weights (`attention_mode`)       |
| `role_bias` | attention         | the role-pair bias (`role_attention_bias`), or None         |
| `node`      | recurrent         | G_pred                                                      |
| `head`      | head              | F_pred (F_cov, F_roll): the Gaussian, scene or agent frame  |
| `highway`   | highway_maps      | the linear highway's maps (`highway_steps`), or None; their |
|             | (highway_refit)   | closed-form fits                                            |
| `modes`     | modes             | the trajectory modes around the rollout (`modes` > 1), or   |
|             |                   | None                                                        |

This module runs the passes over them: the inputs of a pass (predictor.model.pass_inputs, with
its neighbour graph), the teacher-forced steps in chunks, and the fed-back rollout.
Checkpoints name the parts' tensors without the part (`f_attn.weight`), as the model did when it
was one module (predictor.model.state_names).

Graph (`ModelConfig.neighbours`, `predictor.graph`): every other agent ("all", the paper's),
those within a radius, or the k nearest, chosen once per window (each edge keeps an LSTM state
across the steps) and only between agents that are present in it. The edges are packed into
one list for the batch, so the edge LSTM and the attention cost O(edges): a softmax over each
agent's edges and a sum of them (an index_add over a radius or k-nearest graph; over a complete
graph each agent's N-1 edges are one contiguous row, reduced as such); an agent without a
present neighbour attends to nothing (sum 0). The attention is returned in the layout (..., N, N-1)
(zero off the graph), which the losses and metrics read.

Time indexing: the step at time t (t = 0 .. T-2) reads the states at t (and t-1 for the
self-loop; at t = 0, or when the agent was absent at t-1, the previous state is the current one)
and predicts the position at t+1. Its attention is theta^t. The state s_i is the 2-D position
(the fed-back rollout only has positions).

Rollout: from step T_obs on the model feeds back its samples (or means); `sample_rollouts`
draws K futures by feeding back samples, the observed steps run once for all of them. With
the anchored prior (`rollout_prior="anchored"`, the agent frame's head) every predicted step's
mean is p^t plus the velocity at the last observed step, plus, with a highway, the velocity
changes that its maps read from the agent's observed history (and the agents it attends to);
the network predicts the rest. With `frame="agent"` the model is equivariant to rotating and
translating a scene (docs/PREDICTOR.md).

Everything is batched over scenes, agents and edges; the only Python loop is over the time steps
of the fed-back rollout. Absent agents have no edges, or (present at other steps of the window)
are masked out of the attention while absent.
"""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import Tensor, nn

from predictor.config import ModelConfig
from predictor.model.attention import Presence, build_attention, build_role_bias
from predictor.model.encoders import build_encoder
from predictor.model.head import build_head
from predictor.model.highway_maps import build_highway
from predictor.model.modes import build_modes
from predictor.model.pass_inputs import PassInputs, prepare_pass
from predictor.model.recurrent import EdgeRecurrence, NodeRecurrence
from predictor.model.state_names import use_checkpoint_names
from predictor.outputs import (
    Gaussian2D,
    ModelOutput,
    RecurrentState,
    Rollout,
    StepOutputs,
)

# the model's parts (nn.Module children), whose tensors checkpoints name without the part
PARTS = ("highway", "role_bias", "encoder", "recurrent", "attention", "node", "head")


class SmoothAttentionPredictor(nn.Module):
    """Graph-RNN trajectory predictor with (learned, uniform or oracle) attention."""

    def __init__(self, config: ModelConfig) -> None:
        super().__init__()
        if config.num_roles < 0:
            raise ValueError("num_roles=-1 (from the data) must be resolved first (resolve_roles)")
        self.config = config
        # The parts are made in the order of the random initialisation's draws, and the
        # parameters come in the order of the parts: the highway (a learnt attended map) and
        # the role-pair bias, zeros without a random draw, first, as before the model was
        # composed of parts, whose checkpointed optimizer states and gradient-clipping sums
        # follow that order.
        self.highway = build_highway(config)  # own-history and attended maps, or None
        self.role_bias = build_role_bias(config)  # or None
        self.encoder = build_encoder(config)  # F_embed, F_self, F_interact
        self.recurrent = EdgeRecurrence(config)  # G_self, G_interact
        self.attention = build_attention(config)  # learned (F_attn), uniform or oracle
        self.node = NodeRecurrence(config)  # G_pred
        self.head = build_head(config)  # starts at the mean prior, stds init_std_m
        # trajectory modes (modes > 1) or None; made last, so the other parts draw as before,
        # and outside PARTS (its tensors are named modes.*)
        self.modes = build_modes(config)
        use_checkpoint_names(self, PARTS)

    def parameter_groups(self) -> list[list[nn.Parameter]]:
        """Parameters whose gradients come from separate losses (with `detach_covariance`: the
        covariance head, trained by the likelihood alone, and the rest), for per-group gradient
        clipping; one group otherwise."""
        covariance = self.head.covariance_parameters()
        if not covariance:
            return [list(self.parameters())]
        head = {id(p) for p in covariance}
        return [[p for p in self.parameters() if id(p) not in head], covariance]

    # ----------------------------------------------------------------------------- public API
    def forward(
        self,
        positions: Tensor,
        valid: Tensor,
        num_observed: int,
        labels: Tensor | None = None,
        rollout: bool = True,
        sample: bool = True,
        roles: Tensor | None = None,
        scenes: Tensor | None = None,
    ) -> ModelOutput:
        """Training pass: teacher-forced one-step predictions of t = 1 .. T-1 and, if `rollout`,
        a rollout from step T_obs-1 that feeds back reparameterised samples (`sample`) or the
        predicted means (differentiable either way).

        positions (B, T, N, 2) [m], valid (B, T, N) bool, labels (B, T, N) int (-1 none; needed
        for oracle attention), roles (B, N) int (needed with num_roles), scenes (B,) int: the
        scenes' indices in the training split that `fit_normalisation` saw (with a highway, each
        scene's rollout then uses the map fitted without it; None: the map of all scenes). The
        rollout reuses the teacher-forced recurrent states after the observed steps.
        """
        steps = self._prepare(positions, valid, num_observed, labels, roles)
        steps.scenes = scenes
        observed = self._block(steps, 0, num_observed, None)
        rest = self._block(steps, num_observed, positions.shape[1] - 1, observed.state)
        parts = [observed] if rest is None else [observed, rest]
        one_step = Gaussian2D.cat([p.gaussian for p in parts], 0).time_first()
        attention = torch.cat([p.attention for p in parts], 0).transpose(0, 1)  # (B, T-1, N, N-1)
        out = ModelOutput(one_step=one_step, attention=attention)
        if rollout:
            out = out.with_rollout(self._rollout(steps, observed, sample))
            out = self._with_modes(out, steps, observed)
        return out

    @torch.no_grad()
    def predict(
        self,
        positions: Tensor,
        valid: Tensor,
        num_observed: int,
        labels: Tensor | None = None,
        roles: Tensor | None = None,
    ) -> ModelOutput:
        """Test-time prediction: observe t < T_obs, then feed back the predicted means.

        Only positions and validity up to step T_obs-1 are read (plus oracle labels and roles, if
        the model uses them). `one_step`/`attention` cover the observed part (t = 1 .. T_obs,
        theta^0 .. theta^{T_obs-1}).
        """
        steps = self._prepare(positions, valid, num_observed, labels, roles, num_observed)
        observed = self._block(steps, 0, num_observed, None)
        out = ModelOutput(
            one_step=observed.gaussian.time_first(), attention=observed.attention.transpose(0, 1)
        )
        return self._with_modes(
            out.with_rollout(self._rollout(steps, observed, sample=False)), steps, observed
        )

    @torch.no_grad()
    def sample_rollouts(
        self,
        positions: Tensor,
        valid: Tensor,
        num_observed: int,
        num_samples: int,
        labels: Tensor | None = None,
        roles: Tensor | None = None,
    ) -> Tensor:
        """K futures (K, B, T_pred, N, 2) [m] by the paper's sampled rollout: observe t < T_obs
        once, then roll out K times, each step feeding back a draw from the predicted Gaussian
        (torch's global generator: seed it for reproducible draws). Reads what `predict`
        reads, and nothing after step T_obs-1."""
        batch = positions.shape[0]
        steps = self._prepare(positions, valid, num_observed, labels, roles, num_observed)
        observed = self._block(steps, 0, num_observed, None)
        tiled = self._prepare(
            positions.repeat(num_samples, 1, 1, 1),
            valid.repeat(num_samples, 1, 1),
            num_observed,
            None if labels is None else labels.repeat(num_samples, 1, 1),
            None if roles is None else roles.repeat(num_samples, 1),
            num_observed,
        )
        rollout = self._rollout(tiled, tile_outputs(observed, num_samples), True, keep_draws=True)
        draws = rollout.draws  # (K*B, T_pred, N, 2)
        return draws.view(num_samples, batch, *draws.shape[1:])

    @torch.no_grad()
    def fit_normalisation(
        self,
        positions: Tensor,
        valid: Tensor,
        num_observed: int,
        roles: Tensor | None = None,
        fit_maps: bool = True,
    ) -> None:
        """Fit the agent frame's statistics on (training) scenes (B, T, N, 2), (B, T, N): the
        input encoder's standardisation (`AgentFrameEncoder.fit_statistics`), the output
        head's scales (`AgentFrameHead.fit_scales`) and, with `highway_steps`, the highway's
        maps (`Highway.fit`; roles (B, N) choose the map where the model reads roles);
        fit_maps=False leaves its maps (not its edge statistics) to `refit_attended`, as
        training does, which replaces them unread.
        """
        if not self.encoder.has_statistics:
            raise ValueError("fit_normalisation needs frame='agent'")
        no_labels = torch.full(valid.shape, -1, dtype=torch.long)  # labels play no part here
        no_roles = torch.zeros(valid.shape[0], valid.shape[2], dtype=torch.long)  # nor roles
        steps = self._prepare(positions, valid, num_observed, no_labels, no_roles)
        self.encoder.fit_statistics(steps)
        self.head.fit_scales(steps)
        if self.highway is not None:
            self.highway.fit(steps, roles, fit_maps)

    @torch.no_grad()
    def refit_attended(
        self,
        positions: Tensor,
        valid: Tensor,
        num_observed: int,
        labels: Tensor | None = None,
        roles: Tensor | None = None,
        batch_size: int = 64,
    ) -> None:
        """Refit the highway's own and attended maps jointly in closed form
        (`ModelConfig.attended_refit`) on the training scenes (B, T, N, .), in the order
        `fit_normalisation` saw them (the cross-fitting folds follow the scene index), with the
        attention the model gives now at the last observed step. labels (B, T, N) are needed
        for oracle attention, roles (B, N) where the model reads roles."""
        if self.highway is None or not self.highway.refits:
            raise ValueError("refit_attended needs ModelConfig.attended_refit")
        self.highway.require_roles(roles, "refit_attended")
        samples: list[tuple[Tensor, ...]] = []
        for first in range(0, positions.shape[0], batch_size):
            sl = slice(first, first + batch_size)
            steps = self._prepare(
                positions[sl],
                valid[sl],
                num_observed,
                None if labels is None else labels[sl],
                None if roles is None else roles[sl],
            )
            theta = self._block(steps, 0, num_observed, None).attention[-1]  # (B, N, N-1)
            samples.append(self.highway.samples(steps, theta))
        self.highway.refit(samples, num_observed, self.head.anchor_std)

    def fill_unclamped_range(self, state: dict[str, Tensor]) -> dict[str, Tensor]:
        """A checkpoint's state dict with the highway's output range added where it lacks one
        (`Highway.fill_unclamped_range`; unchanged without a highway)."""
        return state if self.highway is None else self.highway.fill_unclamped_range(state)

    # ----------------------------------------------------------------------------- internals
    def _prepare(
        self,
        positions: Tensor,
        valid: Tensor,
        num_observed: int,
        labels: Tensor | None,
        roles: Tensor | None = None,
        graph_steps: int | None = None,
    ) -> PassInputs:
        """The time-first inputs of a pass with its neighbour graph (`prepare_pass`)."""
        return prepare_pass(self.config, positions, valid, num_observed, labels, roles, graph_steps)

    def _block(
        self, steps: PassInputs, start: int, stop: int, state: RecurrentState | None
    ) -> StepOutputs | None:
        """Teacher-forced steps start .. stop-1 (None if empty).

        The steps run in chunks of `chunk_steps` per nn.LSTM call, carrying the recurrent state:
        the same result as one call over the whole span (tested), but faster on CPU because a
        chunk's working set stays in cache (a training epoch of the default shape took ~10-20 %
        less time with chunks of 8 than with one call over all 59 steps).
        """
        if stop <= start:
            return None
        chunks = []
        for first in range(start, stop, self.config.chunk_steps):
            sl = slice(first, min(first + self.config.chunk_steps, stop))
            labels = None if steps.labels is None else steps.labels[sl]
            chunk = self._run(
                steps.pos[sl],
                steps.prev_pos[sl],
                steps.present[sl],
                steps,
                labels,
                state,
            )
            chunks.append(chunk)
            state = chunk.state
        return StepOutputs(
            Gaussian2D.cat([c.gaussian for c in chunks], 0),
            torch.cat([c.attention for c in chunks], 0),  # (S, B, N, N-1)
            state,
        )

    def _rollout(
        self, steps: PassInputs, observed: StepOutputs, sample: bool, keep_draws: bool = False
    ) -> Rollout:
        """Feed back samples (or means) from step T_obs on; with `keep_draws` (and `sample`)
        the rollout also keeps the fed-back draws and draws the last step's."""
        t_obs = steps.num_observed
        num_steps = steps.pos.shape[0]
        present = steps.present[t_obs - 1]  # (B, N) agents rolled out
        gaussian = Gaussian2D(observed.gaussian.mean[-1], observed.gaussian.tril[-1])  # (B, N, .)
        state, prev = observed.state, steps.pos[t_obs - 1]  # prev: (B, N, 2)
        presence = self.attention.presence(present[None], steps)  # the same at every step
        anchors = self._anchors(steps, observed)  # (B, N, K, 2) or None
        if anchors is not None:
            # the first predicted step too: F_roll on the node output of step T_obs-1 (the
            # LSTM's last h), so the rollout loss trains every step of the rollout's means
            o_last = state.node[0][0].view(*present.shape, -1)  # (B, N, Hn)
            gaussian = self.head.anchored_step(o_last, prev + anchors[:, :, 0], steps.frame[1])
        gaussians, attentions, draws = [gaussian], [observed.attention[-1]], []
        for t in range(t_obs, num_steps - 1):
            anchor = None  # the anchored prior's velocity at predicted step t + 1 - T_obs
            if anchors is not None:
                anchor = anchors[:, :, min(t + 1 - t_obs, anchors.shape[2] - 1)]  # (B, N, 2)
            current = gaussian.rsample() if sample else gaussian.mean  # (B, N, 2)
            current = torch.where(present.unsqueeze(-1), current, torch.zeros_like(current))
            draws.append(current)
            labels = None if steps.labels is None else steps.labels[t : t + 1]  # (1, B, N)
            block = self._run(
                current[None],
                prev[None],
                present[None],
                steps,
                labels,
                state,
                anchor,
                presence,
            )
            gaussian = Gaussian2D(block.gaussian.mean[0], block.gaussian.tril[0])  # (B, N, .)
            gaussians.append(gaussian)
            attentions.append(block.attention[0])
            state, prev = block.state, current
        if keep_draws and sample:
            draws.append(gaussian.rsample())
        return Rollout(
            gaussian=Gaussian2D(
                torch.stack([g.mean for g in gaussians], 1),  # (B, T_pred, N, 2)
                torch.stack([g.tril for g in gaussians], 1),  # (B, T_pred, N, 3)
            ),
            attention=torch.stack(attentions, 1),  # (B, T_pred, N, N-1)
            present=present,
            draws=torch.stack(draws, 1) if keep_draws and sample else None,
        )

    def _with_modes(
        self, out: ModelOutput, steps: PassInputs, observed: StepOutputs
    ) -> ModelOutput:
        """`out` with the trajectory modes (modes > 1) around its rollout."""
        if self.modes is None:
            return out
        present = steps.present[steps.num_observed - 1]  # (B, N)
        o_last = observed.state.node[0][0].view(*present.shape, -1)  # (B, N, Hn) at T_obs-1
        mixture = self.modes(o_last, out.rollout, steps.frame[1], self.head.anchor_std)
        return replace(out, modes=mixture)

    def _anchors(self, steps: PassInputs, observed: StepOutputs) -> Tensor | None:
        """The anchored rollout's velocities (B, N, K, 2) [m/step], world axes, of predicted
        steps 0 .. K-1 (later ones take the last): the velocity at the last observed step plus
        the highway's velocity changes over its horizon K (K = 1 without a highway), read with
        the attention at the last observed step; None with the one-step prior."""
        if not self.head.anchored:
            return None
        t_obs = steps.num_observed
        velocity = steps.pos[t_obs - 1] - steps.prev_pos[t_obs - 1]  # (B, N, 2)
        velocity = velocity.unsqueeze(2)  # (B, N, 1, 2)
        if self.highway is None:
            return velocity
        return velocity + self.highway(steps, observed.attention[-1], self.head.anchor_std)

    def _run(
        self,
        pos: Tensor,
        prev_pos: Tensor,
        present: Tensor,
        steps: PassInputs,
        labels: Tensor | None,
        state: RecurrentState | None,
        anchor: Tensor | None = None,
        presence: Presence | None = None,
    ) -> StepOutputs:
        """S consecutive steps through the graph; inputs time-first (S, B, N, .).

        `anchor` (B, N, 2) [m/step]: rollout steps with the anchored prior p^t + anchor and the
        offset from F_roll (rollout_prior "anchored"); None: the one-step prior. `presence`: the
        edges' presence terms of `present` (`GraphAttention.presence`), if already computed.
        """
        num_steps, batch, num_agents, _ = pos.shape
        graph = steps.graph
        inputs = self.encoder(pos, prev_pos, present, steps)
        state = state or RecurrentState(None, None, None)
        edges = self.recurrent(inputs.self_loop, inputs.edge, state.self_loop, state.edge)
        o_edge, o_self = edges.edge, edges.self_loop  # (S, E, H), (S, B*N, H)
        presence = presence or self.attention.presence(present, steps)
        pair_bias = None if self.role_bias is None else self.role_bias(steps)  # (E,) or None
        theta = self.attention(o_self, o_edge, presence, labels, graph, pair_bias)  # (S, E)
        attended = self.attention.read(theta, o_edge, graph)  # (S, B*N, H)
        attended = attended.view(num_steps, batch, num_agents, -1)  # (S, B, N, H)
        o_self = o_self.view(num_steps, batch, num_agents, -1)  # (S, B, N, H)
        o_node, h_node = self.node(inputs.node, attended, o_self, state.node)  # (S, B*N, Hn)
        rotation = None if steps.frame is None else steps.frame[1]
        if anchor is None:
            gaussian = self.head(o_node, pos, prev_pos, rotation)  # (S, B, N, .)
        else:
            gaussian = self.head.anchored_step(o_node, pos + anchor, rotation)
        attention = graph.to_compact(theta)  # (S, B, N, N-1), zero off the graph
        return StepOutputs(
            gaussian, attention, RecurrentState(edges.edge_state, edges.self_state, h_node)
        )


def tile_outputs(outputs: StepOutputs, copies: int) -> StepOutputs:
    """`outputs` of a batch of B scenes as those of the batch repeated `copies` times (scene
    k B + b is scene b): the batch-major tensors and recurrent states tiled, in the order
    `prepare_pass` gives the repeated batch's agents and edges (tested)."""

    def tile(state: tuple[Tensor, Tensor] | None) -> tuple[Tensor, Tensor] | None:
        return None if state is None else tuple(s.repeat(1, copies, 1) for s in state)

    state = outputs.state
    return StepOutputs(
        Gaussian2D(
            outputs.gaussian.mean.repeat(1, copies, 1, 1),
            outputs.gaussian.tril.repeat(1, copies, 1, 1),
        ),
        outputs.attention.repeat(1, copies, 1, 1),
        RecurrentState(tile(state.edge), tile(state.self_loop), tile(state.node)),
    )
