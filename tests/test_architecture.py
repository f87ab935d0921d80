"""Package arrows and import cycles, read from the code (ast): the allowed arrows are written once, here.

plumbing (the foundation) imports none of the others; psychophysics -> plumbing only (a library on its own);
devices -> plumbing; stimuli -> devices; renderer -> devices, stimuli; study -> renderer, devices, stimuli,
psychophysics; analysis -> psychophysics (it reads the study's files through the foundation's definition).
Every package may import plumbing. The renderer core must not import its demo or teleoperation applications,
and devices holds no plumbing (the foundation's modules live in plumbing/ only).
"""

import ast
import io
import os
import re
import tokenize
from functools import lru_cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("plumbing", "psychophysics", "devices", "renderer", "stimuli", "study", "analysis")
FOUNDATION = "plumbing"
ALLOWED = {
    "plumbing": set(),
    "psychophysics": {FOUNDATION},
    "devices": {FOUNDATION},
    "stimuli": {FOUNDATION, "devices"},
    "renderer": {FOUNDATION, "devices", "stimuli"},
    "study": {FOUNDATION, "renderer", "devices", "stimuli", "psychophysics"},
    "analysis": {FOUNDATION, "psychophysics"},
}
#: the project's own top-level packages (any other import is the standard library or a third-party package);
#: figstyle is the one figure style, a leaf that imports no package of the project
PROJECT = set(PACKAGES) | {"figstyle", "benchmarks", "tests"}
APPLICATIONS = ("renderer.demo", "renderer.teleop")  # the renderer core (renderer/*.py) must not import these


@lru_cache(maxsize=None)
def _parsed_at(path: str, mtime_ns: int, size: int) -> tuple[str, ast.Module]:
    src = Path(path).read_text(encoding="utf-8")
    return src, ast.parse(src)


