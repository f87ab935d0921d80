"""plumbing.lazy: a package's names imported on first use, once."""

import subprocess
import sys
import textwrap

import pytest

from plumbing.lazy import lazy_exports


def _package(tmp_path, name: str) -> None:
    pkg = tmp_path / name
    pkg.mkdir()
    (pkg / "__init__.py").write_text(textwrap.dedent("""
        from plumbing.lazy import lazy_exports
        _EXPORTS = {"VALUE": "heavy", "twice": "heavy"}
        __all__ = list(_EXPORTS)
        __getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
    """))
    (pkg / "heavy.py").write_text("import sys\nsys.heavy_loads = getattr(sys, 'heavy_loads', 0) + 1\n"
                                  "VALUE = 42\ndef twice(x):\n    return 2 * x\n")


def test_a_name_loads_its_module_on_first_use_only(tmp_path):
    _package(tmp_path, "lazypkg")
    code = ("import sys, lazypkg\n"
            "assert 'lazypkg.heavy' not in sys.modules\n"
            "assert {'VALUE', 'twice'} <= set(dir(lazypkg))\n"
            "assert 'lazypkg.heavy' not in sys.modules\n"
            "assert lazypkg.VALUE == 42 and lazypkg.twice(3) == 6\n"
            "from lazypkg import VALUE\n"
            "assert sys.heavy_loads == 1 and 'VALUE' in vars(lazypkg)\n"
            "try:\n    lazypkg.nope\nexcept AttributeError as exc:\n    print(exc)\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "module 'lazypkg' has no attribute 'nope'"


def test_an_unknown_name_is_an_attribute_error_naming_the_package():
    getattr_, dir_ = lazy_exports("plumbing", {"lazy_exports": "lazy"})
    assert getattr_("lazy_exports") is lazy_exports
    with pytest.raises(AttributeError, match="module 'plumbing' has no attribute 'missing'"):
        getattr_("missing")
    assert "lazy_exports" in dir_()
