"""The documentation points at what exists: every relative link in README.md and docs/ reaches a file (and, with an
anchor, one of that file's headings as GitHub names them), and every `ocpipe <command>` the docs show in code is a
subcommand the CLI has."""

import argparse
import re
from pathlib import Path
from urllib.parse import unquote

from conftest import REPO

from ocpipe import cli

DOCS = [REPO / "README.md", *sorted((REPO / "docs").rglob("*.md"))]

# an opening or closing fence: up to three spaces of indent, then three or more backticks or tildes
FENCE = re.compile(r" {0,3}(`{3,}|~{3,})")
CODE_SPAN = re.compile(r"(?<!`)(`+)(?!`)(.+?)(?<!`)\1(?!`)", re.S)
LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r" {0,3}#{1,6}\s+(.*?)(?:\s+#+)?\s*$")
HTML_ANCHOR = re.compile(r"<a\s+(?:name|id)=\"([^\"]+)\"")
# links with a scheme (https:, mailto:, ...) leave the repository: nothing here can say whether they resolve
EXTERNAL = re.compile(r"[A-Za-z][A-Za-z0-9+.-]*:")
# GitHub shows a code file's lines at #L12 or #L12-L20
LINE_ANCHOR = re.compile(r"L\d+(-L\d+)?")
# `ocpipe X` where a shell would run it: at the start of the code, after a prompt or an operator, or after `time`,
# with or without a path (.venv/bin/ocpipe); "Snakemake object -> ocpipe call" in a layout map names no command
COMMAND = re.compile(r"(?:^|&&|\|\||[;|(`]|\btime\b)\s*(?:\$\s+)?(?:[\w.~/-]*/)?ocpipe\s+([A-Za-z][\w-]*)", re.M)


def split_code(text: str) -> tuple[str, list[tuple[int, str]]]:
    """The prose of a Markdown text with its fenced code blocks blanked (so line numbers still hold), and the blocks'
    lines with their numbers."""
    prose, code, fence = [], [], None
    for number, line in enumerate(text.splitlines(), 1):
        marker = FENCE.match(line)
        if fence is None and marker:
            fence = marker.group(1)
        elif fence is not None and marker and set(line.strip()) == {fence[0]} and len(line.strip()) >= len(fence):
            fence = None
        elif fence is not None:
            code.append((number, line))
        else:
            prose.append(line)
            continue
        prose.append("")
    return "\n".join(prose), code


def code_spans(prose: str) -> list[tuple[int, str]]:
    """Each inline code span of the prose with the line it starts on."""
    return [(prose.count("\n", 0, m.start()) + 1, m.group(2)) for m in CODE_SPAN.finditer(prose)]


def without_code_spans(prose: str) -> str:
    """The prose with each code span blanked (newlines kept): a link written in code is no link."""
    return CODE_SPAN.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), prose)


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading: its text lowercased, punctuation dropped but for hyphens (and underscores,
    which GitHub counts as word characters), each space a hyphen."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link in a heading contributes its text
    text = re.sub(r"<[^>]+>", "", text).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """The anchors of a Markdown file: its headings' slugs, a repeated slug numbered as GitHub numbers it
    (-1, -2, ...), and any explicit <a name/id>."""
    prose, _ = split_code(path.read_text())
    found, seen = set(), {}
    for line in prose.splitlines():
        heading = HEADING.match(line)
        if heading:
            slug = github_slug(heading.group(1))
            found.add(f"{slug}-{seen[slug]}" if slug in seen else slug)
            seen[slug] = seen.get(slug, 0) + 1
    return found | set(HTML_ANCHOR.findall(prose))


def links(path: Path) -> list[tuple[int, str]]:
    """Each link target of a Markdown file with its line, leaving out links written inside code."""
    prose = without_code_spans(split_code(path.read_text())[0])
    return [(prose.count("\n", 0, m.start()) + 1, m.group(1)) for m in LINK.finditer(prose)]


def _shown(path: Path, root: Path) -> str:
    return str(path.relative_to(root)) if path.is_relative_to(root) else str(path)


