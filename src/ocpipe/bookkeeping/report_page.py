"""What Snakemake's HTML report (`snakemake --report report.html TARGET`) shows of a run beyond its files: where
each item sits in the report's menu, and two reStructuredText directives for its landing page
(workflow/report/workflow.rst) and its items' captions (workflow/report/*.rst).

Snakemake renders those pages with Jinja, which sees the config but no file, then with docutils, in its own process
after the Snakefile has run; the Snakefile registers the directives, so a page can show

- ``.. ocpipe-table:: results/tables/table5_1.md``: one of the study's Markdown tables (title, table and the line
  under it naming the profile and the recipe's departures; every table of a file of several), or, where the file is
  not there, its ``:missing:`` text;
- ``.. ocpipe-commit::``: the commit of the workflow's checkout, marked where its working tree differs from it.

The menu: a category per kind (Tables, Figures; the gallery's videos and contact sheets under Gallery), and in it a
subcategory per group target (``group``), each item with one label naming its table or figure. One label only:
Snakemake turns a further label that takes two values, each on half of a subcategory's items, into a switch that
shows one of the two items, and a group may hold just two (figures 5.5 and 5.6).
"""

from __future__ import annotations

from pathlib import Path

from docutils import nodes
from docutils.parsers.rst import Directive, directives

from ..study import findings, registry
from .record import commit_of

SCOPE_NAMES = {"main": "Main job", "ablations": "Ablations", "stackcube": "StackCube"}
WHOLE_STUDY = "Whole study: all twelve findings, the run's compute"
LEVERS = "Levers: the recipe's candidates on the validation pool"
FIGURE_TITLES = {
    "fig5_1": "training loss and evaluation reward per method",
    "fig5_2": "episode length per method",
    "fig5_3": "failure counts per method",
    "fig5_5": "success rate by visual representation",
    "fig5_6": "failure distribution by loss weighting",
    "fig5_7": "StackCube sub-task funnel: grasp, lift, near target, success",
}


def group(scope: str) -> str:
    """The report's subcategory of a group target's tables, figures and findings: 'Main job: Tables 5.1-5.2'."""
    numbers = [registry.table_number(t) for t in registry.tables_in(scope)]
    return f"{SCOPE_NAMES[scope]}: Tables {numbers[0]}-{numbers[-1]}"


def table_group(table: str) -> str:
    return group(registry.TABLES[table].scope)


def table_label(table: str) -> dict[str, str]:
    return {"table": registry.TABLES[table].title.removeprefix("Table ")}


def _finding_ids(scope: str) -> str:
    ids = findings.SCOPES[scope]
    return f"{ids[0]}-{ids[-1]}"


def findings_group(scope: str) -> str:
    """``scope`` as findings.SCOPES names it: 'findings' (all twelve) or 'findings_main' (a group target's)."""
    return WHOLE_STUDY if scope == "findings" else group(scope.removeprefix("findings_"))


def findings_label(scope: str, two_builds: bool = False) -> dict[str, str]:
    what = "two builds side by side" if two_builds else "judged on this build"
    return {"table": f"findings {_finding_ids(scope)}, {what}"}


def figure_table(figure: str) -> str:
    return registry.SPATIAL_FIGURES_TABLE if figure in registry.SPATIAL_FIGURES else registry.FIGURES[figure].table


def figure_group(figure: str) -> str:
    return table_group(figure_table(figure))


def figure_label(figure: str) -> dict[str, str]:
    number = figure.removeprefix("fig").replace("_", ".")
    return {"figure": f"{number}: {FIGURE_TITLES[figure]} (Table {registry.table_number(figure_table(figure))}'s rows)"}


def read_markdown(path) -> list[tuple[str, object]]:
    """A Markdown file as the study's writers make one (ocpipe.study.report.markdown, the compute table, the two
    builds): blocks between blank lines, each ("table", (title, header, rows)) (the title from a bold line just
    above it, or "") or ("text", line); a malformed table is an error naming the file and line."""
    lines = Path(path).read_text().splitlines()
    blocks, start = [], 0
    for i, line in enumerate([*lines, ""]):
        if not line.strip():
            if i > start:
                blocks.append((start, lines[start:i]))
            start = i + 1
    out = []
    for first, block in blocks:
        if not block[0].startswith("|"):
            out.append(("text", " ".join(line.strip() for line in block)))
            continue
        if len(block) < 2 or not all(line.startswith("|") for line in block) or set(block[1]) - set("|-: "):
            raise ValueError(f"{path}, line {first + 1}: a table needs a header row, a '|---|' row and '|' rows only")
        header, *rows = [line.strip()[1:-1].strip().split(" | ") for line in block[:1] + block[2:]]
        for i, row in enumerate(rows):
            if len(row) != len(header):
                raise ValueError(f"{path}, line {first + 3 + i}: {len(row)} cells under a header of {len(header)}")
        title = ""
        if out and out[-1][0] == "text" and out[-1][1].startswith("**") and out[-1][1].endswith("**"):
            title = out.pop()[1][2:-2]
        out.append(("table", (title, header, rows)))
    return out


def _table(title: str, header: list[str], rows: list[list[str]]) -> nodes.table:
    cols = nodes.tgroup(cols=len(header))
    cols += [nodes.colspec(colwidth=1) for _ in header]

    def row(cells):
        out = nodes.row()
        out += [nodes.entry("", nodes.paragraph(text=cell)) for cell in cells]
        return out

    cols += nodes.thead("", row(header))
    cols += nodes.tbody("", *[row(r) for r in rows])
    # no column widths: the browser sizes each column by its text (a claim needs more room than a p-value)
    return nodes.table("", *([nodes.title(text=title)] if title else []), cols, classes=["colwidths-auto"])


def markdown_nodes(path) -> list[nodes.Node]:
    """The tables and lines of ``path`` as docutils nodes, every cell and line plain text (a claim's '<' or '*' is
    never markup), then the file's path."""
    out = []
    for kind, block in read_markdown(path):
        if kind == "table":
            out.append(_table(*block))
        elif block.startswith("**") and block.endswith("**"):
            out.append(nodes.paragraph("", "", nodes.strong(text=block[2:-2])))
        else:
            out.append(nodes.paragraph("", "", nodes.emphasis(text=block)))
    return [*out, nodes.paragraph("", "", nodes.literal(text=str(path)))]


class TableDirective(Directive):
    required_arguments = 1
    option_spec = {"missing": directives.unchanged}

    def run(self):
        path = Path(self.arguments[0])
        if path.is_file():
            return markdown_nodes(path)
        note = self.options.get("missing", "not built")
        return [nodes.paragraph("", "", nodes.literal(text=str(path)), nodes.Text(f": {note}"))]


class CommitDirective(Directive):
    checkout: Path = Path(".")  # set by register()

    def run(self):
        try:
            commit = commit_of(self.checkout)
        except FileNotFoundError:  # a copy outside git, or no git installed
            commit = f"unknown ({self.checkout} is not a git checkout)"
        return [nodes.paragraph("", "", nodes.Text("Report built by the workflow at commit "),
                                nodes.literal(text=commit), nodes.Text("."))]


def register(checkout) -> None:
    """Make ``ocpipe-table`` and ``ocpipe-commit`` (of the git checkout ``checkout``) known to docutils."""
    directives.register_directive("ocpipe-table", TableDirective)
    directives.register_directive("ocpipe-commit", type("Commit", (CommitDirective,), {"checkout": Path(checkout)}))
