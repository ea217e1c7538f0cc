"""Two independent builds of one recipe, side by side: the configured K policies (replicate_seed_offset) and the
next K (offset + K), trained on the same stores and evaluated on their own blocks of the test pool. Two checks:
no finding's claim is resolved one way in one build and the other way in the other, and each row's mean success
rate lies within the other build's 95 % interval."""

from __future__ import annotations

import polars as pl

from .. import paths
from ..config.errors import ConfigError
from ..config.seed_pools import policies_drawn, pool_problems
from ..stats import by_policy
from ..util.atomic import atomic_path
from . import findings, registry, report, tables, targets
from .inputs import STABILITY
from .registry import TABLES


def second_build(config: dict) -> dict:
    """The config of the build after this one: the next K policies on the same stores."""
    return {**config, "replicate_seed_offset": config["replicate_seed_offset"] + config["replicates"]}


def _label(config: dict) -> str:
    first = config["replicate_seed_offset"]
    return f"policies {first}-{first + config['replicates'] - 1}"


def inputs(config: dict, scope: str) -> list[str]:
    """Every episode file both builds' findings of ``scope`` read; a test pool too small for the second build's
    blocks is named before anything trains."""
    problems = pool_problems(config["evaluation"], policies_drawn(second_build(config)))
    if problems:
        raise ConfigError(f"two builds: {problems[0].strip()}")
    out = targets.findings_inputs(config, scope)
    return out + [f for f in targets.findings_inputs(second_build(config), scope) if f not in out]


def _checks(config: dict, finding: findings.Finding, runs_dir) -> tuple[list, str]:
    rows = findings.by_experiment(report.table_rows(config, finding.table, finding.needs, runs_dir))
    reason = findings.not_run(finding, rows)
    if reason:
        return [], reason
    checks = finding.judge(rows)
    return checks, findings.verdict_of(checks, rows)


def compare_findings(config: dict, scope: str, runs_dir=paths.RUNS) -> pl.DataFrame:
    a, b = config, second_build(config)
    out = []
    for fid in findings.SCOPES[scope]:
        finding = findings.BY_ID[fid]
        (ca, va), (cb, vb) = _checks(a, finding, runs_dir), _checks(b, finding, runs_dir)
        # a finding judged in both builds has the same checks in the same order; one not run has none
        pairs = zip(ca, cb, strict=True) if ca and cb else ()
        both_ways = any({x.outcome, y.outcome} == {"holds", "violated"} for x, y in pairs)
        p = [findings.finding_p(cs) for cs in (ca, cb)]
        out.append({"Finding": fid, "Claim": finding.claim, f"Verdict, {_label(a)}": va, f"p, {_label(a)}": p[0],
                    f"Verdict, {_label(b)}": vb, f"p, {_label(b)}": p[1],
                    "Resolved both ways": "yes" if both_ways else "no"})
    return pl.DataFrame(out, infer_schema_length=None)


def _summary(config: dict, table: str, runs_dir) -> dict[str, dict]:
    return {r.label: tables.stability_summary(r.data[STABILITY])
            for r in report.table_rows(config, table, (STABILITY,), runs_dir) if r.status is None}


def compare_rows(config: dict, scope: str, runs_dir=paths.RUNS) -> pl.DataFrame:
    """Each row of the scope's success-rate tables: both builds' mean and 95 % interval over policies (SD floored at
    one policy's episode noise), whether each mean lies within the other's interval, and Welch's two-sided test of
    the two means over their policies. The interval check is the stricter: even two builds of one recipe miss it
    now and then (at K = 5, a mean falls outside the other build's 95 % interval about 1 time in 8), while the
    test's p is calibrated."""
    a, b = config, second_build(config)
    out = []
    for table in dict.fromkeys(findings.BY_ID[f].table for f in findings.SCOPES[scope]):
        if STABILITY not in TABLES[table].needs:
            continue
        sa, sb = _summary(a, table, runs_dir), _summary(b, table, runs_dir)
        for label in sa:
            x, y = sa[label], sb[label]
            if x["policies"] < 2:
                raise ValueError("comparing builds needs an interval over policies: config `replicates` >= 2")
            out.append({"Table": registry.table_number(table), "Method": label,
                        f"SR mean, {_label(a)}": x["sr_mean"], "95 % low A": x["sr_low"], "95 % high A": x["sr_high"],
                        f"SR mean, {_label(b)}": y["sr_mean"], "95 % low B": y["sr_low"], "95 % high B": y["sr_high"],
                        "A within B's interval": "yes" if y["sr_low"] <= x["sr_mean"] <= y["sr_high"] else "no",
                        "B within A's interval": "yes" if x["sr_low"] <= y["sr_mean"] <= x["sr_high"] else "no",
                        "p (Welch, two-sided)": _p_apart(x, y)})
    return pl.DataFrame(out, infer_schema_length=None)


def _p_apart(x: dict, y: dict) -> float | None:
    if any(n == 0 for _, n in x["policy_counts"] + y["policy_counts"]):
        return None  # a policy whose every success was trivial has no rate
    w = by_policy.Welch.of(*(by_policy.PolicyValues.of_counts(s["policy_counts"]) for s in (x, y)))
    return min(1.0, 2 * min(w.p_below(), w.p_above()))


def write(config: dict, scope: str, csv_path, rows_csv_path, md_path, runs_dir=paths.RUNS) -> tuple[bool, bool]:
    """Both comparisons, as CSVs and one Markdown page; returns (no finding resolved both ways, every mean within
    the other build's interval)."""
    f, r = compare_findings(config, scope, runs_dir), compare_rows(config, scope, runs_dir)
    tables.write_csv(f, csv_path)
    tables.write_csv(r, rows_csv_path)
    agree = (f["Resolved both ways"] == "no").all()
    within = r.is_empty() or ((r["A within B's interval"] == "yes") & (r["B within A's interval"] == "yes")).all()
    a, b = _label(config), _label(second_build(config))
    text = (report.markdown(f, f"Two builds of one recipe: {a} and {b}", "Pass when no claim is resolved one way "
                            f"in one build and the other way in the other: {'pass' if agree else 'FAIL'}.")
            + "\n" + report.markdown(r, "Each row's mean success rate against the other build's 95 % interval",
                                     f"Pass when every mean lies within the other's interval: "
                                     f"{'pass' if within else 'FAIL'}."))
    with atomic_path(md_path) as tmp:
        tmp.write_text(text)
    return bool(agree), bool(within)
