"""Citations of ``docs/papers/<page>.md#<heading>`` in the repository name a page and a heading that exist."""
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CITATION = re.compile(r"docs/papers/([\w-]+\.md)(?:#([\w-]+))?")


def heading_anchor(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, punctuation dropped, spaces to hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def anchors(pages: Path) -> dict[str, set[str]]:
    return {page.name: {heading_anchor(h) for h in re.findall(r"^#+ (.*)$", page.read_text(), re.M)}
            for page in pages.glob("*.md")}


def broken_citations(texts: dict[str, str], known: dict[str, set[str]]) -> list[str]:
    return sorted(f"{name}: {m.group(0)}" for name, text in texts.items() for m in CITATION.finditer(text)
                  if m.group(1) not in known or (m.group(2) and m.group(2) not in known[m.group(1)]))


def repository_texts() -> dict[str, str]:
    paths = [ROOT / "README.md", *[p for d in ("jaxanom", "tests", "experiments", "benchmarks", "docs")
                                   for p in (ROOT / d).rglob("*") if p.suffix in {".py", ".md"}]]
    return {str(p.relative_to(ROOT)): p.read_text(errors="replace") for p in paths
            if p != Path(__file__).resolve()}  # this file cites missing headings on purpose


def test_every_docs_papers_citation_names_an_existing_heading():
    known = anchors(ROOT / "docs" / "papers")
    assert {"mmf.md", "offroad.md", "sml-cudam-msaam.md", "anomaly-metrics.md"} <= set(known)
    assert broken_citations(repository_texts(), known) == []


def test_a_citation_of_a_missing_page_or_heading_is_found():
    known = {"mmf.md": {heading_anchor("Superpixel step"), heading_anchor("FPR at 95% TPR")}}
    texts = {"a.py": "see docs/papers/mmf.md#superpixel-step and docs/papers/mmf.md#fpr-at-95-tpr",
             "b.py": "see docs/papers/mmf.md#superpixel-steps", "c.py": "docs/papers/offroad.md"}
    assert broken_citations(texts, known) == ["b.py: docs/papers/mmf.md#superpixel-steps",
                                              "c.py: docs/papers/offroad.md"]
