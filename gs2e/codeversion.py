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
functions), the packages' ``__init__.py`` on the way (their module level: a
package's lazy ``__getattr__`` runs only when a name is imported from the
package itself), and, in modules that import by name with ``importlib`` or
through :mod:`gs2e.common.registry`, the gs2e modules their string constants
name (lazy import tables and registries: ``module`` or ``module:function``). Not followed:
the dispatcher's list of the other stages' CLI modules, which ``gs2e`` imports only to declare their subcommands'
arguments. No list is kept by hand, so a new import is covered the moment it is
written (tests/test_codeversion.py runs each stage and checks that every gs2e
module it loaded is covered). The installed versions of the few other
packages that ship results of their own (network weights, :data:`VERSIONED`)
join the hash of the stages that import them.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import os
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
    # one CLI module, two rules: the dataset table does not run the tasks
    "bench": "gs2e.bench.cli:run_bench",
    "bench_summary": "gs2e.bench.cli:run_summary",
    "bench_real": "gs2e.bench.cli:run_real",
    "sim2real": "gs2e.bench.cli:run_sim2real",
    # one CLI module, two rules: the gate reads a scene's stats files, the datasheet a whole run
    "gate": "gs2e.dataset.cli:run_gate",
    "datasheet": "gs2e.dataset.cli:run_datasheet",
}
# What every stage's command goes through before its own module.
COMMAND_ROOTS = ("gs2e.__main__", "gs2e.cli")
# Its string constants name the stage CLIs it registers: not imports of a stage.
DISPATCHER = "gs2e.cli"
# Modules that import it name their registered code by strings (gs2e.common.registry).
REGISTRY = "gs2e.common.registry"
# Other packages whose version changes a stage's results beyond rounding (shipped
# network weights): {import name: distribution}. Their installed version joins the
# code version of every stage that imports them; numpy, torch and the like do not.
VERSIONED = {"pie_net": "event-pienet"}
# Plug-ins (gs2e.common.registry): a stage that imports a registry runs its group's
# installed plug-ins, whose names and versions join that stage's code version. (Not
# imported from gs2e.common.registry: importing it makes a module's gs2e names count.)
PLUGIN_REGISTRIES = {"gs2e.bench_tasks": "gs2e.bench.tasks", "gs2e.export_formats": "gs2e.export.formats",
                     "gs2e.event_models": "gs2e.events.models", "gs2e.sensors": "gs2e.events.sensors"}

_MODULE_NAME = re.compile(r"^[A-Za-z_]\w*(\.[A-Za-z_]\w*)*$")


def package_modules(pkg: Path | None = None) -> dict[str, Path]:
    """Every module of the package under ``pkg``: {``gs2e.a.b``: its .py file}
    (a package's name maps to its ``__init__.py``). One directory scan: a stat
    per imported name would cost more than parsing the sources."""
    pkg = PKG if pkg is None else pkg
    out: dict[str, Path] = {}
    for folder, dirs, files in os.walk(pkg):
        dirs[:] = [d for d in dirs if d != "__pycache__"]
        rel = Path(folder).relative_to(pkg).parts
        for fname in files:
            if fname.endswith(".py"):
                stem = fname[:-3]
                parts = (ROOT, *rel) if stem == "__init__" else (ROOT, *rel, stem)
                out.setdefault(".".join(parts), Path(folder) / fname)
    return out


def _statements(node: ast.AST):
    """``node`` and every statement nested in it (bodies of functions, classes,
    if/for/while/with/try/match), without descending into expressions: imports
    are statements, and skipping expressions makes the walk ~10x faster."""
    todo = [node]
    while todo:
        n = todo.pop()
        yield n
        for field in ("body", "orelse", "finalbody", "handlers", "cases"):
            sub = getattr(n, field, None)
            if isinstance(sub, list):
                todo.extend(sub)


def _imported_names(tree: ast.AST, module: str, is_package: bool, strings: bool) -> set[str]:
    """Module names a module's source imports anywhere (``from A import b``
    gives ``A.b`` and ``A``: ``b`` may be a submodule or an attribute); with
    ``strings``, also the gs2e module names its string constants spell."""
    out: set[str] = set()
    for node in _statements(tree):
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
    if strings:  # "module" or "module:function"
        names = (n.value.split(":")[0] for n in ast.walk(tree)
                 if isinstance(n, ast.Constant) and isinstance(n.value, str))
        out.update(v for v in names if v.startswith(ROOT + ".") and _MODULE_NAME.match(v))
    return out


# ``import_closure``'s mark for a package that runs only as the parent of an
# imported submodule: its module level runs, its functions (a lazy
# ``__getattr__`` and its table of names) do not.
ON_THE_WAY = "<parent>"


