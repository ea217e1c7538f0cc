"""The Autoregressive Multimodal Sequence Policy (docs/study.md, Policy).

Per timestep the sequence holds, in this order: the visual tokens of every camera used, one proprioception token
(3-layer MLP), one goal token (2d: 3-layer MLP of the 4-vector; 3d: linear of xyz; absent for goal 'none') and
one learnable action token. Learned positional embeddings cover the whole T-step sequence; a causal GPT-style
decoder (pre-norm) runs over it, and the current step's action token is read out by a 3-layer MLP into
H x 8 actions (joints z-scored, gripper raw). With `gripper: bce` a separate 3-layer MLP gives H gripper logits.

Departures from the study, each off in config/thesis.yaml: `token_norm: zscore` standardizes every visual token
dimension with training-set statistics held in the model (the frozen encoders' dimensions differ in scale by
orders of magnitude, and a 64-wide projection trained for a few epochs does not undo that); `aux_object_weight`
> 0 adds a head that predicts the manipulated object's position from the current action token, so the features
the action read-out uses must carry where the object is; `object_readout` adds, per step, a token made
from an MLP's read-out of the object's pose (position, sin/cos of 4x yaw: what the privileged-state control sees)
from that step's frozen tokens, trained on the frames store's poses and passed on without gradient, so the
policy gets an explicit object estimate it cannot reshape to fit the actions; with `readout_scenes` that read-out
is fitted before the policy, on the demos' frames plus many extra scenes, and frozen (training.fit_readout). The
read-out standardizes its input per token dimension like the visual tokens, or (`readout_standardize: element`)
per camera, slot and dimension with its own statistics: slots keep their own offsets, which the pooled statistics
leave in and which cost the read-out half its precision. `visual_dropout` blanks a
training step's standardized visual tokens (to their mean) with that chance, and `visual_head: none` leaves them out
altogether: with 100 demos the policy can fit its actions to the slots' many dimensions instead of to the read-out's
estimate, and then acts on the slots' imprecise object position in closed loop. `goal_relative: tcp` widens the
goal input with the goal minus the TCP (for the 2D goal: the TCP projected into each image like the goal): how far
the hand still has to go, which the policy otherwise has to work out from the joints."""

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


class SequencePolicy(nn.Module):
    """The policy; ``K``, ``D``: tokens per camera and their width in the features store. Its Normalizer holds
    every statistic (identity until fitted), so a checkpoint's state dict is the whole policy."""

    def __init__(self, policy: PolicySettings | dict, K: int, D: int):
        super().__init__()
        policy = PolicySettings.of(policy)
        W, heads = policy.network.width, policy.network.heads
        self.T, self.H = policy.network.window, policy.network.horizon
        self.cams = len(policy.stores.cameras)
        self.tanh = policy.network.action_head == "tanh"
        self.visual_dropout = policy.visual.dropout
        self.bce = policy.network.gripper == "bce"
        P, G = PROPRIO_DIMS[policy.network.proprio], goal_dims(policy)
        self.normalizer = Normalizer(policy, K, D, self.cams, P, G)
        # modules in this order: each draws its initial weights from the seeded generator in turn
        self.visual = HEADS[policy.visual.head](K, D, W, heads)
        self.fusion = CrossCameraFusion(W, heads) if policy.visual.fusion == "cross_attention" else None
        self.proprio = mlp([P, W, W, W])
        # only the goal module in use is built: no init draws for the others
        kind = policy.goal.kind
        self.goal = mlp([G, W, W, W]) if kind == "2d" else nn.Linear(G, W) if kind == "3d" else None
        self.action_token = nn.Parameter(torch.zeros(W))
        readout = policy.readout.enabled
        self.object_readout = mlp([self.cams * K * D, 4 * W, 4 * W, STATE_DIMS]) if readout else None
        self.object_token = nn.Linear(STATE_DIMS, W) if readout else None
        # per step: the visual tokens of every camera, proprio, goal, object read-out, action
        self.per_step = self.cams * self.visual.tokens_out + 1 + (self.goal is not None) + readout + 1
        self.pos = nn.Parameter(torch.zeros(self.T * self.per_step, W))
        layer = nn.TransformerEncoderLayer(W, heads, 4 * W, dropout=policy.network.dropout, activation="gelu",
                                           batch_first=True, norm_first=True)
        self.decoder = nn.TransformerEncoder(layer, policy.network.layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(W)
        self.readout = mlp([W, W, W, self.H * (7 if self.bce else 8)])
        self.gripper_head = mlp([W, W, W, self.H]) if self.bce else None
        self.aux_head = mlp([W, W, 3]) if policy.training.aux_object_weight > 0 else None
        nn.init.normal_(self.pos, std=0.02)
        nn.init.normal_(self.action_token, std=0.02)

    def _visual(self, z):
        """Standardized tokens (B, T, C, K, D) -> (B, T, C, k, W)."""
        vis = self.visual(z)
        return self.fusion(vis) if self.fusion is not None else vis

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
        z = norm.tokens(tokens)
        if self.training and self.visual_dropout > 0:  # blank whole steps: the policy must act without the slots
            blank = torch.rand(B, T, 1, 1, 1, device=z.device) < self.visual_dropout
            z = z.masked_fill(blank, 0.0)
        parts = [self._visual(z).flatten(2, 3), self.proprio(norm.proprio(proprio))[:, :, None]]
        if self.goal is not None:
            parts.append(self.goal(norm.goal(goal))[:, :, None])
        readout = None
        if self.object_readout is not None:
            readout = self.object_pose(tokens)
            seen = readout.detach() if readout_seen is None else readout_seen
            parts.append(self.object_token(seen)[:, :, None])
        parts.append(self.action_token.expand(B, T, 1, -1))
        return torch.cat(parts, dim=2).flatten(1, 2) + self.pos, readout

    def action_states(self, seq):
        """Sequence (B, L, W) -> the decoder's output at every step's action token (B, T, W), causally masked."""
        mask = nn.Transformer.generate_square_subsequent_mask(seq.shape[1], device=seq.device, dtype=seq.dtype)
        h = self.norm(self.decoder(seq, mask=mask, is_causal=True))
        return h[:, self.per_step - 1 :: self.per_step]

    def forward(self, tokens, proprio, goal, readout_seen=None) -> PolicyOutput:
        """(B, T, C, K, D), (B, T, P), (B, T, G) -> PolicyOutput: the current step's (B, H, 8) actions, the object
        read-out of every step (B, T, 5) and the auxiliary head's object position (B, 3), each None when the
        policy has no such head. ``readout_seen``: see tokens."""
        seq, readout = self.tokens(tokens, proprio, goal, readout_seen)
        act = self.action_states(seq)[:, -1]  # (B, W): the current step's action token
        B = act.shape[0]
        out = self.readout(act)
        if self.bce:
            out = torch.cat([out.reshape(B, self.H, 7), self.gripper_head(act).reshape(B, self.H, 1)], -1)
        else:
            out = out.reshape(B, self.H, 8)
        if self.tanh:
            out = torch.cat([torch.tanh(out[..., :7]), out[..., 7:]], -1)
        obj = self.aux_head(act) if self.aux_head is not None else None
        return PolicyOutput(out, readout, obj)


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
