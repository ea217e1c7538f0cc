"""Assembling tables and figures from the files under results/runs/{exp}/ (the evaluation rules' outputs)."""

from __future__ import annotations

import polars as pl

from .. import paths
from ..config import replicates
from ..config.experiments import resolve
from ..encoders.registry import tokens_per_camera
from ..paths import split_policy
from ..stats import by_policy, pooled
from ..util.atomic import atomic_path
from . import conditions, figures, findings, registry, tables, targets
from .inputs import FAILURES, STABILITY, SWEEP, TRAIN_LOG
from .registry import FIGURES, SPATIAL_FIGURES_NEEDS, SPATIAL_FIGURES_TABLE, TABLES


def _cell(v) -> str:
    """Floats to 3 decimals, but a small non-zero one (a p-value) in scientific notation rather than as 0.000."""
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.1e}" if 0 < abs(v) < 5e-4 else f"{v:.3f}"
    return str(v)


def markdown(table: pl.DataFrame, title: str, footer: str = "") -> str:
    lines = [f"**{title}**", "", "| " + " | ".join(table.columns) + " |", "|" + "---|" * len(table.columns)]
    lines += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in table.iter_rows()]
    return "\n".join(lines + ([f"\n{footer}"] if footer else [])) + "\n"


def write(table: pl.DataFrame, csv_path, md_path, title: str, footer: str = "") -> pl.DataFrame:
    tables.write_csv(table, csv_path)
    with atomic_path(md_path) as tmp:
        tmp.write_text(markdown(table, title, footer))
    return table


def table_rows(config: dict, table: str, needs=None, runs_dir=paths.RUNS) -> list[tables.Row]:
    """The rows of a table (or of a figure drawing a table's rows), each with the artefacts of its K policies."""
    skip = targets.unavailable(config, table)
    out = []
    for label, exp in targets.rows(config, table).items():
        policy = resolve(config, exp)
        tokens = len(policy["cameras"]) * tokens_per_camera(policy["encoder"], config["encoders"])
        pids = targets.policies(config, exp, table)
        row = tables.Row(label, policy, exp=exp, status=skip.get(label), visual_tokens=tokens, policies=len(pids))
        if row.status is None:
            row.data = {need: need.load({split_policy(pid)[1]: need.files(config, pid, runs_dir) for pid in pids})
                        for need in (TABLES[table].needs if needs is None else needs)}
        out.append(row)
    return out


def write_table(config: dict, table: str, csv_path, md_path, runs_dir=paths.RUNS) -> pl.DataFrame:
    spec, rows = TABLES[table], table_rows(config, table, runs_dir=runs_dir)
    if spec.columns is None:
        frame = tables.table5_2({r.label: r.data[FAILURES] for r in rows if r.status is None}, spec.always_classes)
    else:
        frame = tables.build(spec.columns, rows)
    return write(frame, csv_path, md_path, spec.title, conditions.footer(config, table))


def _tests_note(config: dict, scope: str) -> str:
    """How the findings of ``scope`` are tested, by the number of policies their tables' rows are."""
    by_k: dict[int, list[str]] = {}
    for table in dict.fromkeys(findings.BY_ID[f].table for f in findings.SCOPES[scope]):
        by_k.setdefault(replicates.of_table(config, table), []).append(table)
    by_k = dict(sorted(by_k.items(), reverse=True))
    parts = []
    replicated = [k for k in by_k if k > 1]
    if replicated:
        per_row = (f"{replicated[0]} policies per row, each trained with its own seed" if len(by_k) == 1 else
                   "Policies per row, each trained with its own seed: " + ", ".join(
                       f"{k} ({', '.join(f'Table {registry.table_number(t)}' for t in ts)})" for k, ts in by_k.items()))
        parts.append(
            f"{per_row} (config `replicates`, `table_replicates`); the trained policy is the unit. Order claims: "
            "Welch's t on the per-policy rates (floored at one policy's binomial noise), lengths and rewards; 'about "
            f"the same': equivalence (TOST), 'at most': non-inferiority, each within ±{100 * by_policy.MARGIN:.0f} "
            "points. Resolvable: the smallest true gap (for 'about the same', the narrowest margin) the test finds at "
            "80 % power with this run's spread and policy counts")
    if 1 in by_k:
        parts.append(
            "One policy per row: its episodes show episode noise only, not how far another training seed would move "
            "the row, so these p-values are too small (config `replicates`). SR: Fisher's exact test on success "
            "counts pooled over the stability runs; lengths and rewards: Mann-Whitney U; shares: Fisher or binomial")
    return ". ".join(parts)


def write_findings(config: dict, scope: str, csv_path, md_path, runs_dir=paths.RUNS) -> pl.DataFrame:
    """The findings of ``scope`` (findings.SCOPES), each judged on the episode files its table reads."""
    out = []
    for fid in findings.SCOPES[scope]:
        finding = findings.BY_ID[fid]
        out.append(findings.judge(finding, findings.by_experiment(table_rows(config, finding.table, finding.needs,
                                                                             runs_dir))))
    frame = pl.DataFrame(out, infer_schema_length=None)
    note = (f"Profile {config.get('profile', '?')}. {_tests_note(config, scope)}. p: the largest p-value of the "
            "claims that must resolve (with one policy, the order claims); "
            f"reproduced = every claim resolved at p < {pooled.ALPHA}; 'not contradicted' = an 'about the same' or "
            "'at most' claim the test could neither show nor reject.")
    return write(frame, csv_path, md_path, "Findings of the study, judged on this build", note)


def write_figure(config: dict, figure: str, out_png, runs_dir=paths.RUNS) -> None:
    spec = FIGURES[figure]
    rows = table_rows(config, spec.table, spec.needs, runs_dir)
    spec.draw(rows, out_png)


def write_figures5_1_to_5_3(config: dict, fig5_1, fig5_2, fig5_3, runs_dir=paths.RUNS) -> None:
    rows = [r for r in table_rows(config, SPATIAL_FIGURES_TABLE, SPATIAL_FIGURES_NEEDS, runs_dir) if r.status is None]
    figures.fig5_1({r.label: r.data[TRAIN_LOG] for r in rows}, {r.label: r.data[SWEEP] for r in rows}, fig5_1)
    figures.fig5_2({r.label: r.data[STABILITY] for r in rows}, fig5_2)
    figures.fig5_3({r.label: r.data[FAILURES] for r in rows}, fig5_3)
