"""The Autoregressive Multimodal Sequence Policy (docs/study.md, Policy).

Per timestep the sequence holds one group of tokens per source, in this order: the visual tokens of every camera
used, one proprioception token (3-layer MLP), one goal token (2d: 3-layer MLP; 3d: linear; no token for goal
'none'), one object token (the object read-out's pose estimate, with `object_readout`) and one learnable action
token. Learned positional embeddings cover the whole T-step sequence; a causal GPT-style decoder (pre-norm) runs
over it, and the current step's action token is read out into H x 8 actions (joints in model units, gripper raw,
or a separate gripper logit with `gripper: bce`).

    raw inputs --Normalizer--> standardized --TokenSource each--> (B, T, n_s, W) --cat + pos--> (B, T*S, W)
    --causal decoder--> action token of the last step (B, W) --ActionHead--> (B, H, 8)

Departures from the study, each off in config/thesis.yaml (what each measured: docs/results.md): `token_norm`
standardizes every visual token dimension (the Normalizer); `aux_object_weight` > 0 adds a head that predicts
the object's position from the action token; `object_readout` adds the object token: an MLP's read-out of the
object's pose (position, sin/cos of 4x yaw: what the privileged-state control sees) from that step's frozen
tokens, trained on the stores' poses (with `readout_scenes`: fitted first on many extra scenes, then frozen) and
passed on without gradient, so the policy gets an estimate it cannot reshape to fit the actions;
`visual_dropout` blanks a training step's standardized visual tokens (to their mean) with that chance, so the
policy also learns to act from the read-out, joints and goal; `visual_head: none` leaves the visual tokens out;
`goal_relative: tcp` widens the goal with the goal minus the TCP."""

from __future__ import annotations

from typing import NamedTuple

import torch
from torch import nn

from ..encoders.state import STATE_DIMS
from .heads import HEADS, CrossCameraFusion, mlp
from .normalization import Normalizer
from .settings import PolicySettings

GOAL_DIMS = {"none": 0, "2d": 4, "3d": 3}
PROPRIO_DIMS = {"joints7": 7, "qpos9_global": 9, "qpos9_grouped": 9, "joints7_tcp": 10}


class PolicyOutput(NamedTuple):
    actions: torch.Tensor  # (B, H, 8): joints in model units, gripper raw (or its logit with gripper: bce)
    readout: torch.Tensor | None  # (B, T, 5): the object read-out of every step (standardized pose)
    object_pos: torch.Tensor | None  # (B, 3): the auxiliary head's object position (standardized)


def goal_dims(policy: PolicySettings) -> int:
    """Width of the goal input: the goal, and with `goal_relative: tcp` the goal minus the TCP beside it."""
    return GOAL_DIMS[policy.goal.kind] * (2 if policy.goal.relative == "tcp" else 1)


class Inputs(NamedTuple):
    """One batch of standardized inputs, as the token sources read them."""

    z: torch.Tensor  # (B, T, C, K, D) visual tokens
    proprio: torch.Tensor  # (B, T, P)
    goal: torch.Tensor  # (B, T, G)
    readout_in: torch.Tensor  # (B, T, C * K * D): the object read-out's input
    readout_seen: torch.Tensor | None  # (B, T, 5): a pose to see in place of the read-out's own


class VisualSource(nn.Module):
    """Standardized tokens (B, T, C, K, D) -> (B, T, C * k, W): through the visual head (and fusion); in training,
    whole steps are blanked with chance ``dropout``."""

    def __init__(self, head: nn.Module, fusion: nn.Module | None, dropout: float, cams: int):
        super().__init__()
        self.head, self.fusion, self.dropout = head, fusion or nn.Identity(), dropout
        self.tokens_out = cams * head.tokens_out

    def forward(self, x: Inputs):
        z = x.z
        if self.training and self.dropout > 0:  # blank whole steps: the policy must act without the slots
            z = z.masked_fill(torch.rand(*z.shape[:2], 1, 1, 1, device=z.device) < self.dropout, 0.0)
        return self.fusion(self.head(z)).flatten(2, 3), None


class VectorSource(nn.Module):
    """One token per step from a vector input (proprio or goal): (B, T, n) -> (B, T, 1, W)."""

    def __init__(self, field: str, net: nn.Module):
        super().__init__()
        self.field, self.net, self.tokens_out = field, net, 1

    def forward(self, x: Inputs):
        return self.net(getattr(x, self.field))[:, :, None], None


