"""The privileged-state control: an 'encoder' whose token is the manipulated object's true pose.

Not a method of the study but its ceiling: the same policy, recipe and demos, with one token per step that
holds what the visual encoders are supposed to extract (the object's position and its yaw). If this control
fails, the recipe or the budget is to blame; if it succeeds and a visual policy does not, perception is. The
token is read from the frames store in training and from the simulator in evaluation, where nothing is
rendered. Yaw enters as sin/cos of 4x yaw: a cube looks the same after a quarter turn, so poses that differ by
90 degrees get one encoding. With ``tcp_relative`` the token also holds the object's offset from the TCP: the
policy then reads how far the gripper still has to go instead of working the difference out from two
separately normalized inputs (docs/journal.md, "The control's missing piece")."""

from __future__ import annotations

import numpy as np

STATE_DIMS = 5  # x, y, z, sin(4 yaw), cos(4 yaw)
RELATIVE_DIMS = 3  # object minus TCP, x, y, z (tcp_relative tokens only)


def yaw(quat_wxyz: np.ndarray) -> np.ndarray:
    """Rotation about the world z axis of (..., 4) unit quaternions (w, x, y, z)."""
    w, x, y, z = np.moveaxis(np.asarray(quat_wxyz, dtype=np.float64), -1, 0)
    return np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))


def state_tokens(obj_pos: np.ndarray, obj_quat: np.ndarray, tcp_pos: np.ndarray | None = None) -> np.ndarray:
    """(..., 3) positions and (..., 4) quaternions -> (..., 1, 1, 5) tokens: one camera, one token; with the
    (..., 3) TCP positions, (..., 1, 1, 8) tokens whose last three dims are the object minus the TCP."""
    pos = np.asarray(obj_pos, np.float64)
    a = 4 * yaw(obj_quat)
    parts = [pos, np.sin(a)[..., None], np.cos(a)[..., None]]
    if tcp_pos is not None:
        parts.append(pos - np.asarray(tcp_pos, np.float64))
    return np.concatenate(parts, -1).astype(np.float32)[..., None, None, :]


class StateEncoder:
    """Reads labels, not images: the features stage and evaluation ask it for tokens from poses."""

    name = "state"
    checkpoint = None
    reads_labels = True

    def __init__(self, tcp_relative: bool = False):
        self.tcp_relative = bool(tcp_relative)
        self.extra_attrs = {"tcp_relative": self.tcp_relative}
        self.dims = STATE_DIMS + RELATIVE_DIMS * self.tcp_relative

    def tokens_from_store(self, frames) -> np.ndarray:
        if "obj_quat" not in frames:
            raise ValueError(f"{frames.store}: the frames store has no 'obj_quat' array (built before it was "
                             "recorded): rebuild it to use the 'state' encoder")
        tcp = frames["tcp_pos"][...] if self.tcp_relative else None
        return state_tokens(frames["obj_pos"][...], frames["obj_quat"][...], tcp)

    def tokens_from_labels(self, labels: dict) -> np.ndarray:
        """The token of the simulator's current state (task_readouts), as tokens_from_store gives it per frame."""
        return state_tokens(labels["obj_pos"], labels["obj_quat"], labels["tcp_pos"] if self.tcp_relative else None)
