"""A scenes table from user-supplied scene id lists (the paper's MVImgNet + DL3DV selection).

The paper selects 1,000 MVImgNet clips and 50 DL3DV scenes but does not publish
the ids; the user supplies them as text files (one id per line, ``#`` comments).
This module maps ids to folders by each dataset's release layout and writes a
``config/scenes.tsv``-style table:

MVImgNet
    ``<root>/<category>/<clip>`` holding ``images/`` + ``sparse/0`` (layout
    ``mvimgnet``). An id is ``category/clip``; a bare ``clip`` is looked up as
    ``<root>/*/<clip>`` (needs the data, so not with ``check=False``).
DL3DV
    ``<root>/<scene_hash>`` holding ``images_N/`` + ``transforms.json`` (or
    ``nerfstudio/``; layout ``dl3dv``). An id is the hash or a path below the
    root such as ``1K/<hash>`` (the subset folders of DL3DV-ALL); a bare hash
    missing at ``<root>/<hash>`` is looked up as ``<root>/*/<hash>``.

Scene ids are ``mvi_<category>_<clip>`` and ``dl3dv_<hash>``, every character
outside ``[A-Za-z0-9_.-]`` replaced by ``_`` (the workflow's wildcard constraint).
"""

from __future__ import annotations

import logging
import os
import re
from dataclasses import dataclass
from pathlib import Path

from gs2e.common.atomic import atomic_path
from gs2e.common.errors import ConfigError, InputError

log = logging.getLogger("gs2e.scenes")

# dataset -> (scene layout, scene_id prefix, paper's per-scene overrides)
DATASETS = {
    "mvimgnet": ("mvimgnet", "mvi", "ingest.max_views=30"),
    "dl3dv": ("dl3dv", "dl3dv", "ingest.max_views=100"),
}
_ID_CHARS = re.compile(r"^[A-Za-z0-9_.\-/]+$")
_UNSAFE = re.compile(r"[^A-Za-z0-9_.-]")
SCENE_ID_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")  # = workflow wildcard constraint
HEADER = ("scene_id", "layout", "path", "overrides")
# Snakemake rejects a wildcard value ending in a unit repeated >= 20 times (PeriodicWildcardError)
_PERIODIC_TAIL = re.compile(r"(.+?)\1{19,99}$")


@dataclass(frozen=True)
class SceneId:
    """One id from a list file: the dataset-relative id and where it came from."""

    dataset: str
    id: str
    where: str  # "file:line"


def parse_id_list(text: str, where: str, dataset: str) -> list[SceneId]:
    """Parse an id list: one id per line, blank lines and ``#`` comments ignored.

    An id is a relative path below the dataset root (``category/clip`` or a
    hash); ``..``, absolute paths, whitespace inside an id, and duplicates are
    errors naming ``where:line``.
    """
    if dataset not in DATASETS:
        raise ConfigError(f"unknown dataset '{dataset}' (one of {', '.join(DATASETS)})")
    out: list[SceneId] = []
    seen: dict[str, str] = {}
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        loc = f"{where}:{lineno}"
        if not _ID_CHARS.match(line):
            raise InputError(f"{loc}: bad {dataset} id '{line}' (letters, digits, '_', '.', '-', '/' only)")
        parts = [p for p in line.split("/") if p]  # drops a trailing '/' and doubled separators
        if line.startswith("/") or any(p in ("..", ".") for p in parts) or not parts:
            raise InputError(f"{loc}: bad {dataset} id '{line}' (must be a relative path below the root)")
        key = "/".join(parts)
        if dataset == "mvimgnet" and len(parts) > 2:
            raise InputError(f"{loc}: bad mvimgnet id '{line}' (expected 'category/clip' or 'clip')")
        if key in seen:
            raise InputError(f"{loc}: duplicate {dataset} id '{key}' (first at {seen[key]})")
        seen[key] = loc
        out.append(SceneId(dataset, key, loc))
    return out


def read_id_list(path: str | Path, dataset: str) -> list[SceneId]:
    """Read and parse an id list file (see :func:`parse_id_list`)."""
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read {dataset} id list {path}: {exc}") from exc
    ids = parse_id_list(text, str(path), dataset)
    if not ids:
        raise InputError(f"{dataset} id list {path} has no ids")
    return ids


def scene_id_for(sid: SceneId) -> str:
    """Workflow-safe scene id, unsafe characters -> '_': ``mvi_<category>_<clip>`` (give
    the resolved ``category/clip``), ``dl3dv_<hash>`` (the last path component: the
    subset folder is not part of a DL3DV scene's identity)."""
    prefix = DATASETS[sid.dataset][1]
    name = sid.id.rsplit("/", 1)[-1] if sid.dataset == "dl3dv" else sid.id
    out = _UNSAFE.sub("_", f"{prefix}_{name}")
    assert SCENE_ID_RE.match(out), out
    if _PERIODIC_TAIL.search(out):
        raise InputError(f"{sid.where}: {sid.dataset} id '{sid.id}' gives scene_id '{out}', which ends "
                         f"in a repeated pattern that Snakemake rejects as a wildcard value")
    return out


def _looks_like_scene(dataset: str, folder: Path) -> bool:
    if dataset == "mvimgnet":
        return (folder / "images").is_dir()
    return any((folder / sub / "transforms.json").is_file() for sub in ("", "nerfstudio"))


