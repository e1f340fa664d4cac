"""Rewrite the generated parameter table in every docs/methods/<method>.md (see methods/paramdoc.py).

python tools/gen_method_docs.py          # rewrite
python tools/gen_method_docs.py --check  # exit 1 if a page is stale or missing
"""

from __future__ import annotations

import pathlib
import sys

import softshadows as ss
from softshadows.methods.paramdoc import replace_block

DOCS = pathlib.Path(__file__).resolve().parent.parent / "docs" / "methods"


def main(argv=None) -> int:
    check = "--check" in (argv if argv is not None else sys.argv[1:])
    bad = 0
    for name, m in ss.methods().items():
        page = DOCS / f"{name}.md"
        if not page.exists():
            print(f"missing {page}")
            bad += 1
            continue
        old = page.read_text()
        new = replace_block(old, m)
        if new != old:
            if check:
                print(f"stale parameter table in {page}")
                bad += 1
            else:
                page.write_text(new)
                print(f"updated {page}")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
