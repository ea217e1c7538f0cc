"""What a slot encoder makes of a camera's frame, for the contact sheets: the frozen encoder the policy was trained
on (encoders.registry) run on the policy's replayed view, each of its mask cells coloured by the slot that claims
it most, over the part of the image the encoder reads (slots_ssl: its workspace crop; SPOT: the whole image)."""

from __future__ import annotations

import numpy as np

from ..encoders import registry

ALPHA = 0.55  # share of the slot colour in a cell; the rest is the image under it, so objects stay recognizable
# ten distinct colours (matplotlib's tab10), one per slot index (slots beyond ten repeat them)
PALETTE = np.array([(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
                    (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)], dtype=np.float64)


def slot_encoder(policy: dict, encoders_cfg: dict, frames_store, encoder_checkpoint, camera: int):
    """The policy's frozen encoder built for its camera ``camera`` (an index into its camera set), or None where
    its encoder has no slot masks."""
    if policy["encoder"] not in registry.SLOT_ENCODERS:
        return None
    return registry.build(policy["encoder"], encoders_cfg, frames_store, encoder_checkpoint, cameras=[camera])


def slot_map(encoder, image: np.ndarray) -> np.ndarray:
    """``image`` (H, W, 3) uint8, one camera's frame -> the region the encoder reads (square), each mask cell
    coloured by its argmax slot and blended over the image, at the region's own pixel size."""
    import torch
    from PIL import Image

    with torch.inference_mode():
        _, masks = encoder.encode(torch.from_numpy(np.ascontiguousarray(image))[None, None])
    argmax = masks[0, 0].float().argmax(0).numpy()  # (g, g)
    windows = getattr(encoder, "windows", None)  # slots_ssl: (x0, y0, size) per camera, in pixels
    x0, y0, size = (int(v) for v in windows[0]) if windows is not None else (0, 0, image.shape[0])
    region = image[y0:y0 + size, x0:x0 + size].astype(np.float64)
    colours = PALETTE[argmax % len(PALETTE)].astype(np.uint8)
    cells = np.asarray(Image.fromarray(colours).resize((region.shape[1], region.shape[0]),
                                                       Image.Resampling.NEAREST), dtype=np.float64)
    return np.round((1 - ALPHA) * region + ALPHA * cells).astype(np.uint8)
