"""The shipped artefacts derived from the simulation: rebuilt by one command, stamped, checked cheaply.

Some files of the repository are results of the project's own code on the simulated device: the default HFAM
library the catalog's HFAM samples play, the docs' figure gallery (the simulated demo and a simulated
16-subject study) and the README's figures. Each is an :class:`Artefact`: what it is (``outputs``), the
sources whose content makes it (``inputs``), and the command that rebuilds it. ``python -m plumbing.artefacts
rebuild`` (``make artefacts``) runs every command, in order, and writes beside each artefact a stamp
(``stamp``, JSON): the SHA-256 of its inputs and of every file it wrote. :func:`check` compares the stamps
with the sources and the files as they are now -- no rebuild, a fraction of a second -- and names every
artefact whose code or parameters changed since it was made, or whose files were edited by hand
(``tests/plumbing/test_artefacts.py`` runs it).

The commands run the other packages' own commands in subprocesses (``python -m ...``); this module imports
none of them.
"""

from __future__ import annotations

import argparse
import ast
import hashlib
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from .fileio import user_cache_dir

ROOT = Path(__file__).resolve().parents[1]
#: the files of an input tree that make results (code, parameters, data the code reads); caches and tests aside
INPUT_SUFFIXES = (".py", ".toml", ".json", ".mplstyle", ".npz")
STAMP_VERSION = 1


@dataclass(frozen=True)
class Artefact:
    """One shipped artefact.

    Attributes
    ----------
    name : str
        Short name (``rebuild NAME``).
    outputs : tuple of str
        Files or folders it consists of, relative to the repository.
    inputs : tuple of str
        Source files or folders whose content makes it (:data:`INPUT_SUFFIXES` inside folders).
    command : tuple of str
        ``python`` arguments that rebuild it, run from the repository.
    stamp : str
        Its stamp file, relative to the repository.
    """

    name: str
    outputs: tuple
    inputs: tuple
    command: tuple
    stamp: str


#: the code and parameters of the simulated device, its identification and the HFAM pipeline
_SIM_PIPELINE = ("devices/sim", "devices/identify", "devices/model.py", "devices/recording.py", "devices/registry.py",
                 "devices/base.py", "stimuli/hfam", "stimuli/library.py", "stimuli/recordings.py")

ARTEFACTS = (
    Artefact("hfam-library", ("stimuli/libraries/wood_on_foam_sim.npz",), _SIM_PIPELINE,
             ("-m", "stimuli", "sim-library", "--out", "stimuli/libraries/wood_on_foam_sim.npz", "--force"),
             "stimuli/libraries/wood_on_foam_sim.stamp.json"),
    # the gallery's study plays the library above (the catalog's HFAM samples), so it comes after it
    Artefact("gallery", ("docs/gallery", "docs/img/demo_penetration.png", "docs/img/teleop_figure_5_11.png"),
             ("devices", "stimuli", "renderer", "study", "analysis", "figstyle"),
             ("-m", "figstyle.gallery", "--out", "docs/gallery", "--readme-figures", "docs/img"),
             "docs/gallery/artefact.stamp.json"),
)


def _files(rel: str, suffixes=None, root: Path = ROOT) -> list[Path]:
    p = root / rel
    if p.is_file():
        return [p]
    if not p.is_dir():
        return []
    return sorted(f for f in p.rglob("*") if f.is_file() and "__pycache__" not in f.parts
                  and (suffixes is None or f.suffix in suffixes))


def _code_of(data: bytes) -> bytes:
    """A Python module's code without its comments, docstrings and layout (the AST's dump): rewording a comment
    or a docstring does not make an artefact stale, a changed statement or constant does. A module that does not
    parse is taken as its bytes."""
    try:
        tree = ast.parse(data)
    except (SyntaxError, ValueError):
        return data.replace(b"\r\n", b"\n")
    for node in ast.walk(tree):
        body = getattr(node, "body", None)
        if (isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and body
                and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                and isinstance(body[0].value.value, str)):
            node.body = body[1:] or [ast.Pass()]
    return ast.dump(tree).encode()


def inputs_digest(artefact: Artefact, root: Path = ROOT) -> str:
    """SHA-256 over the names and contents of the artefact's input files (line endings normalised; Python
    modules by their code, :func:`_code_of`).

    Parsing and dumping the modules' syntax trees takes about 2 s of CPU for the gallery's ~290 files, and
    every sim demo checks the gallery's stamp: the digest is kept by the files' raw names and bytes (plus this
    module and the Python version, which make the syntax-tree dump), in the process and, for the repository's
    own files, in the user cache (:func:`_known_digest`). Reading and hashing the raw bytes takes milliseconds.
    """
    files = [(f.relative_to(root).as_posix(), f.suffix, f.read_bytes()) for rel in artefact.inputs
             for f in _files(rel, INPUT_SUFFIXES, root)]
    raw = hashlib.sha256(_DIGEST_CODE)
    for name, _suffix, data in files:
        raw.update(b"%d:%s%d:" % (len(name.encode()), name.encode(), len(data)))
        raw.update(data)
    key = raw.hexdigest()
    known = _known_digest(key, root)
    if known is not None:
        return known
    h = hashlib.sha256()
    for name, suffix, data in files:
        h.update(name.encode())
        if suffix == ".py":
            data = _code_of(data)
        h.update(data if suffix == ".npz" else data.replace(b"\r\n", b"\n"))
    digest = h.hexdigest()
    _remember_digest(key, digest, root)
    return digest


#: what besides the input files makes :func:`inputs_digest`: this module's code and the Python whose ``ast`` dumps
_DIGEST_CODE = hashlib.sha256(Path(__file__).read_bytes() + sys.version.encode()).digest()
#: raw key -> inputs digest, for this process
_DIGESTS: dict = {}