def link_problems(doc: Path, root: Path = REPO) -> list[str]:
    """'file:line: link: reason' for every relative link of doc that does not reach a file or heading."""
    problems = []
    for line, target in links(doc):
        if EXTERNAL.match(target):
            continue
        file_part, _, anchor = target.partition("#")
        # a leading slash is the repository's root on GitHub, not the file system's
        base = root if file_part.startswith("/") else doc.parent
        dest = (base / unquote(file_part.lstrip("/"))).resolve() if file_part else doc
        reason = None
        if not dest.is_relative_to(root.resolve()):
            reason = "points outside the repository"
        elif not dest.exists():
            reason = f"no such file: {_shown(dest, root.resolve())}"
        elif anchor and dest.is_dir():
            reason = "an anchor on a folder"
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            reason = f"no heading with anchor #{anchor} in {_shown(dest, root.resolve())}"
        elif anchor and dest.suffix != ".md" and not LINE_ANCHOR.fullmatch(anchor):
            reason = f"#{anchor} in a file that is not Markdown"
        if reason:
            problems.append(f"{_shown(doc, root)}:{line}: {target}: {reason}")
    return problems


def commands_named(doc: Path) -> list[tuple[int, str]]:
    """Each `ocpipe <command>` doc shows in a code span or code block, with its line."""
    prose, code = split_code(doc.read_text())
    return [(line, m.group(1)) for line, text in code_spans(prose) + code for m in COMMAND.finditer(text)]


def cli_commands() -> set[str]:
    """The subcommands the `ocpipe` parser accepts, read from the parser itself so that a new command needs no edit
    here."""
    return {name for action in cli.parser()._actions if isinstance(action, argparse._SubParsersAction)
            for name in action.choices}


def command_problems(doc: Path, known: set[str], root: Path = REPO) -> list[str]:
    return [f"{_shown(doc, root)}:{line}: ocpipe {name}: not an ocpipe command (it has: {', '.join(sorted(known))})"
            for line, name in commands_named(doc) if name not in known]


def test_every_relative_link_reaches_a_file_and_heading():
    problems = [problem for doc in DOCS for problem in link_problems(doc)]
    assert not problems, "broken links in the docs:\n" + "\n".join(problems)


def test_every_ocpipe_command_in_the_docs_is_one_the_cli_has():
    known = cli_commands()
    assert {"summary", "record"} <= known  # the parser was read: an empty set would pass every doc
    problems = [problem for doc in DOCS for problem in command_problems(doc, known)]
    assert not problems, "commands the CLI does not have:\n" + "\n".join(problems)


def test_slugs_follow_githubs_rules():
    assert github_slug("Numbers in the tests, on any x86-64 CPU") == "numbers-in-the-tests-on-any-x86-64-cpu"
    assert github_slug("How each table's variable reaches its rows") == "how-each-tables-variable-reaches-its-rows"
    assert github_slug("The `ocpipe` command") == "the-ocpipe-command"
    # punctuation goes but the spaces around it stay, so " / " leaves two hyphens
    assert github_slug("Quick start (Debian 12 / Ubuntu, Python 3.11)") == "quick-start-debian-12--ubuntu-python-311"


def test_the_checks_catch_a_missing_file_a_missing_heading_and_an_unknown_command(tmp_path):
    (tmp_path / "other.md").write_text("# Same heading\n\n## Same heading\n\n```\n# not a heading\n```\n")
    doc = tmp_path / "doc.md"
    doc.write_text(
        "[fine](other.md#same-heading-1) [gone](missing.md) [wrong anchor](other.md#not-a-heading)\n"
        "[web](https://example.org/x.md) [here](#a-title) [folder](.)\n"
        "# A title\n"
        "`[in code](missing.md)` `ocpipe summary results` `.venv/bin/ocpipe frobnicate` and ocpipe prose\n"
        "```bash\n"
        "[not a link](missing.md)\n"
        "ocpipe record results  # then `ocpipe unknown-too`\n"
        "Snakemake object -> ocpipe call\n"
        "```\n")
    assert link_problems(doc, root=tmp_path) == [
        "doc.md:1: missing.md: no such file: missing.md",
        # other.md has "# not a heading" only inside a code block
        "doc.md:1: other.md#not-a-heading: no heading with anchor #not-a-heading in other.md",
    ]
    assert commands_named(doc) == [(4, "summary"), (4, "frobnicate"), (7, "record"), (7, "unknown-too")]
    assert [p.split(":")[1] for p in command_problems(doc, {"summary", "record"}, root=tmp_path)] == ["4", "7"]