class ObjectSource(nn.Module):
    """The object token: the read-out's pose estimate (B, T, 5) of each step, seen without gradient (or the pose
    given in its place), projected to (B, T, 1, W); the estimate itself comes out beside it for its loss."""

    def __init__(self, inputs: int, width: int):
        super().__init__()
        self.readout = mlp([inputs, 4 * width, 4 * width, STATE_DIMS])
        self.token = nn.Linear(STATE_DIMS, width)
        self.tokens_out = 1

    def forward(self, x: Inputs):
        pose = self.readout(x.readout_in)
        seen = pose.detach() if x.readout_seen is None else x.readout_seen
        return self.token(seen)[:, :, None], pose


def token_sources(policy: PolicySettings, K: int, D: int, W: int) -> nn.ModuleList:
    """The sources of one step's tokens, in sequence order; built in this order, each draws its initial weights
    from the seeded generator in turn (the action token's place: between the goal and the object)."""
    heads, cams = policy.network.heads, len(policy.stores.cameras)
    head = HEADS[policy.visual.head](K, D, W, heads)
    fusion = CrossCameraFusion(W, heads) if policy.visual.fusion == "cross_attention" else None
    sources = [VisualSource(head, fusion, policy.visual.dropout, cams),
               VectorSource("proprio", mlp([PROPRIO_DIMS[policy.network.proprio], W, W, W]))]
    G = goal_dims(policy)
    if policy.goal.kind == "2d":
        sources.append(VectorSource("goal", mlp([G, W, W, W])))
    elif policy.goal.kind == "3d":
        sources.append(VectorSource("goal", nn.Linear(G, W)))
    return nn.ModuleList(sources)


class ActionHead(nn.Module):
    """The current step's action token (B, W) -> (B, H, 8): joints (tanh-squashed with action_head 'tanh') and the
    gripper, from one 3-layer MLP or (gripper 'bce') a second MLP giving its logit."""

    def __init__(self, policy: PolicySettings, W: int):
        super().__init__()
        self.H, bce = policy.network.horizon, policy.network.gripper == "bce"
        self.net = mlp([W, W, W, self.H * (7 if bce else 8)])
        self.gripper = mlp([W, W, W, self.H]) if bce else None
        self.squash = nn.Tanh() if policy.network.action_head == "tanh" else nn.Identity()

    def forward(self, act):
        out = self.net(act).reshape(len(act), self.H, -1)  # (B, H, 8), or (B, H, 7) joints beside a gripper MLP
        grip = out[..., 7:] if self.gripper is None else self.gripper(act).reshape(len(act), self.H, 1)
        return torch.cat([self.squash(out[..., :7]), grip], -1)


