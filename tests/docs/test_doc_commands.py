"""Every command the README and the manual show runs, against one simulated rig (docrun.py).

One test per page, so a failure names the page and the line; the pages share one simulated
rig and daemon, started once for the module on free ports and private paths.
"""

from __future__ import annotations

import re
import subprocess

import pytest
from docrun import ROOT, DocRig, blocks, check_covered_by, command_words, pages, run_page

PAGES = pages()


@pytest.fixture(scope="module")
def rig(tmp_path_factory):
    r = DocRig(tmp_path_factory.mktemp("docrun"))
    try:
        yield r
    finally:
        r.shutdown()


@pytest.mark.realtime
@pytest.mark.timeout(600)
@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(ROOT)) for p in PAGES])
def test_page_commands_run(rig, page):
    failures = run_page(rig, page)
    assert not failures, "\n\n".join(failures)


def test_every_sh_block_is_found_and_marked_or_run(tmp_path):
    """The parser reads marks, continuation lines and comments as the runner's docstring says."""
    page = tmp_path / "p.md"
    page.write_text(
        "text\n\n<!-- cmd: hardware-only: needs can0 -->\n```sh\nsudo ip link set can0 up\n```\n"
        "```sh\n# a comment\ncdcr-ctl -c config/qi2023-sim.yaml trajectory \\\n"
        "    --builtin planar_bend\n\ncdcr-ctl status\n```\n```python\nnot_a_command()\n```\n"
    )
    got = blocks(page)
    assert [b.mark for b in got] == ["hardware-only: needs can0", ""]
    assert [(c.line, c.text) for c in got[1].commands] == [
        (9, "cdcr-ctl -c config/qi2023-sim.yaml trajectory      --builtin planar_bend"),
        (12, "cdcr-ctl status"),
    ]


def test_covered_by_checks_the_test_and_its_words():
    assert command_words(".venv/bin/cdcr-ctl experiments --jobs 2") == ["experiments"]
    assert command_words("scripts/demo") == ["demo"]
    ok = check_covered_by(
        "covered-by tests/docs/test_doc_commands.py::test_page_commands_run",
        "cdcr-ctl -c x.yaml rig",
    )
    assert ok is None
    bad = check_covered_by("covered-by tests/docs/test_doc_commands.py::no_such_test", "x")
    assert bad and "no test" in bad
    word = "q" * 3 + "unmentioned"  # a word this file does not hold as such
    missing = check_covered_by(
        "covered-by tests/docs/test_doc_commands.py::test_page_commands_run", f"cdcr-ctl {word}"
    )
    assert missing and word in missing


HISTORY = re.compile(r"session [0-9]|issue [0-9]+|#[0-9]{2}", re.IGNORECASE)


def test_no_page_speaks_of_history():
    """`grep -rniE 'session [0-9]|issue [0-9]+|#[0-9]{2}' README.md docs/` finds nothing."""
    res = subprocess.run(
        ["grep", "-rniE", HISTORY.pattern, "README.md", "docs/"],
        cwd=ROOT,
        capture_output=True,
        text=True,
    )
    assert res.returncode == 1, f"history in the docs:\n{res.stdout}"


def test_readme_is_short_and_says_what_how_and_run():
    text = (ROOT / "README.md").read_text()
    lines = text.splitlines()
    assert len(lines) <= 300, f"README.md has {len(lines)} lines"
    first_screen = "\n".join(lines[:50])
    for needed in ("scripts/demo", "scripts/test", "cdcr-ctl", "docs/"):
        assert needed in first_screen, f"README's first screen lacks {needed!r}"
    # CI's entry point runs the README's test command.
    assert "scripts/test" in (ROOT / ".ci/run").read_text()
