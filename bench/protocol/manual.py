"""A method's manual and its parameter tables, generated from the `Param` declarations.

A method's manual is the docstring of its `method.py` (what it computes, the paper, a parameter
table, an example, its stress limits); the README.md beside it repeats the table for readers of
the folder. Measurements and history go to NOTES.md (neither is hashed into the method's
version). Each parameter is documented once, in its `Param(doc=...)`: the tables between the
markers below are generated from the declarations (`gibench manuals --write`) and checked
against them (`gibench manuals`, and the test suite), so a table never disagrees with the code.
"""
from __future__ import annotations

import ast
import importlib
import re
from pathlib import Path

BEGIN = "<!-- parameters: generated from the Param declarations by `gibench manuals --write` -->"
END = "<!-- end of parameters -->"
_BLOCK = re.compile(re.escape(BEGIN) + r"\n.*?" + re.escape(END), re.S)
# "Stress limit <pattern>: <reason>" documents a stress failure the method's design implies (one
# line; the pattern may itself hold colons, params:NAME=VALUE, so it ends at a colon followed by
# white space)
_STRESS_LIMIT = re.compile(r"^\s*[-*]?\s*Stress limit\s+(\S+)\s*:\s+(.+?)\s*$", re.MULTILINE)


def stress_limits(text: str) -> dict:
    """{fnmatch pattern: reason} of the "Stress limit PATTERN: reason" lines of a manual."""
    limits: dict = {}
    for pattern, reason in _STRESS_LIMIT.findall(text or ""):
        limits.setdefault(pattern, reason)
    return limits


def format_value(value) -> str:
    """A declared value as Python writes it (2.0, 0.0001, 1e-05), booleans lower-case."""
    if isinstance(value, bool):
        return "true" if value else "false"
    return str(value)


def param_range(p) -> str:
    if p.choices is not None:
        return ", ".join(format_value(c) for c in p.choices)
    if isinstance(p.default, bool):
        return "bool"
    if p.low is None and p.high is None:
        return "any"
    low = format_value(p.low) if p.low is not None else "-inf"
    high = format_value(p.high) if p.high is not None else "inf"
    return f"{low} .. {high}"


def param_meaning(p) -> str:
    """The declared doc on one line ("|" would end the cell: it becomes "/"), and for a quality
    knob the values a sweep turns it to."""
    text = " ".join(str(p.doc).replace("|", "/").split())
    if p.quality:
        text += " (quality knob" + (f"; sweep {', '.join(format_value(v) for v in p.sweep)})" if p.sweep else ")")
    return text


def param_table(cls) -> str:
    """The Markdown table of `cls.params` (name, default, range, meaning), between the markers."""
    rows = [("parameter", "default", "range", "meaning")]
    for name, p in cls.params.items():
        rows.append((name, format_value(p.default), param_range(p), param_meaning(p)))
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    lines = []
    for i, r in enumerate(rows):
        lines.append("| " + " | ".join(c.ljust(w) for c, w in zip(r[:3], widths)) + " | " + r[3] + " |")
        if i == 0:
            lines.append("|" + "|".join("-" * (w + 2) for w in widths) + "|---|")
    if len(rows) == 1:
        lines.append("| (none) | | | |")
    return "\n".join([BEGIN, *lines, END])


def manual_files(cls) -> list[Path]:
    """The files that carry the method's parameter table: its module (the docstring) and README.md."""
    module = importlib.import_module(cls.__module__)
    source = Path(module.__file__)
    return [source, source.parent / "README.md"]


def check(cls) -> list[str]:
    """One line per file whose table is missing or differs from the declarations."""
    table = param_table(cls)
    problems = []
    doc = ast.get_docstring(ast.parse(manual_files(cls)[0].read_text()), clean=False) or ""
    if table not in doc:
        found = _BLOCK.search(doc)
        problems.append(f"method '{cls.name}': the manual's parameter table "
                        + ("differs from the Param declarations" if found else "is missing")
                        + " (gibench manuals --write)")
    readme = manual_files(cls)[1]
    text = readme.read_text() if readme.is_file() else ""
    if table not in text:
        found = _BLOCK.search(text)
        problems.append(f"method '{cls.name}': {readme.name} parameter table "
                        + ("differs from the Param declarations" if found else "is missing")
                        + " (gibench manuals --write)")
    return problems


def write(cls) -> list[Path]:
    """Replace the table between the markers in the module docstring and README.md (a file that has
    no markers yet gets none: put the two marker lines where the table belongs). Returns the files changed."""
    table = param_table(cls)
    changed = []
    for path in manual_files(cls):
        if not path.is_file():
            continue
        text = path.read_text()
        new = _BLOCK.sub(lambda _: table, text)
        if new != text:
            path.write_text(new)
            changed.append(path)
    return changed
