"""How the tests compare numbers: every comparison in tests/ is one of three kinds, named by a tag that opens a
comment (or a '; '-separated clause of one) on its statement or in the comment lines just above it; a statement
with several comparisons takes its tags in order, the last tag standing for the rest. tests/test_tolerance_audit.py
fails on a comparison without one; `python tests/tolerances.py` prints the tally (-v: every comparison).

  exact:    equal by construction, so the comparison holds on every CPU: copies, integer or decimal-exact
            arithmetic, or the very same operations on the same inputs in one process (the bits themselves may
            differ between CPUs; both sides differ alike). Compared with == (a tolerance only where the expected
            side is written in decimal and so rounds, e.g. 0.1).
  one-cpu:  exact on one CPU kind only: two runs (processes, jobs, trainings) whose float kernels (vector width,
            FMA, thread split) decide the last bits, compared only where both ran on the same machine; what is
            stable across CPUs is compared apart (tests/golden.py).
  derived:  a tolerance that follows from what sets it: for round-off, the dtype's epsilon and the problem size
            (reduction_atol), in float64 wherever the test checks that two computations are the same function, so
            float32 round-off is no part of what it checks; for a physical or sampling margin, the quantity that
            sets it (a cube's half size, a sampling SD). Never a number fitted to the last failure.
"""

from __future__ import annotations

import ast
import io
import re
import sys
import tokenize
from collections import Counter
from pathlib import Path

import numpy as np

EPS64 = float(np.finfo(np.float64).eps)
EPS32 = float(np.finfo(np.float32).eps)
EPS16 = float(np.finfo(np.float16).eps)
KINDS = ("exact", "one-cpu", "derived")
TAG = re.compile(r"^\s*(exact|one-cpu|derived):")  # at the start of a comment or of a '; ' clause
# calls that compare numbers (by name, whatever module they come from)
COMPARING_CALLS = {"allclose", "assert_allclose", "assert_close", "approx", "isclose", "assert_array_equal",
                   "array_equal", "equal", "equals", "assert_frame_equal", "assert_series_equal",
                   "assert_array_almost_equal"}
ARRAY_MODULE_ONLY = {"equal", "array_equal"}
GAP_CALLS = {"abs", "norm", "ptp", "dist"}
READS_A_FILE = {"read_bytes", "read_text"}


def gamma(n: int, eps: float = EPS64) -> float:
    """Higham's gamma_n = n eps / (1 - n eps): the relative error bound of n chained floating-point operations."""
    if n * eps >= 1:
        raise ValueError(f"{n} operations at eps {eps} have no error bound")
    return n * eps / (1 - n * eps)


def reduction_atol(n: int, magnitude: float, depth: int = 1, eps: float = EPS64) -> float:
    """How far two evaluation orders of the same computation may differ: ``depth`` reductions in sequence, each a sum
    of ``n`` terms no larger than ``magnitude``. One such sum is off by at most gamma_(n-1) * sum|x_i| <= gamma_n *
    n * magnitude (Higham, Accuracy and Stability of Numerical Algorithms, 2002, eq. 4.4); two orders differ by
    twice that, and errors carried through later reductions add one such term per reduction. For one sum this is
    a bound; through a network (norms divide by a spread, weights scale) it is an estimate, which is why the
    float64 checks that use it sit some 1e5 below it and still many orders below any wrong answer."""
    return 2 * depth * gamma(n, eps) * n * magnitude


def decoder_atols(layers: int, shape: tuple[int, int, int], seq_max: float, out_max: float) -> tuple[float, float]:
    """(outputs, weight gradients): how far two float64 evaluation orders of the policy's decoder may differ, on a
    (B, L, W) sequence whose largest entry is ``seq_max``, of the loss sum(out^2) whose output's largest is
    ``out_max``. Each layer chains about six reductions (two norms, scores, softmax, values, feed-forward), the final
    norm one more, over at most max(4 W, L) terms. A weight's gradient sums, over the B x L rows, an activation (of
    the sequence's size, the norms keep it there) times an upstream gradient (of the size of the loss's own,
    2 |out|), after the backward pass has chained as many reductions again."""
    B, L, W = shape
    depth = 6 * layers + 1
    return (reduction_atol(max(4 * W, L), seq_max, depth=depth),
            reduction_atol(max(4 * W, B * L), seq_max * 2 * out_max, depth=2 * depth))


def mean_atol(n: int, magnitude: float, eps: float = EPS64) -> float:
    """reduction_atol for the mean of ``n`` terms no larger than ``magnitude`` (the sum's bound over n)."""
    return reduction_atol(n, magnitude, eps=eps) / n


# ---- the audit: find every comparison and its tag ------------------------------------------------------------------


