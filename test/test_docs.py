"""The README is a front door (<= 250 lines) and every page behind it is reachable: each
docs/*.md is linked from the README, and every relative link of the README and the docs
pages points at a file that exists."""

import re
from pathlib import Path

import pytest

pytestmark = pytest.mark.unit

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\[[^\]]*\]\(([^)\s]+)\)")


def _relative_links(page: Path) -> list[str]:
    text = re.sub(r"```.*?```", "", page.read_text(encoding="utf-8"), flags=re.DOTALL)
    return [t for t in LINK.findall(text) if not re.match(r"(https?:|mailto:|#)", t)]


def test_readme_is_at_most_250_lines() -> None:
    n = len((ROOT / "README.md").read_text(encoding="utf-8").splitlines())
    assert n <= 250, f"README.md has {n} lines: move reference and results into docs/"


def test_every_docs_page_is_linked_from_the_readme() -> None:
    linked = {(ROOT / t.split("#")[0]).resolve() for t in _relative_links(ROOT / "README.md")}
    pages = sorted((ROOT / "docs").glob("*.md"))
    assert len(pages) >= 8
    missing = [p.name for p in pages if p.resolve() not in linked]
    assert not missing, f"docs pages the README does not link (add a line to 'Where to read on'): {missing}"


PAGES = ["README.md", *sorted(f"docs/{p.name}" for p in (ROOT / "docs").glob("*.md"))]


@pytest.mark.parametrize("page", PAGES)
def test_relative_links_resolve(page) -> None:
    base = (ROOT / page).parent
    broken = [t for t in _relative_links(ROOT / page) if not (base / t.split("#")[0]).exists()]
    assert not broken, f"{page}: links to nothing: {broken}"


def test_the_check_sees_a_broken_link(tmp_path) -> None:
    (tmp_path / "x.md").write_text("see [a](nowhere.md), [b](https://x.org), [c](#here)\n"
                                   "```\n[d](in_code.md)\n```\n")
    assert _relative_links(tmp_path / "x.md") == ["nowhere.md"]
