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
the action read-out uses must carry where the object is; `first_frame` puts the visual tokens of the episode's
first frame once before the T steps, so what the cameras saw before the arm came between them and the object
stays in view of every query (the T-step window alone forgets it); `object_readout` adds, per step, a token made
from an MLP's read-out of the object's pose (position, sin/cos of 4x yaw: what the privileged-state control sees)
from that step's frozen tokens, trained on the frames store's poses and passed on without gradient, so the
policy gets an explicit object estimate it cannot reshape to fit the actions; with `readout_scenes` that read-out
is fitted before the policy, on the demos' frames plus many extra scenes, and frozen (training.fit_readout). The
read-out standardizes its input per token dimension like the visual tokens, or (`readout_standardize: element`)
per camera, slot and dimension with its own statistics: slots keep their own offsets, which the pooled statistics
leave in and which cost the read-out half its precision. `readout_tcp_relative` adds the read-out's position
minus the TCP to its token (what the control's token holds with the true position). `visual_dropout` blanks a
training step's standardized visual tokens (to their mean) with that chance, and `visual_head: none` leaves them out
altogether: with 100 demos the policy can fit its actions to the slots' many dimensions instead of to the read-out's
estimate, and then acts on the slots' imprecise object position in closed loop. `goal_relative: tcp` widens the
goal input with the goal minus the TCP (for the 2D goal: the TCP projected into each image like the goal): how far
the hand still has to go, which the policy otherwise has to work out from the joints."""

from __future__ import annotations

import torch
from torch import nn

from ..encoders.state import STATE_DIMS
from .heads import HEADS, CrossCameraFusion, mlp
from .settings import PolicySettings

GOAL_DIMS = {"none": 0, "2d": 4, "3d": 3}
PROPRIO_DIMS = {"joints7": 7, "qpos9_global": 9, "qpos9_grouped": 9, "joints7_tcp": 10}


def goal_dims(policy: PolicySettings) -> int:
    """Width of the goal input: the goal, and with `goal_relative: tcp` the goal minus the TCP beside it."""
    return GOAL_DIMS[policy.goal] * (2 if policy.goal_relative == "tcp" else 1)


class SequencePolicy(nn.Module):
    def __init__(self, policy: PolicySettings | dict, K: int, D: int, token_stats: tuple | None = None,
                 readout_stats: tuple | None = None, readout_pose_stats: tuple | None = None):
        super().__init__()
        policy = PolicySettings.of(policy)
        W, heads = policy.width, policy.heads
        self.T, self.H = policy.window, policy.horizon
        self.cams = len(policy.cameras)
        self.goal_kind = policy.goal
        self.tanh = policy.action_head == "tanh"
        self.visual_dropout = policy.visual_dropout
        self.bce = policy.gripper == "bce"
        self.visual = HEADS[policy.visual_head](K, D, W, heads)
        self.fusion = CrossCameraFusion(W, heads) if policy.fusion == "cross_attention" else None
        self.proprio = mlp([PROPRIO_DIMS[policy.proprio], W, W, W])
        G = goal_dims(policy)  # only the goal module in use is built: no init draws for the others
        self.goal = mlp([G, W, W, W]) if self.goal_kind == "2d" else nn.Linear(G, W) if self.goal_kind == "3d" else None
        self.action_token = nn.Parameter(torch.zeros(W))
        readout = policy.object_readout
        self.object_readout = mlp([self.cams * K * D, 4 * W, 4 * W, STATE_DIMS]) if readout else None
        # readout_tcp_relative: the token also gets the read-out's position minus the TCP, in decimetres
        self.readout_tcp = readout and policy.readout_tcp_relative
        self.object_token = nn.Linear(STATE_DIMS + 3 * self.readout_tcp, W) if readout else None
        if self.readout_tcp:  # to turn the standardized read-out back into metres
            self._stats_buffers("readout_out", readout_pose_stats, STATE_DIMS)
        # readout_standardize 'element': the read-out's own input statistics, one per camera, slot and dimension
        self.readout_elementwise = readout and policy.readout_standardize == "element"
        if self.readout_elementwise:
            self._stats_buffers("readout_in", readout_stats, self.cams * K * D)
        self.per_step = self.cams * self.visual.tokens_out + 1 + (self.goal is not None) + readout + 1
        self.pos = nn.Parameter(torch.zeros(self.T * self.per_step, W))
        layer = nn.TransformerEncoderLayer(W, heads, 4 * W, dropout=policy.dropout, activation="gelu",
                                           batch_first=True, norm_first=True)
        self.decoder = nn.TransformerEncoder(layer, policy.layers, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(W)
        self.readout = mlp([W, W, W, self.H * (7 if self.bce else 8)])
        self.gripper_head = mlp([W, W, W, self.H]) if self.bce else None
        self._stats_buffers("token", token_stats, D)
        self.aux_head = mlp([W, W, 3]) if policy.aux_object_weight > 0 else None
        self.first_frame = bool(policy.first_frame)
        self.prefix = self.cams * self.visual.tokens_out if self.first_frame else 0
        self.first_pos = nn.Parameter(torch.zeros(self.prefix, W)) if self.first_frame else None
        if self.first_pos is not None:
            nn.init.normal_(self.first_pos, std=0.02)
        nn.init.normal_(self.pos, std=0.02)
        nn.init.normal_(self.action_token, std=0.02)

    def _stats_buffers(self, prefix: str, stats: tuple | None, n: int) -> None:
        """Buffers ``{prefix}_mean`` / ``{prefix}_std`` of n values (identity standardization without ``stats``): saved
        in the checkpoint with the weights."""
        mean, std = stats if stats is not None else (torch.zeros(n), torch.ones(n))
        self.register_buffer(f"{prefix}_mean", torch.as_tensor(mean, dtype=torch.float32).reshape(n))
        self.register_buffer(f"{prefix}_std", torch.as_tensor(std, dtype=torch.float32).reshape(n))

    def _visual(self, z):
        """Standardized tokens (B, T, C, K, D) -> (B, T, C, k, W)."""
        vis = self.visual(z)
        return self.fusion(vis) if self.fusion is not None else vis

    def _standardize(self, tokens):
        return (tokens - self.token_mean) / self.token_std

    def readout_input(self, tokens):
        """Raw tokens (..., C, K, D) -> the object read-out's standardized input (..., C * K * D)."""
        if self.readout_elementwise:
            return (tokens.flatten(-3) - self.readout_in_mean) / self.readout_in_std
        return self._standardize(tokens).flatten(-3)

    def object_pose(self, tokens):
        """Raw tokens (..., C, K, D) -> the read-out's standardized object pose (..., 5)."""
        return self.object_readout(self.readout_input(tokens))

    def tokens(self, tokens, proprio, goal, first=None, readout_noise=None, tcp=None, readout_seen=None):
        """(B, T, C, K, D), (B, T, P), (B, T, G) [, first frame (B, C, K, D)] -> the flattened sequence
        (B, prefix + T * per_step, W) and the object read-out (B, T, 5) (None without one). ``readout_noise``
        (3,): std of Gaussian noise added to the read-out's (standardized) position before the policy sees it.
        ``tcp`` (B, T, 3): the TCP's position (m), for readout_tcp_relative policies. ``readout_seen`` (B, T, 5):
        the (standardized) object pose the policy sees in place of each step's own read-out, e.g. one filtered
        over the episode's frames (evaluation.readout_filter)."""
        B, T = tokens.shape[:2]
        if T != self.T:
            raise ValueError(f"policy expects windows of T={self.T} steps, got {T}")
        z = self._standardize(tokens)
        if self.training and self.visual_dropout > 0:  # blank whole steps: the policy must act without the slots
            blank = torch.rand(B, T, 1, 1, 1, device=z.device) < self.visual_dropout
            z = z.masked_fill(blank, 0.0)
        parts = [self._visual(z).flatten(2, 3), self.proprio(proprio)[:, :, None]]
        if self.goal is not None:
            parts.append(self.goal(goal)[:, :, None])
        readout = None
        if self.object_readout is not None:
            readout = self.object_pose(tokens)
            seen = readout.detach() if readout_seen is None else readout_seen
            if readout_noise is not None:
                seen = torch.cat([seen[..., :3] + readout_noise * torch.randn_like(seen[..., :3]), seen[..., 3:]], -1)
            if self.readout_tcp:
                if tcp is None:
                    raise ValueError("this policy was trained with readout_tcp_relative: true and needs the TCP")
                pos = seen[..., :3] * self.readout_out_std[:3] + self.readout_out_mean[:3]
                seen = torch.cat([seen, 10.0 * (pos - tcp)], -1)
            parts.append(self.object_token(seen)[:, :, None])
        parts.append(self.action_token.expand(B, T, 1, -1))
        seq = torch.cat(parts, dim=2).flatten(1, 2) + self.pos
        if not self.first_frame:
            return seq, readout
        if first is None:
            raise ValueError("this policy was trained with first_frame: true and needs the episode's first frame")
        prefix = self._visual(self._standardize(first[:, None])).flatten(1, 3) + self.first_pos
        return torch.cat([prefix, seq], dim=1), readout

    def forward(self, tokens, proprio, goal, first=None, all_steps: bool = False, aux: bool = False,
                readout_noise=None, tcp=None, readout_seen=None):
        """-> (B, H, 8) predictions for the current step, or (B, T, H, 8) for every step's action token; with
        ``aux`` also a dict of the auxiliary predictions: 'object_pos' (B, 3), the auxiliary head's object position
        at the current step, and 'readout' (B, T, 5), the object read-out of every step (each None when the
        policy has no such head). ``first``: the episode's first-frame tokens (B, C, K, D), for first_frame
        policies only. ``readout_noise``, ``tcp``, ``readout_seen``: see tokens."""
        seq, readout = self.tokens(tokens, proprio, goal, first, readout_noise, tcp, readout_seen)
        L = seq.shape[1]
        mask = nn.Transformer.generate_square_subsequent_mask(L, device=seq.device, dtype=seq.dtype)
        h = self.norm(self.decoder(seq, mask=mask, is_causal=True))
        act = h[:, self.prefix + self.per_step - 1 :: self.per_step]  # (B, T, W): each step's action token
        if not all_steps:
            act = act[:, -1:]
        out = self.readout(act)
        B, S = act.shape[:2]
        if self.bce:
            out = torch.cat([out.reshape(B, S, self.H, 7), self.gripper_head(act).reshape(B, S, self.H, 1)], -1)
        else:
            out = out.reshape(B, S, self.H, 8)
        if self.tanh:
            out = torch.cat([torch.tanh(out[..., :7]), out[..., 7:]], -1)
        out = out if all_steps else out[:, 0]
        if aux:
            obj = self.aux_head(act[:, -1]) if self.aux_head is not None else None
            return out, {"object_pos": obj, "readout": readout}
        return out


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
