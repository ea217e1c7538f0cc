"""Writing a gallery episode's frames: an MP4 (H.264, yuv420p, even sides: what browsers play) through the ffmpeg
binary that the imageio-ffmpeg wheel ships, or an animated GIF through Pillow where imageio-ffmpeg cannot be
imported. Written under a temporary name and renamed."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from ..util.atomic import atomic_path

log = logging.getLogger(__name__)


def ffmpeg_available() -> bool:
    try:
        import imageio_ffmpeg

        imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        return False
    return True


def write_video(frames: list[np.ndarray], path: str | Path, fps: float, use_ffmpeg: bool | None = None,
                crf: int = 20) -> Path:
    """``frames`` (H, W, 3) uint8, all of one size with even sides -> ``path`` as MP4 (x264 at constant quality
    ``crf``: higher is smaller), or beside it as .gif without ffmpeg. Returns the file written. One encoder thread
    and bit-exact flags, so a rerun writes the same bytes."""
    path = Path(path)
    if not frames:
        raise ValueError(f"{path}: no frames to write")
    height, width = frames[0].shape[:2]
    if height % 2 or width % 2:
        raise ValueError(f"{path}: frames of {width} x {height} px: H.264 in yuv420p needs even sides")
    if any(f.shape != frames[0].shape or f.dtype != np.uint8 for f in frames):
        raise ValueError(f"{path}: frames differ in size or are not uint8")
    if use_ffmpeg is None:
        use_ffmpeg = ffmpeg_available()
    if not use_ffmpeg:
        log.warning("imageio-ffmpeg is not importable: %s written as an animated GIF", path.name)
        return write_gif(frames, path.with_suffix(".gif"), fps)
    import imageio_ffmpeg

    with atomic_path(path) as tmp:
        writer = imageio_ffmpeg.write_frames(
            str(tmp), (width, height), fps=fps, codec="libx264", pix_fmt_in="rgb24", pix_fmt_out="yuv420p",
            quality=None, bitrate=None, macro_block_size=2,
            output_params=["-crf", str(crf), "-preset", "medium", "-threads", "1", "-movflags", "+faststart",
                           "-fflags", "+bitexact", "-flags:v", "+bitexact", "-map_metadata", "-1"])
        writer.send(None)  # start the encoder
        for frame in frames:
            writer.send(np.ascontiguousarray(frame))
        writer.close()
    return path


def write_gif(frames: list[np.ndarray], path: str | Path, fps: float) -> Path:
    from PIL import Image

    path = Path(path)
    images = [Image.fromarray(np.ascontiguousarray(f)) for f in frames]
    with atomic_path(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0)
    return path

