"""What the writers of ``docs/*.md`` share: Markdown templates filled with measurements.

A page is a template in ``benchmarks/templates/`` whose ``${name}`` placeholders a benchmark
fills with its measurements (:func:`fill`; a placeholder left without a value is an error);
tables are :func:`table`, and :func:`provenance` says where and when the numbers were made.
"""

from __future__ import annotations

import os
import platform
import string
import subprocess
from collections.abc import Iterable, Sequence
from datetime import datetime, timezone
from pathlib import Path

from fempm import output

__all__ = ["ROOT", "fill", "provenance", "table", "write"]

ROOT = Path(__file__).resolve().parents[1]
TEMPLATES = Path(__file__).resolve().parent / "templates"


def fill(template: str, **values) -> str:
    """The template ``benchmarks/templates/<template>`` with every ``${name}`` replaced by ``values[name]``."""
    return string.Template((TEMPLATES / template).read_text()).substitute(values)


def table(head: Sequence[str], rows: Iterable[Sequence]) -> str:
    """A Markdown table: the header, the rule, one line per row (cells as ``str``)."""
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    lines += ["| " + " | ".join(str(cell) for cell in row) + " |" for row in rows]
    return "\n".join(lines)


def provenance() -> dict[str, str]:
    """``date`` (UTC, to the minute), ``commit`` (short, or ?), ``machine`` (processor, cores), ``node``."""
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                            text=True).stdout.strip()
    return {"date": f"{datetime.now(timezone.utc):%Y-%m-%d %H:%M}", "commit": commit or "?",
            "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores",
            "node": platform.node()}


def write(path: Path, text: str):
    """Write a page whole (a temporary file renamed), so that a stopped run leaves the old page."""
    with output.atomic_path(path) as tmp:
        Path(tmp).write_text(text)
