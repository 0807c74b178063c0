"""
Two table directives of the sb3-trlsd pages.

``.. pipe-table::`` with a Markdown pipe table as its content (or ``.. pipe-table:: FILE``, a file of one,
as ``sb3-trlsd claims --out`` writes it): tables stay readable in the page's source and in a terminal, the
way the commands print them; each cell is inline reST.

``.. results-table:: results/protocols/no-restarts/fig5.json``: a figure's results as a table, read from the
JSON that ``sb3-trlsd reproduce`` wrote, formatted as ``reproduce`` prints them (mean ± standard error, one
row per method). The numbers on the pages are the files' numbers: no copy to drift.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from docutils import nodes
from docutils.parsers.rst import directives
from sphinx.util.docutils import SphinxDirective


def cell(value: Any) -> str:
    if isinstance(value, Mapping) and {"mean", "se"} <= set(value):
        return f"{value['mean']:.3f} ± {value['se']:.3f}"
    if isinstance(value, float):
        return f"{value:.3g}"
    return str(value)


def flatten(entry: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    flat: dict[str, Any] = {}
    for key, value in entry.items():
        name = f"{prefix} {key}".strip()
        if isinstance(value, Mapping) and not {"mean", "se"} <= set(value) <= {"mean", "se", "se_runs"}:
            flat.update(flatten(value, name))
        else:
            flat[name] = value
    return flat


def results_rows(data: Mapping[str, Any], columns: list[str] | None) -> tuple[list[str], list[list[str]]]:
    results = data["results"]
    if not all(isinstance(entry, Mapping) for entry in results.values()):
        results = {data["figure"]: results}  # a single run's aggregates (Figures 2-4)
    rows = {label: flatten(entry) for label, entry in results.items()}
    names = columns or list(dict.fromkeys(column for row in rows.values() for column in row))
    header = ["method", *(name.replace("_", " ") for name in names)]
    body = [[label, *(cell(row.get(name, "")) for name in names)] for label, row in rows.items()]
    return header, body


class ResultsTable(SphinxDirective):
    required_arguments = 1
    option_spec = {"columns": directives.unchanged, "caption": directives.unchanged}

    def run(self) -> list[nodes.Node]:
        path = Path(self.env.srcdir) / self.arguments[0]
        self.env.note_dependency(str(path))
        columns = (
            [c.strip() for c in self.options["columns"].split(";")] if "columns" in self.options else None
        )
        header, body = results_rows(json.loads(path.read_text()), columns)
        table = table_node(
            [[nodes.Text(c)] for c in header], [[[nodes.Text(c)] for c in row] for row in body]
        )
        if "caption" in self.options:
            table.insert(0, nodes.title(text=self.options["caption"]))
        return [table]


def split_row(line: str) -> list[str]:
    """``| a | b \\| c |`` -> ["a", "b | c"]: cells split on the pipes not escaped."""
    cells, current, escaped = [], "", False
    for char in line.strip()[1:]:
        if escaped:
            current += char if char == "|" else "\\" + char
            escaped = False
        elif char == "\\":
            escaped = True
        elif char == "|":
            cells.append(current.strip())
            current = ""
        else:
            current += char
    return cells


def table_node(header: list, body: list[list]) -> nodes.table:
    """A docutils table of ``header`` and ``body`` rows, each cell a list of inline nodes."""
    table = nodes.table()
    group = nodes.tgroup(cols=len(header))
    table += group
    group.extend(nodes.colspec(colwidth=1) for _ in header)
    for part, rows in ((nodes.thead(), [header]), (nodes.tbody(), body)):
        for values in rows:
            row = nodes.row()
            for value in values:
                row += nodes.entry("", nodes.paragraph("", "", *value))
            part += row
        group += part
    return table


class PipeTable(SphinxDirective):
    optional_arguments = 1
    has_content = True

    def run(self) -> list[nodes.Node]:
        if self.arguments:
            path = Path(self.env.srcdir) / self.arguments[0]
            self.env.note_dependency(str(path))
            lines = path.read_text().splitlines()
        else:
            lines = list(self.content)
        rows = [split_row(line) for line in lines if line.strip().startswith("|")]
        rows = [row for row in rows if not all(set(cell) <= set("-: ") and cell for cell in row)]
        if len(rows) < 2 or any(len(row) != len(rows[0]) for row in rows):
            raise self.error("pipe-table: a header row and rows of as many cells are needed")
        messages: list[nodes.Node] = []

        def inline(text: str) -> list[nodes.Node]:
            parsed, problems = self.state.inline_text(text, self.lineno)
            messages.extend(problems)
            return parsed

        table = table_node([inline(c) for c in rows[0]], [[inline(c) for c in row] for row in rows[1:]])
        return [table, *messages]


def markdown_sections(app: Any, what: str, name: str, obj: Any, options: Any, lines: list[str]) -> None:
    """
    The envs' class docstrings follow Gymnasium's (Markdown sections: ``## Description``, ``## Arguments``,
    ...): each section title becomes a rubric, followed by the blank line reST wants before a list.
    """
    for index in reversed(range(len(lines))):
        if lines[index].startswith("## "):
            lines[index : index + 1] = [f".. rubric:: {lines[index][3:].strip()}", ""]


def setup(app: Any) -> dict[str, Any]:
    app.add_directive("results-table", ResultsTable)
    app.add_directive("pipe-table", PipeTable)
    app.connect("autodoc-process-docstring", markdown_sections)
    return {"parallel_read_safe": True, "parallel_write_safe": True}