def resolve_path(sid: SceneId, root: str | Path, check: bool = True) -> Path:
    """Folder of one scene under ``root``; with ``check`` it must exist and look like a scene
    of its dataset (MVImgNet: ``images/``; DL3DV: ``transforms.json`` or ``nerfstudio/``)."""
    root = Path(root)
    direct = root / sid.id
    bare = "/" not in sid.id
    if not check:
        if sid.dataset == "mvimgnet" and bare:
            raise InputError(f"{sid.where}: mvimgnet id '{sid.id}' has no category; without the "
                             f"data (--no-check) ids must be 'category/clip'")
        return direct
    if not direct.is_dir() and bare and root.is_dir():
        hits = sorted(p for p in root.glob(f"*/{sid.id}") if p.is_dir())
        if len(hits) > 1:
            raise InputError(f"{sid.where}: {sid.dataset} id '{sid.id}' matches several folders: "
                             f"{', '.join(map(str, hits[:5]))}")
        if hits:
            direct = hits[0]
    if not direct.is_dir():
        raise InputError(f"{sid.where}: {sid.dataset} id '{sid.id}': folder {direct} does not exist")
    if not _looks_like_scene(sid.dataset, direct):
        need = "images/" if sid.dataset == "mvimgnet" else "transforms.json (or nerfstudio/transforms.json)"
        raise InputError(f"{sid.where}: {sid.dataset} id '{sid.id}': {direct} has no {need}")
    return direct


def build_rows(selections: list[tuple[list[SceneId], str | Path, str]],
               check: bool = True) -> list[dict]:
    """Scenes-table rows for (ids, dataset root, overrides) triples, in list order.

    Raises InputError naming every id whose folder is missing (first 20) and
    ConfigError if two ids give the same scene id (e.g. ``clip`` and ``7/clip``).
    """
    rows: list[dict] = []
    by_scene: dict[str, SceneId] = {}
    missing: list[str] = []
    for ids, root, overrides in selections:
        for sid in ids:
            try:
                path = resolve_path(sid, root, check)
            except InputError as exc:
                missing.append(str(exc))
                continue
            canon = sid
            if sid.dataset == "mvimgnet" and "/" not in sid.id:  # bare clip: its category found
                canon = SceneId(sid.dataset, f"{path.parent.name}/{path.name}", sid.where)
            scene = scene_id_for(canon)
            if scene in by_scene:
                raise ConfigError(f"{sid.where}: id '{sid.id}' and {by_scene[scene].where}: id "
                                  f"'{by_scene[scene].id}' both give scene_id '{scene}'")
            by_scene[scene] = sid
            rows.append({"scene_id": scene, "layout": DATASETS[sid.dataset][0],
                         "path": str(path), "overrides": overrides or ""})
    if missing:
        more = f"\n... and {len(missing) - 20} more" if len(missing) > 20 else ""
        raise InputError(f"{len(missing)} scene(s) not found:\n" + "\n".join(missing[:20]) + more)
    return rows


def format_table(rows: list[dict], comment: str = "") -> str:
    """TSV text of the rows (header first; ``comment`` lines prefixed with '#')."""
    lines = [f"# {c}" if c else "#" for c in comment.splitlines()]
    lines.append("\t".join(HEADER))
    for r in rows:
        cells = [r.get(k, "") for k in HEADER]
        for c in cells:
            if "\t" in c or "\n" in c:
                raise ConfigError(f"scene '{r['scene_id']}': a cell contains a tab or newline: {c!r}")
        lines.append("\t".join(cells))
    return "\n".join(lines) + "\n"


def write_scenes_table(rows: list[dict], out: str | Path, comment: str = "") -> list[dict]:
    """Write the table atomically after checking it reads back through
    ``gs2e.config.load_scenes`` and every row's overrides validate; returns the rows read."""
    from gs2e.config import load_config, load_scenes, scene_config

    base = load_config({})
    checked: dict[str, dict] = {}
    for row in rows:  # overrides are often shared: validate each distinct string once
        if row.get("overrides", "") not in checked:
            checked[row.get("overrides", "")] = scene_config(base, row)
    text = format_table(rows, comment)
    with atomic_path(out) as tmp:
        tmp.write_text(text)
        table = load_scenes(tmp)
    return table


def source_files(path: str | Path) -> list[str]:
    """Every file of a scene's source: ``path`` itself if it is a file, else the
    regular files below it (symbolic links followed, each folder once; names
    starting with ``.``, dangling links, FIFOs and sockets skipped), sorted;
    ``[path]`` if it does not exist (the caller names it).

    These are the ingest rule's inputs. Listed as files, not as the folder, so
    that Snakemake judges a copy by its content: after a copy that gives every
    file a new mtime but keeps its bytes (a dataset staged to a cluster, an
    rsync without ``-t``), Snakemake compares each newer file with the checksum
    it recorded when ingest ran (files up to ``--max-checksum-file-size``) and
    reruns nothing; a folder's mtime alone would rerun every stage of the
    scene. A changed, added or removed file reruns the scene.
    """
    p = Path(path)
    if not p.is_dir():
        return [str(p)]
    out, seen = [], set()
    for root, dirs, files in os.walk(p, followlinks=True):
        st = os.stat(root)
        if (st.st_dev, st.st_ino) in seen:  # a link back up the tree: walked already
            dirs[:] = []
            continue
        seen.add((st.st_dev, st.st_ino))
        dirs[:] = [d for d in dirs if not d.startswith(".")]
        # regular files only: a dangling link, a FIFO or a socket is nothing ingest reads
        out.extend(f for f in (os.path.join(root, n) for n in files if not n.startswith("."))
                   if os.path.isfile(f))
    return sorted(out)
