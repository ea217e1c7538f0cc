"""A demo set on disk: a ManiSkill-format pair ``<name>.h5`` + ``<name>.json`` whose episodes are listed in the
json in numeric ``episode_id`` order, each with its ``episode_seed``. Reading and checking one, and the DemoError
that names a damaged or mismatched file (the demos and frames stages raise it)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import h5py


class DemoError(RuntimeError):
    pass


def pair_json(h5_path: str | Path) -> Path:
    """The .json of the demo set whose .h5 is ``h5_path``."""
    return Path(h5_path).with_suffix(".json")


def _regenerate(path: str | Path) -> str:
    """What to do about a damaged demo set (path: its .h5 or its .json)."""
    p = Path(path)
    return (
        f"delete {p.with_suffix('.h5').name} and {p.with_suffix('.json').name} and rerun the workflow to "
        "regenerate them (an imported demo set: copy it again from its source)"
    )


def episodes(json_path: str | Path) -> list[dict]:
    """The json's episodes sorted numerically by episode_id (h5 keys sort traj_0, traj_1, traj_10, ...)."""
    try:
        meta = json.loads(Path(json_path).read_text())
    except json.JSONDecodeError as exc:
        raise DemoError(
            f"{json_path}: not valid JSON ({exc}); the file is truncated or corrupt: {_regenerate(json_path)}"
        ) from exc
    if not isinstance(meta, dict) or not isinstance(meta.get("episodes"), list):
        raise DemoError(f"{json_path}: no 'episodes' list, so not a ManiSkill demo json: {_regenerate(json_path)}")
    eps = sorted(meta["episodes"], key=lambda e: int(e["episode_id"]))
    for ep in eps:
        if "episode_seed" not in ep:
            raise DemoError(f"{json_path}: episode {ep['episode_id']} has no episode_seed")
    return eps


def open_h5(path: str | Path) -> h5py.File:
    """Open a demo .h5 for reading; a truncated or corrupt file is a DemoError that names it."""
    try:
        return h5py.File(path, "r")
    except OSError as exc:
        raise DemoError(
            f"{path}: not a readable HDF5 file ({exc}); it is truncated or corrupt: {_regenerate(path)}"
        ) from exc


_TRAJ_KEY = re.compile(r"traj_(\d+)$")


def check_pair(h5_path: str | Path) -> list[dict]:
    """The episodes of the demo set ``<name>.h5`` + ``<name>.json`` after checking that the .h5 opens and holds
    exactly one ``traj_<id>`` per episode the .json lists (a pair from different runs, or a copy cut short, would
    otherwise lose or mix up episodes silently)."""
    h5_path = Path(h5_path)
    json_path = pair_json(h5_path)
    for p in (h5_path, json_path):
        if not p.is_file():
            raise DemoError(f"{p}: file not found; a demo set is a .h5 and a .json of the same name: {_regenerate(p)}")
    eps = episodes(json_path)
    with open_h5(h5_path) as h5:
        try:
            keys = {k for k in h5.keys() if _TRAJ_KEY.match(k)}
        except (OSError, KeyError, RuntimeError) as exc:
            raise DemoError(
                f"{h5_path}: its list of trajectories cannot be read ({exc}); the file is corrupt: "
                f"{_regenerate(h5_path)}"
            ) from exc
    listed = {f"traj_{ep['episode_id']}" for ep in eps}
    if keys != listed:

        def some(names):
            return ", ".join(sorted(names, key=lambda k: int(k[5:]))[:5]) + (" ..." if len(names) > 5 else "")

        parts = [f"the json lists {len(eps)} episodes, the h5 holds {len(keys)} trajectories"]
        if listed - keys:
            parts.append(f"missing from the h5: {some(listed - keys)}")
        if keys - listed:
            parts.append(f"not in the json: {some(keys - listed)}")
        raise DemoError(
            f"{h5_path} does not match {json_path} ({'; '.join(parts)}): the two files come from "
            f"different runs or one was cut short: {_regenerate(h5_path)}"
        )
    return eps


def unreadable_error(h5_path: str | Path, key: str, exc: Exception | None = None) -> DemoError:
    why = f" ({exc})" if exc is not None else ""
    return DemoError(
        f"{h5_path}: episode {key.removeprefix('traj_')} ({key}) cannot be read{why}; the file is "
        f"corrupt: {_regenerate(h5_path)}"
    )