def parsed(path: Path) -> tuple[str, ast.Module]:
    """``path``'s source and syntax tree, parsed once per version of the file (the checks below only read the
    trees; each used to parse all 600 files again, a second per check)."""
    st = os.stat(path)
    return _parsed_at(os.fspath(path), st.st_mtime_ns, st.st_size)


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def imports_of(path: Path) -> list[tuple[str, int, bool]]:
    """(imported module, line, inside a function) for every import in ``path``, relative ones resolved."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            inner = in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef))
            if isinstance(child, ast.Import):
                out.extend((a.name, child.lineno, in_function) for a in child.names)
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package.split(".")
                    base = base[:len(base) - child.level + 1]
                    mod = ".".join(base + ([child.module] if child.module else []))
                else:
                    mod = child.module
                out.extend((f"{mod}.{a.name}", child.lineno, in_function) for a in child.names)
            visit(child, inner)

    visit(parsed(path)[1], False)
    return out


def all_modules():
    return [p for pkg in PACKAGES for p in sorted((ROOT / pkg).rglob("*.py"))]


def test_packages_import_only_along_the_allowed_arrows():
    bad = []
    for path in all_modules():
        own = path.relative_to(ROOT).parts[0]
        for mod, line, _ in imports_of(path):
            top = mod.split(".")[0]
            if top in PACKAGES and top != own and top not in ALLOWED[own]:
                bad.append(f"{path.relative_to(ROOT)}:{line}: {own} imports {mod}")
    assert not bad, "imports against the package arrows:\n" + "\n".join(bad)


@pytest.mark.parametrize("package, may_import", [("psychophysics", {FOUNDATION}),
                                                  ("analysis", {FOUNDATION, "psychophysics", "figstyle"})])
def test_psychophysics_and_analysis_import_only_the_foundation_and_third_party_code(package, may_import):
    """psychophysics is a library on its own (psignifit's and questplus' kind): it imports the foundation and
    third-party code only, no figure style either; analysis adds psychophysics (fits) and the figure style."""
    bad = [f"{path.relative_to(ROOT)}:{line}: imports {mod}"
           for path in sorted((ROOT / package).rglob("*.py")) for mod, line, _ in imports_of(path)
           if mod.split(".")[0] in PROJECT - {package} - may_import]
    assert not bad, "\n".join(bad)


def test_the_foundation_imports_no_domain_package_and_domain_packages_hold_no_plumbing():
    domain = set(PACKAGES) - {FOUNDATION}
    bad = [f"{path.relative_to(ROOT)}:{line}: imports {mod}"
           for path in sorted((ROOT / FOUNDATION).rglob("*.py"))
           for mod, line, _ in imports_of(path) if mod.split(".")[0] in domain]
    assert not bad, "the foundation imports a domain package:\n" + "\n".join(bad)
    plumbing_modules = {p.name for p in (ROOT / FOUNDATION).glob("*.py")} - {"__init__.py", "__main__.py"}
    copies = [str(p.relative_to(ROOT)) for pkg in domain for p in sorted((ROOT / pkg).rglob("*.py"))
              if p.name in plumbing_modules]
    assert not copies, "plumbing modules outside plumbing/: " + ", ".join(copies)


def test_renderer_core_does_not_import_its_applications():
    bad = []
    for path in sorted((ROOT / "renderer").glob("*.py")):
        if path.name == "__main__.py":
            continue  # the command table names the demo's command module as a string, not an import
        for mod, line, _ in imports_of(path):
            if mod.startswith(APPLICATIONS):
                bad.append(f"{path.relative_to(ROOT)}:{line}: imports {mod}")
    assert not bad, "\n".join(bad)


def _graph(level):
    """Import graph between modules (level 'module') or between sub-packages (level 'subpackage')."""
    modules = {_module_name(p): p for p in all_modules()}

    def node(mod):
        while mod and mod not in modules:
            mod = mod.rpartition(".")[0]
        if not mod:
            return None
        path = modules[mod]
        if level == "subpackage":
            return ".".join(path.relative_to(ROOT).parts[:-1]) if path.parent != ROOT else mod
        return mod

    graph = {}
    for name, path in modules.items():
        src = node(name)
        for mod, _, _ in imports_of(path):
            if mod.rpartition(".")[0] in modules and mod in modules:
                pass  # ``from pkg import module``: the edge is to the module
            elif mod not in modules and mod.rpartition(".")[0] in modules:
                mod = mod.rpartition(".")[0]  # ``from module import name``
            dst = node(mod)
            # a module or sub-package using its parent package (devices.sim -> devices) is the layout, not a cycle
            if dst and dst != src and not src.startswith(dst + "."):
                graph.setdefault(src, set()).add(dst)
    return graph


def _cycles(graph):
    """Strongly connected components with more than one node (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in list(graph):
        if v not in index:
            strong(v)
    return out


@pytest.mark.parametrize("level", ["subpackage", "module"])
def test_no_import_cycles(level):
    assert _cycles(_graph(level)) == []


def _unmarked_function_imports(path: Path, root: Path = ROOT) -> list[str]:
    """Imports inside functions of ``path`` without a ``# deferred: <why>`` comment on their first or last line."""
    src, tree = parsed(path)
    lines = src.splitlines()
    out = []

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)) and in_function:
                ends = {lines[child.lineno - 1].partition("#")[2].strip(), lines[child.end_lineno - 1].partition("#")[2].strip()}
                if not any(c.startswith("deferred:") and len(c) > len("deferred:") + 3 for c in ends):
                    out.append(f"{path.relative_to(root)}:{child.lineno}: {lines[child.lineno - 1].strip()}")
            visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)))

    visit(tree, False)
    return out


def test_imports_sit_at_the_top_unless_deferred_with_a_reason():
    """A file's header says what it depends on: an import inside a function is allowed only to keep
    start-up fast or to reach an optional system library, and says so (``# deferred: <why>``)."""
    bad = [hit for path in all_modules() + sorted((ROOT / "benchmarks").rglob("*.py"))
           for hit in _unmarked_function_imports(path)]
    assert not bad, f"{len(bad)} function-level imports without '# deferred: <why>':\n" + "\n".join(bad)


#: the most imports inside functions the source may hold (issue 33): each one a measured start-up figure. The 3-DOF
#: adapters add three: the registry's branch to them (0.13 s CPU a simulated run does not pay), the optional Force
#: Dimension bindings (they load the vendor's SDK at import: only a dhd device may) and numba for the Touch's servo
#: callback (0.3 s CPU, only when a Touch opens). The study adds two: scipy.signal (1.0 s CPU) for the simulated
#: rater's features and for resampling spoken cues, which a lab's keyboard session and its servo process never use
MAX_DEFERRED = 26
#: a deferred import's comment states its measured cost: a number with its unit (``0.3 s``, ``19 ms``)
MEASURED = re.compile(r"\d+(\.\d+)?\s*(ms|s)\b")


