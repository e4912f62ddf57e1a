"""Every pointer into the docs and the sources that the code and the docs hold leads
somewhere: a doc named ``docs/<name>.md`` exists, a section quoted after it (``, "Title"``)
is one of its headings, a ``docs/METHOD.md §N`` is one of its numbered sections, and a
path of the repository's own (``mrsph/...``, ``tools/...``, ``tests/...``) is a file. Docs
are folded and modules moved; a comment that says why by pointing at a page must not
point at nothing."""

import re
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DOC_REF = re.compile(r'docs/([\w.-]+\.md)(?:[,:]?\s*\(?(?:the\s+)?"([^"\n]{3,80})")?')
METHOD_REF = re.compile(r"METHOD\.md,? §(\d+)")
PATH_REF = re.compile(r"(?<![\w/.])((?:mrsph|tools|tests)/[\w/.-]+\.py)")


def _sources() -> list[Path]:
    roots = [REPO / "mrsph", REPO / "tools", REPO / "tests", REPO / "docs", REPO / "scenes"]
    files = [p for root in roots for p in root.rglob("*") if p.suffix in (".py", ".md", ".toml")]
    return files + [REPO / "README.md", REPO / "main.py"]


def _headings(doc: Path) -> list[str]:
    return [line.lstrip("#").strip().lower() for line in doc.read_text().splitlines() if line.startswith("#")]


def test_every_pointer_into_the_docs_and_sources_leads_somewhere():
    method = {int(n) for n in re.findall(r"^## (\d+)\.", (REPO / "docs" / "METHOD.md").read_text(), re.M)}
    bad = []
    for path in _sources():
        text = path.read_text(errors="ignore")
        where = path.relative_to(REPO)

        def line(m, text=text):
            return text.count("\n", 0, m.start()) + 1

        for m in DOC_REF.finditer(text):
            doc = REPO / "docs" / m.group(1)
            if not doc.is_file():
                bad.append(f"{where}:{line(m)}: no docs/{m.group(1)}")
            elif m.group(2) and not any(m.group(2).lower() in h for h in _headings(doc)):
                bad.append(f'{where}:{line(m)}: docs/{m.group(1)} has no heading "{m.group(2)}"')
        for m in METHOD_REF.finditer(text):
            if int(m.group(1)) not in method:
                bad.append(f"{where}:{line(m)}: METHOD.md has no §{m.group(1)}")
        for m in PATH_REF.finditer(text):
            if not (REPO / m.group(1)).is_file():
                bad.append(f"{where}:{line(m)}: no {m.group(1)}")
    assert not bad, "\n".join(bad)
