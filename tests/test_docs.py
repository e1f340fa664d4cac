"""Each method has its doc page, and the page's parameter table is the one its Param list generates."""

import pathlib

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
