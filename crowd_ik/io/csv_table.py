"""The one CSV reader: small comma-separated tables with a header, read line by line so that every
problem names the file and the line.

Used by the player's inputs (io/inputs.py), the mouse demo's target paths (mouse/paths.py) and the
keyframe files (ease.py). Blank lines are skipped; lines starting with '#' are comments (those before
the header may be handed to the caller, e.g. the inputs' settings line); fields are split at commas
and stripped; every row must have as many fields as the header. Problems raise
ValueError("FILE:LINE: problem (got value)").
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass


@dataclass(frozen=True)
class Table:
    path: str
    header: tuple[str, ...]
    rows: tuple[tuple[int, tuple[str, ...]], ...]  # (line number, fields)
    end_line: int  # the line after the last one (where "nothing more" problems point)


def read_table(path, header: tuple[str, ...] | Callable[[list[str]], bool], spec: str, what: str = "row",
               max_rows: int | None = None, on_comment: Callable[[int, str], None] | None = None) -> Table:
    """Read `path`. header: the exact names, or a test of the header's fields; spec: how the header is
    described in messages ("t,x,y"); what: a row's name in messages; max_rows: refuse more rows;
    on_comment(line, text): called for each comment before the header."""
    path = os.fspath(path)
    with open(path, encoding="utf-8", errors="replace") as fh:
        lines = fh.read().splitlines()
    names, rows = None, []
    for number, raw in enumerate(lines, start=1):
        text = raw.strip()
        if not text:
            continue
        if text.startswith("#"):
            if names is None and on_comment is not None:
                on_comment(number, text)
            continue
        fields = tuple(f.strip() for f in text.split(","))
        if names is None:
            ok = fields == tuple(header) if isinstance(header, tuple) else header(list(fields))
            if not ok:
                raise ValueError(f"{path}:{number}: expected header {spec} (got {text[:80]!r})")
            names = fields
            continue
        if len(fields) != len(names):
            raise ValueError(f"{path}:{number}: expected {len(names)} fields {spec} (got {len(fields)}: {text[:80]!r})")
        rows.append((number, fields))
        if max_rows is not None and len(rows) > max_rows:
            raise ValueError(f"{path}:{number}: more than {max_rows} rows (got more)")
    end = len(lines) + 1
    if names is None:
        got = "an empty file" if not any(line.strip() for line in lines) else "only comments"
        raise ValueError(f"{path}:{1 if got == 'an empty file' else end}: expected header {spec} (got {got})")
    if not rows:
        raise ValueError(f"{path}:{end}: expected at least one {what} after the header (got none)")
    return Table(path, names, tuple(rows), end)


def finite(path: str, line: int, name: str, field: str) -> float:
    """The field as a finite float, or ValueError("FILE:LINE: name: expected a finite number (got 'x')")."""
    try:
        v = float(field)
    except ValueError:
        v = math.nan
    if not math.isfinite(v):
        raise ValueError(f"{path}:{line}: {name}: expected a finite number (got {field!r})")
    return v
