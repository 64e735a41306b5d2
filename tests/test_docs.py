"""docs/BENCHMARKS.md, the results page a user reads: short, linked first from the README's results
section, holding every figure that section quotes, each section naming its command and machine, and
every picture and page it links present."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
BENCHMARKS = DOCS / "BENCHMARKS.md"
README = ROOT / "README.md"
RESULTS = DOCS / "RESULTS.md"
MAX_LINES = 300  # a page read in one sitting; RESULTS.md keeps the rest

# A figure as written: digits with decimal or thousands separators and an exponent ("0.9011",
# "241,407", "5.25e-07", "2.13.0"), not part of a name ("ModelNet40", "bf16", "v1.5", "3DMatch").
FIGURE = re.compile(r"(?<![\w.])\d+(?:[.,]\d+)*(?:e-?\d+)?(?!\w)")
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")  # link text may wrap across lines
IMAGE = re.compile(r"!\[[^\]]*\]\(([^)\s]+)\)")
COMMAND = re.compile(r"^(masknet |python scripts/|python -m masknet)", re.M)


def _readme_results() -> str:
    """The README's "## Results" section, up to the next second-level heading."""
    text = README.read_text()
    start = text.index("\n## Results\n")
    end = text.find("\n## ", start + 1)
    return text[start : end if end >= 0 else len(text)]


def _sections() -> list[tuple[str, str]]:
    """(heading, body) of each "## " section of BENCHMARKS.md (none without the page: the test of
    its existence says so, not a collection error)."""
    text = BENCHMARKS.read_text() if BENCHMARKS.exists() else ""
    parts = re.split(r"^## (.+)$", text, flags=re.M)
    return list(zip(parts[1::2], parts[2::2], strict=True))


def _slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_the_page_exists_and_is_short():
    assert BENCHMARKS.exists(), "docs/BENCHMARKS.md is missing"
    lines = BENCHMARKS.read_text().splitlines()
    assert lines[0] == "# Benchmarks"
    assert len(lines) <= MAX_LINES, (
        f"docs/BENCHMARKS.md has {len(lines)} lines, at most {MAX_LINES}"
    )


def test_the_readme_links_the_page_before_any_other_results_link():
    links = LINK.findall(_readme_results())
    assert links and links[0] == "docs/BENCHMARKS.md", links[:3]


def test_the_notebook_points_to_the_page_before_its_first_section():
    head = RESULTS.read_text().split("\n## ", 1)[0]
    assert "BENCHMARKS.md" in LINK.findall(head)


def test_every_figure_of_the_readme_results_section_is_on_the_page():
    # The README's summary quotes the page, digit for digit: a figure changed in one place only
    # fails here.
    on_page = set(FIGURE.findall(BENCHMARKS.read_text()))
    quoted = FIGURE.findall(_readme_results())
    assert len(quoted) >= 20  # the summary quotes figures (the check is not vacuous)
    missing = sorted(set(quoted) - on_page)
    assert not missing, (
        f"figures in the README's results section not on docs/BENCHMARKS.md: {missing}"
    )


def test_the_page_has_the_headline_sections():
    headings = " ".join(heading for heading, _ in _sections()).lower()
    topics = ("robust", "real pairs", "density", "size", "verdict", "mask precision")
    topics += ("mask-x against x", "outliers", "register-many", "inference")
    assert not [topic for topic in topics if topic not in headings]


@pytest.mark.parametrize("heading", [heading for heading, _ in _sections()])
def test_each_section_names_its_command_and_machine(heading):
    body = dict(_sections())[heading]
    code = "\n".join(re.findall(r"```bash\n(.*?)```", body, flags=re.S))
    assert COMMAND.search(code), f"section {heading!r} names no masknet or python scripts/ command"
    machine = re.search(r"^\*\*Machine:\*\*(.*?)(?:\n\n|\Z)", body, flags=re.M | re.S)
    assert machine, f"section {heading!r} names no machine"
    for part in ("EPYC", "AVX512-BF16", "threads", "torch 2."):  # CPU, bf16 or not, threads, torch
        assert part in machine[1], (heading, part)


def test_every_picture_and_page_the_page_links_exists():
    text = BENCHMARKS.read_text()
    assert IMAGE.findall(text), "the page shows no plot"
    for target in LINK.findall(text):
        if target.startswith(("http://", "https://")):
            continue
        path, _, anchor = target.partition("#")
        file = (DOCS / path).resolve() if path else BENCHMARKS
        assert file.exists(), f"docs/BENCHMARKS.md links {target}, which does not exist"
        if anchor and file.suffix == ".md":
            headings = re.findall(r"^#+ (.+)$", file.read_text(), flags=re.M)
            assert anchor in {_slug(h) for h in headings}, f"no heading for {target}"
