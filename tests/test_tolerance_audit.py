"""Every numeric comparison and every file compared byte for byte in tests/ says which kind it is (tests/tolerances.py):
exact by construction, exact on one CPU kind only, or a tolerance derived from epsilon and the problem size."""

from conftest import REPO
from tolerances import EPS32, EPS64, audit, audit_tree, gamma, reduction_atol


def test_every_comparison_in_the_tests_names_its_kind():
    untagged = [f"{name}:{line} ({what})" for name, rows in audit_tree(REPO / "tests").items()
                for line, what, kind in rows if kind is None]
    assert not untagged, ("comparisons without an 'exact:', 'one-cpu:' or 'derived:' tag (tests/tolerances.py says "
                          "which is which):\n" + "\n".join(untagged))


def test_the_audit_finds_calls_files_and_tags_above_or_beside():
    source = '''
def test_x(a, b, path, other):
    np.testing.assert_allclose(a, b, atol=1e-6)
    # derived: why
    torch.testing.assert_close(
        a, b)
    assert path.read_bytes() == other.read_bytes()  # one-cpu: same machine
    assert a == pytest.approx(0.1)  # exact: a decimal
    assert a == 1  # a plain comparison of values is not a tolerance
    assert abs(a - b) < 1e-3  # not exact: a clause must open with its kind
    assert stats.equal(a, b) and torch.equal(a, b)  # a project function that shares torch's name is no comparison
    assert frame.equals(other) and np.allclose(a, b)  # exact: copies; derived: two kinds, in order
    assert np.isclose(a, b) and np.isclose(b, a)  # derived: the last tag stands for the rest
    assert np.linalg.norm(a - b) < 2.0 and len(a) < 3  # derived: a radius; a count is no gap
    while not np.allclose(a, b):  # one-cpu: a loop's header line stands alone
        a = b  # exact: not the header's
'''
    rows = audit(source)
    assert [(line, what) for line, what, _ in rows] == [
        (3, "assert_allclose"), (5, "assert_close"), (7, "file =="), (8, "approx"), (10, "gap <"),
        (11, "equal"), (12, "equals"), (12, "allclose"), (13, "isclose"), (13, "isclose"), (14, "gap <"),
        (15, "allclose")]
    assert [kind for *_, kind in rows] == [None, "derived", "one-cpu", "exact", None, None, "exact", "derived",
                                           "derived", "derived", "derived", "one-cpu"]


def test_the_derived_bound_grows_with_the_sum_and_holds_for_a_real_one():
    assert gamma(10) == 10 * EPS64 / (1 - 10 * EPS64)
    assert reduction_atol(128, 1.0, depth=2) == 2 * reduction_atol(128, 1.0)
    assert reduction_atol(128, 1.0, eps=EPS32) > 1e8 * reduction_atol(128, 1.0)
    import numpy as np

    x = np.random.default_rng(0).uniform(-1, 1, 1000).astype(np.float32)
    forward, backward = np.float32(0), np.float32(0)
    for v in x:
        forward += v
    for v in x[::-1]:
        backward += v
    assert abs(float(forward) - float(backward)) <= reduction_atol(1000, 1.0, eps=EPS32)  # derived: under test
    assert abs(float(forward) - float(x.astype(np.float64).sum())) > 0  # float32 sums do round: the bound is not idle