def _entry_nodes(tree: ast.Module, function: str) -> list[ast.AST]:
    """A CLI module's statements that run for one command: the module level,
    ``register`` (declares the arguments) and ``function``."""
    defs = (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)
    return [n for n in tree.body if not isinstance(n, defs) or n.name in ("register", function)]


@functools.lru_cache(maxsize=4096)
def _file_imports(f: Path, stamp: tuple[int, int], name: str, function: str) -> frozenset[str]:
    """What :func:`import_closure` follows from one source file (cached on the
    file's mtime and size: the workflow asks for every stage's version)."""
    tree = ast.parse(f.read_bytes(), filename=str(f))
    nodes = _entry_nodes(tree, function) if function else [tree]
    imported = _imported_names(tree, name, False, strings=False)
    by_name = (name != DISPATCHER and function != ON_THE_WAY
               and ("importlib" in imported or REGISTRY in imported))
    out: set[str] = set()
    for node in nodes:
        out |= _imported_names(node, name, f.name == "__init__.py", strings=by_name)
    return frozenset(out)


def import_closure(roots: tuple[str, ...], pkg: Path | None = None) -> dict[str, Path]:
    """Every gs2e module reachable from ``roots`` by imports, with its parent
    packages: {module name: source file}. A root ``module:function`` follows
    only what that function of the module runs (see :func:`_entry_nodes`); a
    package reached only as a submodule's parent, only its module level."""
    return _closure(roots, pkg)[0]


def _closure(roots: tuple[str, ...], pkg: Path | None = None) -> tuple[dict[str, Path], set[str]]:
    """(:func:`import_closure`, the top-level names of the other packages it imports)."""
    pkg = PKG if pkg is None else pkg
    modules = package_modules(pkg)
    external: set[str] = set()
    found: dict[str, Path] = {}
    partial: set[str] = set()  # modules followed for one function only so far
    todo = list(roots)
    while todo:
        name, _, function = todo.pop().partition(":")
        if name in found and not (name in partial and not function):
            continue
        f = modules.get(name)
        if f is None:
            if name.partition(".")[0] != ROOT:
                external.add(name.partition(".")[0])
            continue
        found[name] = f
        if function:
            partial.add(name)
        else:
            partial.discard(name)
        parts = name.split(".")
        # parent packages run first, their module level only (a lazy table's
        # targets load when one of its names is imported from the package)
        todo.extend(f"{'.'.join(parts[:i])}:{ON_THE_WAY}" for i in range(1, len(parts)))
        st = f.stat()
        todo.extend(_file_imports(f, (st.st_mtime_ns, st.st_size), name, function))
    return found, external


def _stage_closure(stage: str, pkg: Path | None = None) -> tuple[dict[str, Path], set[str]]:
    if stage not in STAGE_ENTRY:
        raise KeyError(f"unknown stage '{stage}'")
    return _closure(COMMAND_ROOTS + (STAGE_ENTRY[stage],), pkg)


def stage_modules(stage: str, pkg: Path | None = None) -> dict[str, Path]:
    """The modules ``code_version(stage)`` covers: {module name: source file}."""
    return _stage_closure(stage, pkg)[0]


def _dist_version(dist: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return "absent"


def _plugin_versions(group: str) -> list[str]:
    """``name=dist==version`` of each installed plug-in of an entry-point group
    (read from the packages' metadata; nothing imported)."""
    from importlib.metadata import entry_points

    out = []
    for ep in sorted(entry_points(group=group), key=lambda e: e.name):
        dist = getattr(ep, "dist", None)
        out.append(f"{ep.name}={dist.name if dist else '?'}=={dist.version if dist else '?'}")
    return out


def _distributions(external: set[str]) -> dict[str, str]:
    return {VERSIONED[m]: _dist_version(VERSIONED[m]) for m in sorted(external & set(VERSIONED))}


def stage_distributions(stage: str) -> dict[str, str]:
    """{distribution: installed version} of the :data:`VERSIONED` packages the
    stage's import closure imports."""
    return _distributions(_stage_closure(stage)[1])


@functools.lru_cache(maxsize=None)
def code_version(stage: str) -> str:
    """Short sha256 over the source files of the stage's import closure
    (path relative to the package + content, in path order), the installed
    versions of the :data:`VERSIONED` packages it imports, and the installed
    plug-ins (names, packages, versions) of the registries it imports."""
    modules, external = _stage_closure(stage)  # one walk for both
    h = hashlib.sha256()
    for f in sorted(modules.values()):
        h.update(str(f.relative_to(PKG)).encode())
        h.update(b"\0")
        h.update(f.read_bytes())
        h.update(b"\0")
    for dist, ver in _distributions(external).items():
        h.update(f"{dist}=={ver}".encode())
        h.update(b"\0")
    for group, module in PLUGIN_REGISTRIES.items():
        if module in modules:
            for v in _plugin_versions(group):
                h.update(f"{group}:{v}".encode())
                h.update(b"\0")
    return h.hexdigest()[:16]