def _digest_file(key: str) -> Path:
    """Where the user cache keeps the inputs digest of the raw key ``key`` (``plumbing.fileio.user_cache_dir``)."""
    return user_cache_dir() / "artefact-inputs" / f"{key[:32]}.sha256"


def _known_digest(key: str, root: Path):
    """The inputs digest already computed for the raw key ``key`` (None if none is known)."""
    if key in _DIGESTS:
        return _DIGESTS[key]
    if Path(root).resolve() != ROOT:
        return None
    try:
        text = _digest_file(key).read_text(encoding="ascii").split()
    except (OSError, ValueError):
        return None
    # the file holds the whole raw key, then the digest: a truncated or foreign file is ignored
    if len(text) == 2 and text[0] == key and len(text[1]) == 64:
        _DIGESTS[key] = text[1]
        return text[1]
    return None


def _remember_digest(key: str, digest: str, root: Path) -> None:
    """Keep ``digest`` for the raw key ``key``: in this process, and in the user cache for the repository's files
    (written aside and renamed, so a concurrent reader sees all of it or nothing; a cache that cannot be written
    is skipped)."""
    _DIGESTS[key] = digest
    if Path(root).resolve() != ROOT:
        return
    path = _digest_file(key)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_text(f"{key} {digest}\n", encoding="ascii")
        os.replace(tmp, path)
    except OSError:
        pass


def output_digests(artefact: Artefact, root: Path = ROOT) -> dict:
    """``relative path -> SHA-256`` of every file of the artefact (its stamp aside)."""
    stamp = (root / artefact.stamp).resolve()
    out = {}
    for rel in artefact.outputs:
        for f in _files(rel, None, root):
            if f.resolve() != stamp:
                out[f.relative_to(root).as_posix()] = hashlib.sha256(f.read_bytes()).hexdigest()
    return out


def write_stamp(artefact: Artefact, root: Path = ROOT) -> Path:
    """Stamp the artefact as it is now (its inputs' and files' digests)."""
    path = root / artefact.stamp
    record = {"artefact": artefact.name, "version": STAMP_VERSION, "command": "python " + " ".join(artefact.command),
              "inputs": list(artefact.inputs), "inputs_sha256": inputs_digest(artefact, root),
              "outputs_sha256": output_digests(artefact, root)}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n", encoding="utf-8")
    tmp.replace(path)
    return path


def stale(artefact: Artefact, root: Path = ROOT) -> list[str]:
    """Why the artefact no longer matches its stamp (empty if it does): a missing stamp, changed inputs, files
    edited, added or removed since the stamp."""
    path = root / artefact.stamp
    try:
        record = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return [f"{artefact.stamp}: no readable stamp"]
    why = []
    if record.get("inputs_sha256") != inputs_digest(artefact, root):
        why.append(f"its inputs ({', '.join(artefact.inputs)}) changed since it was made")
    now, then = output_digests(artefact, root), record.get("outputs_sha256", {})
    for rel in sorted(set(now) | set(then)):
        if now.get(rel) != then.get(rel):
            why.append(f"{rel} {'added' if rel not in then else 'removed' if rel not in now else 'edited'} since the "
                       "stamp")
    return why


def check(names=None) -> dict:
    """``name -> reasons`` for every stale artefact of ``names`` (default all); empty when all are current."""
    return {a.name: r for a in ARTEFACTS if names is None or a.name in names for r in [stale(a)] if r}


def is_current(name: str) -> bool:
    """True if the artefact ``name`` matches its stamp."""
    return not check([name])


def rebuild(names=None, python: str = sys.executable, log=print) -> None:
    """Run the commands of ``names`` (default every artefact, in order) and stamp each.

    Raises
    ------
    RuntimeError
        A command failed (its output is shown); the artefacts rebuilt before it keep their new stamps.
    """
    for a in ARTEFACTS:
        if names is not None and a.name not in names:
            continue
        log(f"rebuilding {a.name}: python {' '.join(a.command)}")
        t0 = time.monotonic()
        proc = subprocess.run([python, *a.command], cwd=ROOT, text=True, capture_output=True)
        if proc.returncode != 0:
            sys.stderr.write(proc.stdout[-3000:] + proc.stderr[-4000:])
            raise RuntimeError(f"{a.name}: python {' '.join(a.command)} failed with exit code {proc.returncode}")
        log(f"  done in {time.monotonic() - t0:.0f} s; stamp {write_stamp(a).relative_to(ROOT)}")


def main(argv=None) -> int:
    """``python -m plumbing.artefacts rebuild [NAME ...]`` / ``check [NAME ...]``."""
    p = argparse.ArgumentParser(prog="python -m plumbing.artefacts", description=__doc__.splitlines()[0])
    p.add_argument("action", choices=("rebuild", "check"), help="rebuild and stamp, or compare the stamps (cheap)")
    p.add_argument("names", nargs="*", help="artefacts (default all): " + ", ".join(a.name for a in ARTEFACTS))
    args = p.parse_args(argv)
    unknown = set(args.names) - {a.name for a in ARTEFACTS}
    if unknown:
        print(f"error: unknown artefact(s) {', '.join(sorted(unknown))}; known: "
              f"{', '.join(a.name for a in ARTEFACTS)}", file=sys.stderr)
        return 2
    names = args.names or None
    if args.action == "rebuild":
        try:
            rebuild(names)
        except RuntimeError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
        return 0
    bad = check(names)
    for name, why in bad.items():
        print(f"{name}: stale ({'; '.join(why)}); rebuild with: make artefacts")
    if not bad:
        print("every artefact matches the code that made it")
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
