"""Assembling tables and figures from the files under results/runs/{exp}/ (the evaluation rules' outputs)."""

from __future__ import annotations

from pathlib import Path

import polars as pl

from . import figures, tables, taxonomy
from .atomic import atomic_path


def _read(files) -> pl.DataFrame:
    return pl.concat([pl.read_parquet(f) for f in files], how="vertical")


def _steps_file(episodes_file) -> Path:
    return Path(str(episodes_file).replace(".episodes.parquet", ".steps.parquet"))


def classify_episodes(episode_files, task: str, rules: dict, out_path) -> pl.DataFrame:
    episodes = _read(episode_files)
    steps = _read([_steps_file(f) for f in episode_files])
    classes = taxonomy.classify_run(episodes, steps, task, rules)
    with atomic_path(out_path) as tmp:
        classes.write_parquet(tmp)
    return classes


def _runs(exp: str, runs_dir) -> pl.DataFrame:
    files = sorted((Path(runs_dir) / exp / "stability").glob("run_*.episodes.parquet"))
    if not files:
        raise FileNotFoundError(f"no stability runs under {Path(runs_dir) / exp / 'stability'}")
    return _read(files)


def _markdown(table: pl.DataFrame, title: str) -> str:
    fmt = lambda v: f"{v:.3f}" if isinstance(v, float) else str(v)  # noqa: E731
    lines = [f"**{title}**", "", "| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns)]
    lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in table.iter_rows()]
    return "\n".join(lines) + "\n"


def _write(table: pl.DataFrame, csv_path, md_path, title: str) -> pl.DataFrame:
    tables.write_csv(table, csv_path)
    with atomic_path(md_path) as tmp:
        tmp.write_text(_markdown(table, title))
    return table


def write_table5_1(rows: dict[str, str], csv_path, md_path, runs_dir="results/runs") -> pl.DataFrame:
    table = tables.table5_1({label: _runs(exp, runs_dir) for label, exp in rows.items()})
    return _write(table, csv_path, md_path, "Table 5.1: spatial grounding (held-out SR, mean episode length)")


def write_table5_2(rows: dict[str, str], csv_path, md_path, runs_dir="results/runs") -> pl.DataFrame:
    table = tables.table5_2({label: pl.read_parquet(Path(runs_dir) / exp / "failures.parquet")
                             for label, exp in rows.items()})
    return _write(table, csv_path, md_path, "Table 5.2: failure distribution")


def write_figures5_1_to_5_3(rows: dict[str, str], fig5_1, fig5_2, fig5_3, runs_dir="results/runs") -> None:
    runs = Path(runs_dir)
    figures.fig5_1({m: pl.read_parquet(runs / e / "train_log.parquet") for m, e in rows.items()},
                   {m: _read(sorted((runs / e / "sweep").glob("epoch_*.episodes.parquet"))) for m, e in rows.items()},
                   fig5_1)
    figures.fig5_2({m: _runs(e, runs_dir) for m, e in rows.items()}, fig5_2)
    figures.fig5_3({m: pl.read_parquet(runs / e / "failures.parquet") for m, e in rows.items()}, fig5_3)
