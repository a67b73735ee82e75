"""Version of the library code each workflow rule depends on.

Snakemake reruns a job when its params change, but not when an imported
library changes. Each rule therefore carries ``code_version(stage)`` in its
params: a hash of the source files the stage can run, so an edit reruns the
stages that import the edited module and nothing else.

Which files: the import closure of the stage's command (``python -m gs2e
<stage>``): ``gs2e/__main__.py``, the dispatcher ``gs2e/cli.py`` and the
stage's CLI module (``STAGE_ENTRY``; ``module:function`` where one CLI module
serves two rules: then only that function's and ``register``'s imports and the
module-level ones are followed), then every gs2e module they import,
transitively, read from the sources with ``ast``: module-level and
function-level imports alike (a stage's heavy imports sit inside its
functions), the packages' ``__init__.py`` on the way, and, in modules that
import by name with ``importlib``, the gs2e modules their string constants
name (lazy import tables). Not followed: the dispatcher's list of the other stages' CLI modules, which ``gs2e`` imports only
to declare their subcommands' arguments. No list is kept by hand, so a new
import is covered the moment it is written (tests/test_codeversion.py runs each
stage and checks that every gs2e module it loaded is covered).
"""

from __future__ import annotations

import ast
import functools
import hashlib
import re
from pathlib import Path

PKG = Path(__file__).resolve().parent
ROOT = PKG.name  # "gs2e"

# The module whose functions each stage's command runs (gs2e.cli.STAGE_CLIS).
STAGE_ENTRY: dict[str, str] = {
    "demo": "gs2e.demo.cli",
    "ingest": "gs2e.io.cli",
    "sfm": "gs2e.sfm.cli",
    "train": "gs2e.splat.cli",
    "trajectory": "gs2e.trajectory.cli",
    "render": "gs2e.render.cli",
    "events": "gs2e.events.cli",
    "metrics": "gs2e.metrics.cli",
    "report": "gs2e.report.cli",
    # one CLI module, two rules: the windows table does not read exporters' code
    "windows": "gs2e.export.cli:run_windows",
    "export": "gs2e.export.cli:run_export",
}
# What every stage's command goes through before its own module.
COMMAND_ROOTS = ("gs2e.__main__", "gs2e.cli")
# Its string constants name the stage CLIs it registers: not imports of a stage.
DISPATCHER = "gs2e.cli"

_MODULE_NAME = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")


def module_file(name: str, pkg: Path | None = None) -> Path | None:
    """Source file of gs2e module ``name`` (``gs2e.a.b`` -> a/b.py or
    a/b/__init__.py under ``pkg``), None if it is not a gs2e module."""
    pkg = PKG if pkg is None else pkg
    parts = name.split(".")
    if parts[0] != ROOT:
        return None
    base = pkg.joinpath(*parts[1:])
    for f in (base.with_suffix(".py") if len(parts) > 1 else None, base / "__init__.py"):
        if f is not None and f.is_file():
            return f
    return None


def _imported_names(tree: ast.AST, module: str, is_package: bool, strings: bool) -> set[str]:
    """Module names a module's source imports anywhere (``from A import b``
    gives ``A.b`` and ``A``: ``b`` may be a submodule or an attribute)."""
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the module's package
                base_parts = module.split(".")[: len(module.split(".")) - node.level + is_package]
                base = ".".join(base_parts + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names if a.name != "*")
        elif strings and isinstance(node, ast.Constant) and isinstance(node.value, str) \
                and node.value.startswith(ROOT + ".") and _MODULE_NAME.match(node.value):
            out.add(node.value)
    return out


def _entry_nodes(tree: ast.Module, function: str) -> list[ast.AST]:
    """A CLI module's statements that run for one command: the module level,
    ``register`` (declares the arguments) and ``function``."""
    defs = (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)
    return [n for n in tree.body if not isinstance(n, defs) or n.name in ("register", function)]


def import_closure(roots: tuple[str, ...], pkg: Path | None = None) -> dict[str, Path]:
    """Every gs2e module reachable from ``roots`` by imports, with its parent
    packages: {module name: source file}. A root ``module:function`` follows
    only what that function of the module runs (see :func:`_entry_nodes`)."""
    pkg = PKG if pkg is None else pkg
    found: dict[str, Path] = {}
    partial: set[str] = set()  # modules followed for one function only so far
    todo = list(roots)
    while todo:
        name, _, function = todo.pop().partition(":")
        if name in found and not (name in partial and not function):
            continue
        f = module_file(name, pkg)
        if f is None:
            continue
        found[name] = f
        if function:
            partial.add(name)
        else:
            partial.discard(name)
        parts = name.split(".")
        todo.extend(".".join(parts[:i]) for i in range(1, len(parts)))  # parent packages run first
        tree = ast.parse(f.read_bytes(), filename=str(f))
        nodes = _entry_nodes(tree, function) if function else [tree]
        by_name = name != DISPATCHER and "importlib" in _imported_names(tree, name, False, strings=False)
        for node in nodes:
            todo.extend(_imported_names(node, name, f.name == "__init__.py", strings=by_name))
    return found


def stage_modules(stage: str, pkg: Path | None = None) -> dict[str, Path]:
    """The modules ``code_version(stage)`` covers: {module name: source file}."""
    if stage not in STAGE_ENTRY:
        raise KeyError(f"unknown stage '{stage}'")
    return import_closure(COMMAND_ROOTS + (STAGE_ENTRY[stage],), pkg)


@functools.lru_cache(maxsize=None)
def code_version(stage: str) -> str:
    """Short sha256 over the source files of the stage's import closure
    (path relative to the package + content, in path order)."""
    h = hashlib.sha256()
    for f in sorted(stage_modules(stage).values()):
        h.update(str(f.relative_to(PKG)).encode())
        h.update(b"\0")
        h.update(f.read_bytes())
        h.update(b"\0")
    return h.hexdigest()[:16]
