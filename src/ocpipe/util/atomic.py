"""Write-then-rename helpers, so a killed job never leaves an artifact that looks complete."""

from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
from pathlib import Path


def tmp_sibling(path: str | Path) -> Path:
    path = Path(path)
    # keep the suffix last: some writers (ManiSkill, matplotlib) choose the format from it
    return path.with_name(f".tmp-{os.getpid()}-{path.name}")


class DiskFull(OSError):
    """The disk filled up while an artifact was written; the message names it (errno stays ENOSPC)."""


@contextlib.contextmanager
def atomic_path(path: str | Path):
    """Yield a temporary sibling of ``path`` (file or directory) to write; rename it onto ``path`` on success."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = tmp_sibling(path)
    _remove(tmp)
    try:
        yield tmp
        _remove(path)
        os.replace(tmp, path)
    except DiskFull:
        raise
    except OSError as exc:
        if exc.errno in (errno.ENOSPC, errno.EDQUOT) or "No space left on device" in str(exc):
            raise DiskFull(errno.ENOSPC, f"No space left on device while writing {path}; its partial temporary "
                           "copy was removed and nothing was written there: free space (or move results/ to a "
                           "bigger disk) and rerun") from exc
        raise
    finally:
        _remove(tmp)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    elif path.exists() or path.is_symlink():
        path.unlink()


def write_json(path: str | Path, data) -> None:
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(data, indent=2, sort_keys=False) + "\n")
