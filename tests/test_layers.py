"""The packages' layering: the stages never import the study's reporting or the run bookkeeping above them, the
study never imports the bookkeeping, and the statistics import nothing of ocpipe, so evaluation can use them."""

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "ocpipe"
# each package and the ocpipe packages it must never import
FORBIDDEN = {
    **{stage: {"study", "bookkeeping", "cli"}
       for stage in ("util", "sim", "config", "demos", "frames", "encoders", "features", "policy", "evaluation")},
    "stats": {p.stem if p.is_file() else p.name for p in PACKAGE.iterdir() if p.name not in ("__pycache__",
                                                                                           "__init__.py", "stats")},
    "study": {"bookkeeping", "cli"},
    "bookkeeping": {"cli"},
}


def imported_packages(package: str) -> dict[str, set[str]]:
    """Module -> the top-level ocpipe packages it imports (relative or absolute)."""
    out = {}
    for f in sorted((PACKAGE / package).rglob("*.py")):
        depth = len(f.relative_to(PACKAGE).parts) - 1  # folders between ocpipe and the module
        found = set()
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level:
                inside = list(f.relative_to(PACKAGE).parts[:-1])[: depth - (node.level - 1)]
                parts = inside + (node.module.split(".") if node.module else [])
                found |= {parts[0]} if parts else {alias.name for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("ocpipe."):
                found.add(node.module.split(".")[1])
            elif isinstance(node, ast.ImportFrom) and node.module == "ocpipe":  # from ocpipe import study
                found |= {alias.name for alias in node.names}
            elif isinstance(node, ast.Import):
                found |= {a.name.split(".")[1] for a in node.names if a.name.startswith("ocpipe.")}
        out[str(f.relative_to(PACKAGE))] = found - {package}
    return out


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_no_package_imports_one_above_it(package):
    reached = {module: sorted(found & FORBIDDEN[package]) for module, found in imported_packages(package).items()}
    assert not {m: f for m, f in reached.items() if f}, f"{package} imports from above it"


def test_the_import_reader_sees_every_form_of_import(tmp_path, monkeypatch):
    pkg = tmp_path / "evaluation"
    pkg.mkdir()
    forms = {"a.py": "from ocpipe import study", "b.py": "import ocpipe.study.tables", "c.py": "from .. import study",
             "d.py": "from ..study import tables", "e.py": "from ocpipe.study import tables"}
    for name, line in forms.items():
        (pkg / name).write_text(line + "\n")
    monkeypatch.setitem(globals(), "PACKAGE", tmp_path)
    assert imported_packages("evaluation") == {f"evaluation/{n}": {"study"} for n in forms}


def test_the_import_reader_sees_relative_and_absolute_imports():
    found = imported_packages("evaluation")
    assert "stats" in found["evaluation/best.py"] and "policy" in found["evaluation/closed_loop.py"]
    assert "study" in imported_packages("bookkeeping")["bookkeeping/compute.py"]
