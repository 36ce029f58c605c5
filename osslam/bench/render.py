"""Tables as text: Markdown, CSV and LaTeX (a plain ``tabular``).

Markdown and LaTeX show ``mean ± std`` when a cell has more than one value; CSV keeps
numbers apart, adding a ``<column> std`` column after every column that has repeats.
"""

from __future__ import annotations

import csv
import io
import math

from .tables import Cell, Stat, Table

_LATEX_ESCAPES = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_",
                  "{": r"\{", "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}"}


def format_cell(cell: Cell, decimals: int, pm: str = " ± ") -> str:
    """A cell as text: floats with ``decimals`` places, Stats as ``mean ± std`` when n > 1."""
    if isinstance(cell, Stat):
        if cell.n == 0:
            return "n/a"
        text = format_cell(cell.mean, decimals)
        return text + pm + format_cell(cell.std, decimals) if cell.n > 1 else text
    if isinstance(cell, float):
        return f"{cell:.{decimals}f}" if math.isfinite(cell) else "n/a"
    return str(cell)


def to_markdown(table: Table) -> str:
    """A Markdown table under a ``### title`` heading; numeric columns right-aligned."""
    align = ["---"] + ["---:"] * (len(table.header) - 1)
    lines = [f"### {table.title}", "", "| " + " | ".join(table.header) + " |", "|" + "|".join(align) + "|"]
    lines += ["| " + " | ".join(format_cell(c, table.decimals) for c in row) + " |" for row in table.rows]
    if not table.rows:
        lines.append("| " + " | ".join(["-"] * len(table.header)) + " |")
    return "\n".join(lines) + "\n"


def to_csv(table: Table) -> str:
    """CSV with full-precision numbers; a ``<column> std`` column follows each column with repeats."""
    with_std = {j for j in range(len(table.header))
                if any(isinstance(row[j], Stat) and row[j].n > 1 for row in table.rows)}
    header = []
    for j, name in enumerate(table.header):
        header += [name, f"{name} std"] if j in with_std else [name]
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    for row in table.rows:
        out = []
        for j, cell in enumerate(row):
            value = cell.mean if isinstance(cell, Stat) else cell
            out.append("" if isinstance(value, float) and not math.isfinite(value) else value)
            if j in with_std:
                out.append(cell.std if isinstance(cell, Stat) and cell.n > 1 else "")
        writer.writerow(out)
    return buffer.getvalue()


def _latex_escape(text: str) -> str:
    return "".join(_LATEX_ESCAPES.get(ch, ch) for ch in text)


def to_latex(table: Table) -> str:
    """A ``table`` environment with a plain ``tabular`` (no packages needed) and the title as caption."""
    spec = "l" + "r" * (len(table.header) - 1)
    body = [" & ".join(_latex_escape(h) for h in table.header) + r" \\", r"\hline"]
    for row in table.rows:
        cells = [_latex_escape(format_cell(c, table.decimals, pm="\x00")).replace("\x00", r" $\pm$ ") for c in row]
        body.append(" & ".join(cells) + r" \\")
    return "\n".join([
        r"\begin{table}[t]", r"\centering", rf"\caption{{{_latex_escape(table.title)}}}",
        rf"\label{{tab:{table.name}}}", rf"\begin{{tabular}}{{{spec}}}", r"\hline",
        *body, r"\hline", r"\end{tabular}", r"\end{table}", "",
    ])
