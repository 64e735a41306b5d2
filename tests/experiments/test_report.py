"""Tables and the results blocks of the docs."""

from __future__ import annotations

from masknet.experiments import markdown_table, update_results
from masknet.experiments.report import csv_text


def test_results_block_is_replaced_in_place(tmp_path):
    doc = tmp_path / "RESULTS.md"
    doc.write_text("# Results\n\nintro\n")
    update_results(doc, "demo", markdown_table([{"a": 1.0, "b": "x"}]))
    update_results(doc, "demo", markdown_table([{"a": 2.0, "b": "y"}]))
    text = doc.read_text()
    assert (
        text.count("<!-- benchmark:demo -->") == 1 and "| 2 | y |" in text and "| 1 |" not in text
    )
    assert text.startswith("# Results\n\nintro")


def test_tables_leave_a_column_blank_where_a_row_lacks_it():
    rows = [{"a": 1.0}, {"a": 2.0, "b": 3}]
    assert markdown_table(rows).splitlines()[0] == "| a | b |"
    assert markdown_table(rows).splitlines()[2] == "| 1 |  |"
    assert csv_text(rows).splitlines() == ["a,b", "1.0,", "2.0,3"]
