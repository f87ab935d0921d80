"""The README's printed demo table is what ``make demo`` prints.

``make demo`` runs ``python -m renderer demo --device sim:onedof --force``: the default DemoConfig. The session's
default demo (tests/conftest.py ``default_demo``, same settings, its own cache) formats its table with the
same functions the command prints with; every line of the README's block (the rendering lines, the
penetration-cut, reactive-hand and thesis-claims lines) must be among those lines, character for character
(trailing blanks aside).
"""

import re
from pathlib import Path

from renderer.demo import sim_demo
from renderer.demo.report import format_reactive
from renderer.demo.fidelity import format_fidelity

README = Path(__file__).resolve().parents[2] / "README.md"


def _demo_block() -> list[str]:
    text = README.read_text(encoding="utf-8")
    section = text[text.index("## What `make demo` shows"):]
    block = re.search(r"^```text\n(.*?)^```", section, re.S | re.M).group(1)
    return [ln.rstrip() for ln in block.splitlines() if ln.strip()]


def test_readme_demo_table_matches_what_the_demo_prints(default_demo):
    printed = sim_demo.format_table(default_demo.cfg, default_demo.rows, default_demo.pipeline.library)
    printed_lines = [ln.rstrip() for ln in printed.splitlines()] + [format_reactive(default_demo.reactive),
                                                                    format_fidelity(default_demo.claims)]
    block = _demo_block()
    names = [r.name for r in default_demo.cfg.renderings]
    table = [ln for ln in block if ln.split(" ")[0] in names]
    assert [ln.split(" ")[0] for ln in table] == names      # every rendering, in the printed order
    for ln in block:
        assert ln in printed_lines, f"README line not printed by the demo:\n{ln}"