def deferred_imports(path: Path, root: Path = ROOT) -> list[tuple[str, str]]:
    """(``file:line``, its ``# deferred:`` comment) of every import inside a function of ``path``."""
    src, tree = parsed(path)
    lines = src.splitlines()
    out = []

    def visit(node, in_function):
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.Import, ast.ImportFrom)) and in_function:
                ends = [lines[child.lineno - 1].partition("#")[2], lines[child.end_lineno - 1].partition("#")[2]]
                why = next((c.strip() for c in ends if c.strip().startswith("deferred:")), "")
                out.append((f"{path.relative_to(root)}:{child.lineno}", why))
            visit(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)))

    visit(tree, False)
    return out


def test_at_most_max_deferred_imports_each_with_its_measured_cost():
    """A command's body imports at its top (its parser module is apart: plumbing.dispatch.Body); an import
    inside a function is left only where a measured start-up figure needs it, and its comment says how much."""
    found = [hit for path in all_modules() + sorted((ROOT / "benchmarks").rglob("*.py"))
             for hit in deferred_imports(path)]
    assert len(found) <= MAX_DEFERRED, f"{len(found)} imports inside functions (at most {MAX_DEFERRED}):\n" + \
        "\n".join(where for where, _ in found)
    unmeasured = [f"{where}: {why}" for where, why in found if not MEASURED.search(why)]
    assert not unmeasured, "deferred imports without their measured cost (e.g. '0.3 s', '19 ms'):\n" + \
        "\n".join(unmeasured)


