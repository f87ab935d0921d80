"""Every public module-level function and class, and every public method of a public class, in the five
packages has a docstring. The failure lists the offenders as ``path:line name``."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("devices", "renderer", "stimuli", "study", "analysis")


def _public(name: str) -> bool:
    return not name.startswith("_")


def missing_docstrings() -> list[str]:
    """``path:line qualified.name`` of every public function, class or method without a docstring."""
    out = []
    for pkg in PACKAGES:
        for path in sorted((ROOT / pkg).rglob("*.py")):
            if path.name == "__main__.py" or any(part.startswith("_") and part != "__init__.py"
                                                 for part in path.relative_to(ROOT).parts):
                continue
            rel = path.relative_to(ROOT)
            for node in ast.parse(path.read_text(encoding="utf-8")).body:
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)) and _public(node.name):
                    if ast.get_docstring(node) is None:
                        out.append(f"{rel}:{node.lineno} {node.name}")
                    if isinstance(node, ast.ClassDef):
                        for item in node.body:
                            if (isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)) and _public(item.name)
                                    and ast.get_docstring(item) is None):
                                out.append(f"{rel}:{item.lineno} {node.name}.{item.name}")
    return out


def test_every_public_name_has_a_docstring():
    missing = missing_docstrings()
    assert not missing, f"{len(missing)} public names without a docstring:\n" + "\n".join(missing)
