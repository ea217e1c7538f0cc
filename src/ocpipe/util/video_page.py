"""A video as a page Snakemake's report can play: the report (Snakemake 9) shows a PNG in an <img> and an HTML file
in an <iframe>, but offers an MP4 (or an animated GIF) only as a download. So a video goes into the report inside an
HTML page of its own, embedded as a data: URL (the single-file report holds every file as one, so the page cannot
point at a file beside it).

Chromium loads an iframe's data: URL of at most 2 MiB (2,097,152 characters; longer ones leave the frame blank),
and the single-file report base64-encodes the page once more: a page of up to PAGE_LIMIT bytes, an MP4 of up to
about 1.1 MB, is what `snakemake --report report.html` can show. A zip report (`--report report.zip`) links the
page as a file and has no such limit."""

from __future__ import annotations

import base64
import html
from pathlib import Path

from .atomic import atomic_path

DATA_URL_LIMIT = 2 * 1024 * 1024  # characters of a data: URL Chromium navigates a frame to
# a page's bytes whose base64 data: URL fits, with room for Snakemake's "data:text/html;charset=utf8;filename=...;"
# (a file name has at most 255 bytes)
PAGE_LIMIT = (DATA_URL_LIMIT - 512) * 3 // 4

_PAGE = """<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>{title}</title>
<style>body {{ margin: 0; padding: 12px; font: 14px sans-serif; color: #e2e8f0; background: #0f172a; }}
video, img {{ max-width: 100%; display: block; }} p {{ margin: 8px 0 0; }}</style></head>
<body>{media}
<p><strong>{title}</strong></p>{lines}</body></html>
"""


# what a page embeds a video file as, by its suffix: the gallery writes an MP4, or a GIF where no ffmpeg installs
_ELEMENTS = {
    ".mp4": '<video controls muted loop autoplay playsinline src="data:video/mp4;base64,{data}"></video>',
    ".gif": '<img alt="episode" src="data:image/gif;base64,{data}">',
}


def page(video_bytes: bytes, title: str, lines: tuple[str, ...] = (), suffix: str = ".mp4") -> str:
    """The page's HTML: the video (an H.264 MP4, or an animated GIF with ``suffix`` ".gif"), then ``title`` and
    each of ``lines`` as text under it."""
    if suffix not in _ELEMENTS:
        raise ValueError(f"a video page embeds {sorted(_ELEMENTS)}, not {suffix!r}")
    media = _ELEMENTS[suffix].format(data=base64.b64encode(video_bytes).decode("ascii"))
    return _PAGE.format(title=html.escape(title), media=media,
                        lines="".join(f"<p>{html.escape(line)}</p>" for line in lines))


def write(video, out, title: str, lines: tuple[str, ...] = ()) -> int:
    """Write the page of the video file ``video`` (H.264 MP4 or GIF) to ``out`` (atomically); its size in bytes. A
    page the single-file report could not show is an error naming the video and what to change, not a blank frame in
    the report."""
    video = Path(video)
    text = page(video.read_bytes(), title, lines, video.suffix)
    size = len(text.encode("utf-8"))
    if size > PAGE_LIMIT:
        raise ValueError(f"{video}: its report page would be {size} bytes, over the {PAGE_LIMIT} a single-file "
                         "Snakemake report can show in Chromium (a frame's data: URL of at most 2 MiB); make the "
                         "video smaller (fewer frames, a lower resolution or bitrate)")
    with atomic_path(out) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return size