def test_the_deferred_import_count_reads_comments_and_costs(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("import os\n\ndef f():\n    import json  # deferred: 12 ms CPU\n    import y  # deferred: heavy\n")
    found = deferred_imports(f, tmp_path)
    assert [where for where, _ in found] == ["m.py:4", "m.py:5"]
    assert [bool(MEASURED.search(why)) for _, why in found] == [True, False]


def test_the_deferred_import_check_finds_an_unmarked_import(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("import os\n\ndef f():\n    import json\n    from x import (a,\n        b)  # deferred: x is heavy\n"
                 "    import y  # just a note\n    return os, json\n")
    hits = _unmarked_function_imports(f, tmp_path)
    assert [h.split(":")[1] for h in hits] == ["4", "7"]


#: the attempt's steps (the present/ask sequence): called only by the attempt loop, and by the apparatus that
#: implements them (its servo process forwards them)
ATTEMPT_STEPS = {"tap_window", "cue_tap", "cue_rate", "request_confirm", "after_window"}
STEP_CALLERS = {"study/session/loop.py", "study/session/apparatus.py", "study/session/apparatus3.py",
                "study/session/isolated.py"}
#: the durable writes of a subject's files: only the store makes them
STORE = "study/session/store.py"


def _calls(path: Path):
    """(line, callee name, the call node) of every call in ``path``: ``f(...)`` -> ``f``, ``x.f(...)`` -> ``f``."""
    for node in ast.walk(parsed(path)[1]):
        if isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            owner = func.value.id if isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name) else ""
            yield node.lineno, owner, name, node


def _append_mode(call: ast.Call) -> bool:
    """``open(path, "a...")`` (or ``mode="a..."``)."""
    modes = [a for a in call.args[1:2]] + [k.value for k in call.keywords if k.arg == "mode"]
    return any(isinstance(m, ast.Constant) and isinstance(m.value, str) and "a" in m.value for m in modes)


def test_only_the_session_machinery_runs_an_attempt_and_writes_a_subjects_files():
    """No module of ``study`` outside ``study/session/`` repeats the store or the loop: the attempt's steps
    (place and confirm, cue, tapping window, homing after it, the spoken question) are called by the loop only
    (kinds compose them through ``SessionLoop.present`` and ``ask``), and only the store fsyncs, writes to a
    descriptor or opens a file for appending (the row log, the JSON-lines files)."""
    bad = []
    for path in sorted((ROOT / "study").rglob("*.py")):
        rel = str(path.relative_to(ROOT))
        for line, owner, name, call in _calls(path):
            if name in ATTEMPT_STEPS and rel not in STEP_CALLERS:
                bad.append(f"{rel}:{line}: calls {name}() (the attempt loop's step: study.session.loop)")
            if rel != STORE and ((owner == "os" and name in ("fsync", "write", "open")) or
                                 (name == "open" and _append_mode(call))):
                bad.append(f"{rel}:{line}: {owner + '.' if owner else ''}{name}(): a durable write outside the store")
    assert not bad, "\n".join(bad)


def test_the_session_rule_finds_a_kind_that_runs_its_own_window(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("import os\ndef run(app, fh, path):\n    app.tap_window(5.0, 5.0)\n    os.fsync(fh.fileno())\n"
                 "    open(path, 'ab')\n    open(path, mode='a')\n    open(path)\n")
    found = [(line, name) for line, _, name, call in _calls(f)
             if name in ATTEMPT_STEPS or name == "fsync" or (name == "open" and _append_mode(call))]
    assert found == [(3, "tap_window"), (4, "fsync"), (5, "open"), (6, "open")]


# -- words for users: the README, docs/ and the packages' strings speak of the product, not of its history --------

#: "issue 16", "issues 34-35", "issue #38", "(#38)": the tracker's numbers belong in CHANGELOG.md's history at most
#: (not an HTML entity "&#42;", a CSS colour "color:#222", a hex colour "#1f77b4" or a C preprocessor "#if 0")
ISSUE_REF = re.compile(r"\b[Ii]ssues?\s*#?\d+|(?<![\w&:])#\d{1,3}\b(?![\w-])")
#: a working folder of the developers' machines (ships with nobody)
DEV_PATH = re.compile(r"/work/(?:main|wt)\b|/tmp/bash_jobs|\.\./shared/")
USER_DOCS = ("README.md", "docs")


def _user_doc_files():
    out = [ROOT / "README.md"]
    out += sorted(p for p in (ROOT / "docs").rglob("*.md"))
    return out


def _string_constants(path: Path):
    """(line, text) of every string constant (docstrings included) and every comment of a module."""
    src, tree = parsed(path)
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            yield node.lineno, node.value
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):   # comments only: a '#' inside a string is not one
        if tok.type == tokenize.COMMENT:
            yield tok.start[0], tok.string


def issue_words(text: str) -> list[str]:
    return [m.group(0) for m in ISSUE_REF.finditer(text)] + [m.group(0) for m in DEV_PATH.finditer(text)]


def test_no_issue_numbers_or_working_paths_in_the_readme_docs_or_the_packages_strings():
    found = []
    for path in _user_doc_files():
        for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            found += [f"{path.relative_to(ROOT)}:{i}: {w!r}" for w in issue_words(line)]
    for path in all_modules() + sorted((ROOT / "benchmarks").rglob("*.py")) + sorted((ROOT / "figstyle").rglob("*.py")):
        for line, text in _string_constants(path):
            found += [f"{path.relative_to(ROOT)}:{line}: {w!r}" for w in issue_words(text)]
    assert not found, "history belongs in CHANGELOG.md:\n" + "\n".join(found[:60])


@pytest.mark.parametrize("text, hits", [
    ("as issue 16 measured", 1), ("(issues 34 and 35)", 1), ("see #38.", 1), ("Issue #4's rule", 1),
    ("Table 3.1, eq. 5.14, section 4.4.3", 0), ("colour #1f77b4", 0), ("a C++ #include", 0), ("&#38;", 0),
    ("/work/main/study/x.py", 1), ("../shared/seed", 1), ("body{color:#222;margin:0}", 0), ("#if 0", 0),
])
def test_the_history_check_finds_what_it_should(text, hits):
    assert len(issue_words(text)) == hits


def test_the_history_check_reads_comments_not_hashes_inside_strings(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('x = "&#42;"  # as issue 16 measured\ny = 1\n', encoding="utf-8")
    found = [(line, w) for line, text in _string_constants(f) for w in issue_words(text)]
    assert found == [(1, "issue 16")]


def test_the_readme_is_a_front_door():
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    assert len(lines) < 250, f"README.md has {len(lines)} lines: reference material belongs in docs/"
    text = "\n".join(lines)
    assert "make demo" in text and "make test" in text
