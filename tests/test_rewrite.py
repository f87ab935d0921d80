"""pytest's rewritten test modules cached before the workers start (tests/support/rewrite.py)."""

import shutil
from pathlib import Path

from _pytest.assertion import rewrite as rw

from tests.support.rewrite import main, rewritten_files, write_rewritten

HERE = Path(__file__).resolve()


def test_the_cached_module_is_the_code_pytest_makes_for_this_run(tmp_path, pytestconfig, capsys):
    src = tmp_path / "tests" / "test_copy.py"
    src.parent.mkdir()
    shutil.copy(HERE, src)
    (src.parent / "helper.py").write_text("x = 1\n")      # not a test module: pytest imports it plainly
    assert rewritten_files(tmp_path) == [src]
    assert main([str(tmp_path)]) == 0
    assert "1 written, 0 up to date" in capsys.readouterr().out
    pyc = src.parent / "__pycache__" / ("test_copy" + rw.PYC_TAIL)
    cached = rw._read_pyc(src, pyc)
    assert cached is not None
    # the code this run's own rewriting (with this run's configuration) makes of the file (code objects compare
    # by their instructions, constants, names and nested code; marshal's bytes differ by its reference flags)
    assert cached == rw._rewrite_test(src, pytestconfig)[1]
    # and rewritten: not what plain compiling makes of it
    assert cached != compile(src.read_bytes(), str(src), "exec", dont_inherit=True)
    assert not write_rewritten(src)                                   # up to date: left alone
    src.write_text(src.read_text() + "\n\ndef test_more():\n    assert 1 == 1\n")
    assert rw._read_pyc(src, pyc) is None                            # an edit invalidates it (hash checked)
    assert write_rewritten(src) and rw._read_pyc(src, pyc) is not None
