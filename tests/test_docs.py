"""Each method has its doc page, and the page's parameter table is the one its Param list generates."""

import pathlib
import re

import pytest

import softshadows as ss
from softshadows.methods.paramdoc import BEGIN, END, params_table

DOCS = pathlib.Path(__file__).resolve().parent.parent / "docs" / "methods"


@pytest.mark.parametrize("name", list(ss.methods()))
def test_method_page_parameter_table_is_current(name):
    page = DOCS / f"{name}.md"
    assert page.exists(), f"{page} is missing (every registered method has a doc page)"
    text = page.read_text()
    assert BEGIN in text and END in text, f"{page} has no generated parameter block"
    block = text[text.index(BEGIN) + len(BEGIN) : text.index(END)].strip()
    assert block == params_table(ss.methods()[name]), (
        f"{page}: parameter table is stale; run python tools/gen_method_docs.py"
    )
    for p in ss.methods()[name].params:
        assert f"`{p.name}`" in block


ROOT = DOCS.parent.parent
# Every relative link must resolve (no page is exempt).
NOT_YET_HERE: set = set()
_LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
_FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def _relative_links(page: pathlib.Path):
    text = _FENCE.sub("", page.read_text())
    for target in _LINK.findall(text):
        if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue  # absolute URL or a link within the page
        yield target.split("#", 1)[0]


def test_relative_links_resolve():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    checked, broken = 0, []
    for page in pages:
        for target in _relative_links(page):
            path = (page.parent / target).resolve()
            rel = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else str(path)
            checked += 1
            if not path.is_relative_to(ROOT):
                broken.append(f"{page.relative_to(ROOT)}: {target} points outside the repository")
            elif not path.exists() and rel not in NOT_YET_HERE:
                broken.append(f"{page.relative_to(ROOT)}: {target} does not exist")
    assert checked > 50, f"only {checked} links found: the link pattern no longer matches the pages"
    assert not broken, "\n".join(broken)
