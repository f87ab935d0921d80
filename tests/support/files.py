"""Content hashes for the tests that check no data already written is lost or replaced."""

import hashlib
from pathlib import Path


def sha256(path: Path) -> str:
    """SHA-256 hex digest of a file's bytes."""
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def tree_hashes(folder: Path) -> dict:
    """``{relative path: sha256}`` of every file below ``folder`` (sorted, recursive)."""
    folder = Path(folder)
    return {str(p.relative_to(folder)): sha256(p) for p in sorted(folder.rglob("*")) if p.is_file()}