def _called_name(call: ast.Call) -> str | None:
    f = call.func
    return f.attr if isinstance(f, ast.Attribute) else f.id if isinstance(f, ast.Name) else None


def _compares(call: ast.Call) -> bool:
    name = _called_name(call)
    if name in ARRAY_MODULE_ONLY:  # torch.equal or np.array_equal, not a function of the project's that shares a name
        f = call.func
        return isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) and f.value.id in ("torch", "np")
    return name in COMPARING_CALLS


def _reads_a_file(node: ast.AST) -> bool:
    return any(isinstance(n, ast.Call) and _called_name(n) in READS_A_FILE for n in ast.walk(node))


def comparisons(source: str) -> list[tuple[int, int, str]]:
    """(line, column, what) of every numeric comparison (a call in COMPARING_CALLS, or a gap written out by hand:
    abs(a - b) < tolerance, norm(...) <= radius) and every file compared with == or != (a golden or a rerun compared
    byte for byte) in a test module's source."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Call) and _compares(node):
            found.append((node.lineno, node.col_offset, _called_name(node)))
        elif isinstance(node, ast.Compare) and any(isinstance(op, (ast.Eq, ast.NotEq)) for op in node.ops) \
                and _reads_a_file(node):
            found.append((node.lineno, node.col_offset, "file =="))
        elif isinstance(node, ast.Compare) and any(isinstance(op, (ast.Lt, ast.LtE)) for op in node.ops) \
                and _measures_a_gap(node.left):
            found.append((node.lineno, node.col_offset, "gap <"))  # a tolerance written out by hand
    return sorted(set(found))


def _measures_a_gap(node: ast.AST) -> bool:
    """Whether an expression measures how far apart two things are: a difference, or abs, a norm, ptp, dist."""
    return any(isinstance(n, ast.BinOp) and isinstance(n.op, ast.Sub)
               or isinstance(n, ast.Call) and _called_name(n) in GAP_CALLS for n in ast.walk(node))


COMPOUND = (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.If, ast.For, ast.AsyncFor, ast.While, ast.With,
            ast.AsyncWith, ast.Try, ast.TryStar, ast.Match)


def _statements(tree: ast.AST) -> list[ast.stmt]:
    """The simple statements (a compound one's header line stands alone: see audit)."""
    return [n for n in ast.walk(tree) if isinstance(n, ast.stmt) and not isinstance(n, COMPOUND)]


def tags(comment: str) -> list[str]:
    """The kinds a comment names, in order: each clause (split at ';') that opens with 'exact:', 'one-cpu:' or
    'derived:' ('# not exact: ...' names none)."""
    return [m.group(1) for clause in comment.lstrip("#").split(";") for m in [TAG.match(clause)] if m]


def audit(source: str) -> list[tuple[int, str, str | None]]:
    """(line, what, kind) for each comparison in ``source``; kind None where no tag names it. Tags count on the
    lines of the smallest statement holding the comparison and in the comment lines right above it, in order."""
    comments = {}
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.COMMENT:
            comments[tok.start[0]] = tok.string
    lines = source.splitlines()
    statements = _statements(ast.parse(source))
    found = comparisons(source)

    def holding(line):
        inside = [s for s in statements if s.lineno <= line <= (s.end_lineno or s.lineno)]
        return min(inside, key=lambda s: (s.end_lineno or s.lineno) - s.lineno) if inside else None

    out = []
    for line, col, what in found:
        stmt = holding(line)
        first, last = (stmt.lineno, stmt.end_lineno or stmt.lineno) if stmt else (line, line)
        above = first
        while above > 1 and lines[above - 2].lstrip().startswith("#"):
            above -= 1
        named = [k for n in range(above, last + 1) if n in comments for k in tags(comments[n])]
        # in a compound statement's header (if, while, ...), the comparisons of that one line
        siblings = [(ln, c) for ln, c, _ in found if holding(ln) is stmt and (stmt is not None or ln == line)]
        i = siblings.index((line, col))
        out.append((line, what, named[min(i, len(named) - 1)] if named else None))
    return out


def audit_tree(tests: Path) -> dict[str, list[tuple[int, str, str | None]]]:
    return {p.name: audit(p.read_text()) for p in sorted(tests.glob("*.py")) if p.name != Path(__file__).name}


if __name__ == "__main__":
    found = audit_tree(Path(__file__).parent)
    tally = Counter(kind for rows in found.values() for _, _, kind in rows)
    if "-v" in sys.argv:
        for name, rows in found.items():
            for line, what, kind in rows:
                print(f"{name}:{line}\t{what}\t{kind or 'UNTAGGED'}")
    print(", ".join(f"{k}: {tally[k]}" for k in KINDS), f"(untagged: {tally[None]}, total {sum(tally.values())})")