class SequencePolicy(nn.Module):
    """The policy; ``K``, ``D``: tokens per camera and their width in the features store. Its Normalizer holds
    every statistic (identity until fitted), so a checkpoint's state dict is the whole policy."""

    def __init__(self, policy: PolicySettings | dict, K: int, D: int):
        super().__init__()
        policy = PolicySettings.of(policy)
        W, cams = policy.network.width, len(policy.stores.cameras)
        self.T = policy.network.window
        self.normalizer = Normalizer(policy, K, D, cams, PROPRIO_DIMS[policy.network.proprio], goal_dims(policy))
        self.sources = token_sources(policy, K, D, W)
        self.action_token = nn.Parameter(torch.zeros(W))
        if policy.readout.enabled:
            self.sources.append(ObjectSource(cams * K * D, W))
        self.per_step = sum(s.tokens_out for s in self.sources) + 1  # + the action token
        self.pos = nn.Parameter(torch.zeros(self.T * self.per_step, W))
        layer = nn.TransformerEncoderLayer(W, policy.network.heads, 4 * W, dropout=policy.network.dropout,
                                           activation="gelu", batch_first=True, norm_first=True)
        self.decoder = nn.TransformerEncoder(layer, policy.network.layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(W)
        self.action_head = ActionHead(policy, W)
        self.aux_head = mlp([W, W, 3]) if policy.training.aux_object_weight > 0 else None
        nn.init.normal_(self.pos, std=0.02)
        nn.init.normal_(self.action_token, std=0.02)

    @property
    def object_readout(self) -> nn.Module | None:
        """The object read-out MLP (None without one)."""
        return next((s.readout for s in self.sources if isinstance(s, ObjectSource)), None)

    def object_pose(self, tokens):
        """Raw tokens (..., C, K, D) -> the read-out's standardized object pose (..., 5)."""
        return self.object_readout(self.normalizer.readout_input(tokens))

    def tokens(self, tokens, proprio, goal, readout_seen=None):
        """Raw inputs (B, T, C, K, D), (B, T, P), (B, T, G) (policy.observation) -> the flattened sequence
        (B, T * per_step, W) and the object read-out (B, T, 5) (None without one). ``readout_seen`` (B, T, 5): the
        (standardized) object pose the policy sees in place of each step's read-out (the closed loop passes each
        step's read-out as computed when its frame arrived, or the true pose of evaluation.readout_filter)."""
        B, T = tokens.shape[:2]
        if T != self.T:
            raise ValueError(f"policy expects windows of T={self.T} steps, got {T}")
        norm = self.normalizer
        x = Inputs(norm.tokens(tokens), norm.proprio(proprio), norm.goal(goal), norm.readout_input(tokens),
                   readout_seen)
        outs = [source(x) for source in self.sources]  # (B, T, n_s, W) and the read-out's pose (or None)
        parts = [t for t, _ in outs] + [self.action_token.expand(B, T, 1, -1)]
        readout = next((pose for _, pose in outs if pose is not None), None)
        return torch.cat(parts, dim=2).flatten(1, 2) + self.pos, readout

    def action_states(self, seq):
        """Sequence (B, L, W) -> the decoder's output at every step's action token (B, T, W), causally masked."""
        h = self.norm(self.decoder(seq, mask=causal_mask(seq), is_causal=True))
        return h[:, self.per_step - 1 :: self.per_step]

    def current_action_state(self, seq):
        """Sequence (B, L, W) -> the decoder's output at the last token, the current step's action token (B, W):
        action_states(seq)[:, -1] up to float rounding. Only that token is read, so the last layer attends from it
        alone and runs its feed-forward on it alone; its other L - 1 rows made a training step about 1.7x as long
        (bench/bench_policy.py --decoder)."""
        *inner, last = self.decoder.layers
        mask = causal_mask(seq)
        for layer in inner:
            seq = layer(seq, src_mask=mask, is_causal=True)
        # the last token sees every earlier one, so its row of the causal mask masks nothing
        h = last.norm1(seq)
        x = seq[:, -1:] + last.dropout1(last.self_attn(h[:, -1:], h, h, need_weights=False)[0])
        x = x + last.dropout2(last.linear2(last.dropout(last.activation(last.linear1(last.norm2(x))))))
        return self.norm(x[:, 0])

    def forward(self, tokens, proprio, goal, readout_seen=None, every_step: bool = False) -> PolicyOutput:
        """(B, T, C, K, D), (B, T, P), (B, T, G) -> PolicyOutput: the current step's (B, H, 8) actions, the object
        read-out of every step (B, T, 5) and the auxiliary head's object position (B, 3), each None when the
        policy has no such head. ``readout_seen``: see tokens. ``every_step`` (training with action loss
        `every_step`): the actions of every step's action token, (B, T, H, 8), each seeing only the steps up to
        its own; the auxiliary head still reads the current step's."""
        seq, readout = self.tokens(tokens, proprio, goal, readout_seen)
        if every_step:
            states = self.action_states(seq)  # (B, T, W)
            act = states[:, -1]
            actions = self.action_head(states.flatten(0, 1)).unflatten(0, states.shape[:2])
        else:
            act = self.current_action_state(seq)  # (B, W)
            actions = self.action_head(act)
        obj = self.aux_head(act) if self.aux_head is not None else None
        return PolicyOutput(actions, readout, obj)


def causal_mask(seq: torch.Tensor) -> torch.Tensor:
    """The (L, L) mask that keeps each token of a (B, L, W) sequence from attending to later ones."""
    return nn.Transformer.generate_square_subsequent_mask(seq.shape[1], device=seq.device, dtype=seq.dtype)


def loss_terms(pred: torch.Tensor, target: torch.Tensor, weights: torch.Tensor, bce: bool) -> dict[str, torch.Tensor]:
    """Weighted MSE on z-scored joints; gripper MSE on the raw command or BCE on its logit."""
    joints = (weights[..., :7] * (pred[..., :7] - target[..., :7]) ** 2).mean()
    if bce:
        g = nn.functional.binary_cross_entropy_with_logits(pred[..., 7], (target[..., 7] > 0).float(), reduction="none")
    else:
        g = (pred[..., 7] - target[..., 7]) ** 2
    gripper = (weights[..., 7] * g).mean()
    # the gripper is one of 8 action dims: weight it like one so the total equals a plain 8-dim MSE under 'uniform'
    return {"loss": (7 * joints + gripper) / 8, "loss_joints": joints, "loss_gripper": gripper}


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
