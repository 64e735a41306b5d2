"""Tables as markdown and CSV, and the writer of the ``<!-- benchmark:NAME -->`` blocks of a
markdown file (docs/RESULTS.md)."""

from __future__ import annotations

import csv
import io
from pathlib import Path

from masknet.io import write_text_atomic

__all__ = ["csv_text", "markdown_table", "update_results"]


def _format(value: object) -> str:
    if isinstance(value, float):
        return f"{value:.4g}" if abs(value) < 1e4 else f"{value:.0f}"
    return str(value)


def _columns(rows: list[dict]) -> list[str]:
    """Every key of ``rows`` in first-seen order (a column some rows lack stays blank there)."""
    return list(dict.fromkeys(key for row in rows for key in row))


def markdown_table(rows: list[dict]) -> str:
    """A markdown table of ``rows``, floats to 4 significant digits."""
    keys = _columns(rows)
    lines = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    lines += ["| " + " | ".join(_format(r.get(k, "")) for k in keys) + " |" for r in rows]
    return "\n".join(lines)


def csv_text(rows: list[dict]) -> str:
    """``rows`` as CSV, with a header of every key."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=_columns(rows), restval="")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def update_results(path: Path, name: str, block: str) -> None:
    """Replace (or append) the ``<!-- benchmark:name -->`` block of a markdown file."""
    start, end = f"<!-- benchmark:{name} -->", f"<!-- /benchmark:{name} -->"
    text = path.read_text() if path.exists() else ""
    new = f"{start}\n{block.rstrip()}\n{end}"
    if start in text and end in text:
        text = text[: text.index(start)] + new + text[text.index(end) + len(end) :]
    else:
        text = text.rstrip() + "\n\n" + new + "\n"
    write_text_atomic(path, text)
