"""The README and the command reference run as printed: every command in their ```sh blocks, through the
installed console scripts.

The README's five steps and docs/usage.md (the reference by package, where the commands the README used to
print live) are one path: README.md's blocks first, then docs/usage.md's, in one folder.
Blocks tagged ``sh`` are commands a user types after ``make demo`` and activating ``.venv``;
``text`` blocks are output samples or hardware-only templates (a serial device, a person). The
commands run in order in one scratch folder (later ones use earlier outputs), with the venv's
``bin`` first on ``PATH`` as activation puts it. To keep the suite lean, SMALLER shrinks a few
sizes (fewer grip levels and shorter sweeps for ``identify``, fewer samples in ``study run``);
every other flag, file name and command is exactly the README's.

The first command of each family (``hfam-devices``, ``hfam-renderer``, ...) runs as a real process through its
console script, as typed; the family's later commands run the same ``main`` in this process
(``tests/support/cli.py``: the same parser, body and error handling, without a child's 1-3 s of imports), with
the shell's glob expansion done here.
"""

import glob
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from tests.support.cli import run_cli


ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
#: the pages whose commands run, in order (later ones use earlier outputs); links resolve from each page's folder
PAGES = (README, ROOT / "docs" / "usage.md")
BIN = Path(sys.executable).parent          # the venv's bin: console scripts live next to its python

#: (regex, replacement) applied to each command line before running it: sizes only.
SMALLER = [
    (r"(identify .*)--grips-N 0,1,2,3,5,10(.*--out ident/)$", r"\1--grips-N 0,5,10\2 --trials 2 --duration-s 1"),
    (r"(identify .*)--grips-N 0,1,2,3,5,10 --trials 4(.*--out ident4/)$",
     r"\1--grips-N 1,3\2 --trials 2 --duration-s 1"),
    (r"(study run .*--catalog my_catalog.toml.*)$", r"\1 --samples wood,wood_on_foam,hfam_mine --repetitions 1"),
    (r"(study run .*--subject S02.*)$", r"\1 --samples wood,wood_on_foam,firm --repetitions 1"),
]


def code_blocks(text):
    """(info string, [logical lines]) of each fenced block; backslash continuations joined."""
    blocks = []
    for m in re.finditer(r"^```(\w*)\n(.*?)^```", text, re.S | re.M):
        lines, cur = [], ""
        for raw in m.group(2).splitlines():
            if raw.rstrip().endswith("\\"):
                cur += raw.rstrip()[:-1] + " "
                continue
            lines.append((cur + raw).strip())
            cur = ""
        blocks.append((m.group(1), [ln for ln in lines if ln]))
    return blocks


def commands():
    out = []
    for page in PAGES:
        for info, lines in code_blocks(page.read_text()):
            if info == "sh":
                out += [" ".join(shlex.split(ln, comments=True)) for ln in lines]
    return [c for c in out if c]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_block_is_tagged_and_every_command_block_is_sh(page):
    for info, lines in code_blocks(page.read_text()):
        assert info in ("sh", "text", "toml"), f"untagged block in {page.name}: {lines[:2]}"
        if info == "text":
            for ln in lines:   # a hfam-* command in a text block must be a hardware/person template
                if ln.startswith(("hfam-", "python -m")):
                    assert "serial:" in ln or "hid:" in ln, f"{page.name} command not run by a test: {ln}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_readme_mentions_only_shipped_files(page):
    text = page.read_text()
    links = set(re.findall(r"\]\(([^)#:]+)\)", text))                      # markdown links, from the page's folder
    paths = {p for p in re.findall(r"`([\w./-]+\.(?:md|toml|npz|c|h|py))`", text)   # repository paths
             if "/" in p and p.split("/")[0] in {"docs", "examples", "stimuli", "devices", "renderer", "study",
                                                 "analysis", "benchmarks", "tests"}}
    missing = sorted([p for p in links if not (page.parent / p).exists()]
                     + [p for p in paths if not (ROOT / p).exists()])
    assert not missing, missing
    assert (ROOT / "examples" / "my_catalog.toml").is_file()


def test_the_readme_indexes_every_page_of_the_docs():
    text = README.read_text()
    unlisted = [p.name for p in sorted((ROOT / "docs").glob("*.md")) if f"(docs/{p.name})" not in text]
    assert not unlisted, f"docs pages missing from the README's 'Where to read on': {unlisted}"


def test_make_targets_in_the_readme_exist():
    for line in commands():
        if line.startswith("make "):
            r = subprocess.run(["make", "-n", *line.split()[1:]], cwd=ROOT, capture_output=True, text=True,
                               timeout=60)
            assert r.returncode == 0, r.stderr


#: a line with any of these runs through the shell (redirections, pipes, variables)
SHELL_ONLY = set("|&;<>$`(){}")


def in_process_args(cmd: str, cwd: Path) -> list[str]:
    """``cmd``'s arguments after the console script's name, globs expanded as bash does (sorted; a pattern
    that matches nothing stays as typed)."""
    out = []
    for word in shlex.split(cmd)[1:]:
        hits = sorted(glob.glob(word, root_dir=cwd)) if any(c in word for c in "*?[") else []
        out += hits or [word]
    return out


def test_readme_commands_run_as_printed(tmp_path, capsys):
    env = dict(os.environ, PATH=f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", MPLBACKEND="Agg")
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    ran, families = [], set()
    for line in commands():
        if line.startswith("make "):
            continue                              # test_make_targets_in_the_readme_exist; make test runs this
        if line.startswith(". .venv/bin/activate"):
            r = subprocess.run(["bash", "-c", f". {shlex.quote(str(BIN / 'activate'))} && command -v hfam-devices"],
                               capture_output=True, text=True, env=dict(os.environ))
            assert r.returncode == 0 and Path(r.stdout.strip()) == BIN / "hfam-devices", r.stderr
            continue
        cmd = line
        for pattern, repl in SMALLER:
            cmd = re.sub(pattern, repl, cmd)
        script = cmd.split()[0]
        if script.startswith("hfam-") and script in families and not SHELL_ONLY & set(cmd):
            r = run_cli(capsys, script.removeprefix("hfam-"), *in_process_args(cmd, tmp_path), cwd=tmp_path)
        else:
            families.add(script)
            r = subprocess.run(["bash", "-c", cmd], cwd=tmp_path, env=env, capture_output=True, text=True,
                               timeout=600)
        assert r.returncode == 0, f"command of README.md or docs/usage.md failed: {cmd}\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}"
        assert "deprecated" not in r.stderr, f"README uses an old flag spelling: {cmd}\n{r.stderr}"
        ran.append(cmd)
    # the workflow's products exist
    for f in ("REC.csv", "ident/model_set.json", "LIB.npz", "LIB.png", "runs/hfam/run.json", "DATA/S01/session.json",
              "REPORT/report.html", "hfam_model.json", "wood_on_foam.npz"):
        assert (tmp_path / f).exists(), f
    assert sum(c.startswith("hfam-") for c in ran) >= 14
    assert {"hfam-devices", "hfam-renderer", "hfam-stimuli", "hfam-study", "hfam-analysis"} <= families
