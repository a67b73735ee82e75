"""The README and docs/ stay readable and true to the repository.

Pure Python, no network, well under a second:

- every relative Markdown link in README.md and docs/*.md names a file that
  exists, and a ``#anchor`` names a heading of that file (GitHub's slugs);
- every command in the README's first screen (the code blocks that start in
  its first ``FIRST_SCREEN`` lines) exists: ``make X`` is a Makefile target,
  ``gs2e SUB`` a subcommand of the CLI's parser, ``snakemake``'s files and
  profiles exist, ``pip install`` names the pinned torch and a real extra;
- the README's pipeline table names rules of the workflow and CLI subcommands;
- the README stays short (``README_MAX_LINES``): the detail lives in docs/;
- the bad-input page lists every probe of tests/test_bad_inputs.py.
"""

from __future__ import annotations

import argparse
import re
import shlex
from functools import lru_cache
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"
DOCS = REPO / "docs"
README_MAX_LINES = 260
FIRST_SCREEN = 40

FENCE = re.compile(r"^\s*(```|~~~)")
INLINE_CODE = re.compile(r"(`+)(?:(?!\1).)+?\1")
# [text](target) or ![alt](target); target without spaces, optional "title"
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^ {0,3}(#{1,6})\s+(.*?)\s*#*\s*$")
HTML_ANCHOR = re.compile(r"<a\s+(?:name|id)=\"([^\"]+)\"", re.I)


def markdown_files() -> list[Path]:
    return [README, *sorted(DOCS.glob("*.md"))]


def prose_lines(text: str):
    """(line number, line) outside fenced code blocks, inline code removed."""
    fenced = False
    for no, line in enumerate(text.splitlines(), 1):
        if FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            yield no, INLINE_CODE.sub("", line)


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading: the rendered text (no code ticks, link
    targets or emphasis marks), lower case, punctuation dropped, spaces to '-'."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)   # links -> their text
    text = re.sub(r"<[^>]+>", "", text)                            # inline HTML
    text = text.replace("`", "").replace("*", "")
    text = re.sub(r"(?<!\w)_+|_+(?!\w)", "", text)                 # _emphasis_, not snake_case
    text = text.strip().lower()
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


@lru_cache(maxsize=None)
def anchors(path: Path) -> frozenset[str]:
    """Every anchor of a Markdown file: its headings' slugs (repeats get -1, -2, ...)
    and explicit <a name/id> anchors."""
    seen: dict[str, int] = {}
    out = set()
    fenced = False
    for line in path.read_text(encoding="utf-8").splitlines():
        if FENCE.match(line):
            fenced = not fenced
            continue
        if fenced:
            continue
        out.update(HTML_ANCHOR.findall(line))
        m = HEADING.match(line)
        if not m:
            continue
        slug = github_slug(m.group(2))
        n = seen.get(slug, 0)
        seen[slug] = n + 1
        out.add(slug if n == 0 else f"{slug}-{n}")
    return frozenset(out)


def test_github_slug_rules():
    assert github_slug("What the demo produces") == "what-the-demo-produces"
    assert github_slug("Target sensors (`events.sensor`)") == "target-sensors-eventssensor"
    assert github_slug("The paper's Table 1 on gs2e data") == "the-papers-table-1-on-gs2e-data"
    assert github_slug("Scenes table (`config/scenes.tsv`)") == "scenes-table-configscenestsv"
    assert github_slug("`bench_summary` and **more**") == "bench_summary-and-more"
    assert github_slug("Cost — per × scene") == "cost--per--scene"


def relative_links(path: Path):
    for no, line in prose_lines(path.read_text(encoding="utf-8")):
        for target in LINK.findall(line):
            if re.match(r"^[a-z][a-z0-9+.-]*:", target, re.I):   # http:, mailto:, ...
                continue
            yield no, target


@pytest.mark.parametrize("md", markdown_files(), ids=lambda p: str(p.relative_to(REPO)))
def test_relative_links_resolve(md):
    problems = []
    for no, target in relative_links(md):
        file_part, _, anchor = target.partition("#")
        dest = (md.parent / file_part).resolve() if file_part else md
        where = f"{md.relative_to(REPO)}:{no}: {target}"
        if not dest.exists():
            problems.append(f"{where}: no such file")
            continue
        if anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            problems.append(f"{where}: no heading with anchor #{anchor} in "
                            f"{dest.relative_to(REPO)}")
    assert not problems, "broken links:\n" + "\n".join(problems)


def test_every_docs_page_is_reachable_from_the_index():
    index = DOCS / "index.md"
    linked = {(index.parent / t.partition("#")[0]).resolve()
              for _, t in relative_links(index) if t.partition("#")[0]}
    orphans = [p.name for p in DOCS.glob("*.md") if p != index and p.resolve() not in linked]
    assert not orphans, f"docs pages not linked from docs/index.md: {orphans}"


def test_readme_is_short():
    n = len(README.read_text(encoding="utf-8").splitlines())
    assert n <= README_MAX_LINES, \
        f"README.md has {n} lines (at most {README_MAX_LINES}): move detail into docs/"


# ---------------------------------------------------------------- the commands
@lru_cache(maxsize=None)
def make_targets() -> frozenset[str]:
    text = (REPO / "Makefile").read_text(encoding="utf-8")
    return frozenset(m.group(1) for m in re.finditer(r"^([A-Za-z0-9_.-]+)\s*:(?!=)", text, re.M))


@lru_cache(maxsize=None)
def gs2e_subcommands() -> frozenset[str]:
    from gs2e.cli import build_parser

    for action in build_parser()._actions:
        if isinstance(action, argparse._SubParsersAction):
            return frozenset(action.choices)
    raise AssertionError("gs2e's parser has no subcommands")


@lru_cache(maxsize=None)
def workflow_rules() -> frozenset[str]:
    files = [REPO / "Snakefile", *sorted((REPO / "workflow" / "rules").glob("*.smk"))]
    return frozenset(m.group(1) for f in files
                     for m in re.finditer(r"^(?:rule|checkpoint)\s+(\w+)\s*:", f.read_text(), re.M))


def pyproject() -> dict:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        tomllib = pytest.importorskip("tomli")
    with open(REPO / "pyproject.toml", "rb") as fh:
        return tomllib.load(fh)


def first_screen_commands() -> list[tuple[int, list[str]]]:
    """(line number, argv) of every command in the code blocks that start in the
    README's first FIRST_SCREEN lines; `a && b`, `a; b` and `a | b` are split."""
    lines = README.read_text(encoding="utf-8").splitlines()
    out, fenced, start = [], False, 0
    for no, line in enumerate(lines, 1):
        if FENCE.match(line):
            if not fenced and no > FIRST_SCREEN:
                break
            fenced = not fenced
            continue
        if not fenced or not line.strip():
            continue
        argv: list[str] = []
        for tok in shlex.split(line, comments=True):
            if tok in ("&&", "||", ";", "|"):
                out.append((no, argv))
                argv = []
            else:
                argv.append(tok)
        out.append((no, argv))
    return [(no, a) for no, a in out if a]


def _paths_exist(argv: list[str], options: tuple[str, ...]) -> list[str]:
    """The files named after any of ``options`` that do not exist."""
    missing = []
    for opt, val in zip(argv, argv[1:]):
        if opt in options and not (REPO / val).exists():
            missing.append(f"{opt} {val}")
    return missing


def check_command(argv: list[str]) -> str | None:
    """Why this command of the README would fail here, or None."""
    prog, args = argv[0], [a for a in argv[1:] if "=" not in a or a.startswith("-")]
    if prog == "make":
        targets = [a for a in args if not a.startswith("-")] or ["help"]
        bad = [t for t in targets if t not in make_targets()]
        return f"no Makefile target {bad}" if bad else None
    if prog == "gs2e" or argv[:3] in (["python", "-m", "gs2e"], ["python3", "-m", "gs2e"]):
        rest = argv[1:] if prog == "gs2e" else argv[3:]
        sub = next((a for a in rest if not a.startswith("-")), None)
        if sub is not None and sub not in gs2e_subcommands():
            return f"no gs2e subcommand {sub!r} (has {sorted(gs2e_subcommands())})"
        return None
    if prog == "snakemake":
        if not (REPO / "Snakefile").is_file():
            return "no Snakefile"
        missing = _paths_exist(argv, ("--configfile", "--profile", "-s", "--snakefile"))
        return f"missing {missing}" if missing else None
    if prog in ("pip", "pip3") or argv[:3] in (["python", "-m", "pip"], ["python3", "-m", "pip"]):
        for a in argv:
            if a.startswith("torch=="):
                pin = re.search(r"^TORCH \?= (\S+)", (REPO / "Makefile").read_text(), re.M)
                if not pin or pin.group(1) != a:
                    return f"{a} is not the Makefile's TORCH pin ({pin and pin.group(1)})"
            m = re.fullmatch(r"\.\[([\w,-]+)\]", a)
            if m:
                extras = pyproject()["project"].get("optional-dependencies", {})
                bad = [e for e in m.group(1).split(",") if e not in extras]
                if bad:
                    return f"pyproject.toml has no extra {bad}"
        return None
    if prog in ("pytest",) or argv[:3] in (["python", "-m", "pytest"], ["python3", "-m", "pytest"]):
        for opt, val in zip(argv, argv[1:]):
            if opt == "-m":
                markers = {m.split(":")[0].strip()
                           for m in pyproject()["tool"]["pytest"]["ini_options"].get("markers", [])}
                used = set(re.findall(r"\w+", val)) - {"not", "and", "or"}
                if used - markers:
                    return f"unregistered pytest markers {sorted(used - markers)}"
        paths = [a for a in argv[1:] if "/" in a and not a.startswith("-")]
        bad = [p for p in paths if not (REPO / p.split("::")[0]).exists()]
        return f"missing {bad}" if bad else None
    if argv[:3] in (["python", "-m", "venv"], ["python3", "-m", "venv"]):
        return None
    if prog in (".", "source"):
        return None if argv[1].startswith(".venv/") else f"sources {argv[1]}, not the venv"
    return f"the docs test does not know the command {prog!r}: teach check_command()"


def test_first_screen_commands_exist():
    cmds = first_screen_commands()
    assert any(a[:2] == ["make", "demo"] for _, a in cmds) and \
        any(a[:2] == ["make", "test"] for _, a in cmds), "make demo / make test left the first screen"
    problems = [f"README.md:{no}: {' '.join(a)}: {why}"
                for no, a in cmds if (why := check_command(a))]
    assert not problems, "\n".join(problems)


def test_first_lines_are_the_two_commands():
    """`make demo` and `make test` come first, before any other content."""
    blocks = [a for _, a in first_screen_commands()]
    assert blocks[:2] == [["make", "demo"], ["make", "test"]]


def test_check_command_catches_mistakes():
    assert check_command(["make", "no-such-target"])
    assert check_command(["gs2e", "no-such-stage"])
    assert check_command(["snakemake", "--configfile", "config/no-such.yaml"])
    assert check_command(["pip", "install", "-e", ".[no-such-extra]"])
    assert check_command(["pytest", "-m", "not no_such_marker"])
    assert check_command(["frobnicate"])
    assert check_command(["gs2e", "events", "--help"]) is None
    assert check_command(["make", "test", "TEST_WORKERS=4"]) is None


def test_pipeline_table_names_real_rules_and_commands():
    text = README.read_text(encoding="utf-8")
    table = text.split("## The pipeline", 1)[1].split("\n\n", 2)[1]
    rows = [r for r in table.splitlines() if r.startswith("|") and not r.startswith("|---")][1:]
    assert len(rows) >= 10, "the pipeline table lost its rows"
    problems = []
    for row in rows:
        cells = [c.strip() for c in row.strip("|").split("|")]
        stage, rule_cell, cli_cell = cells[0], cells[1], cells[2]
        for rule in re.findall(r"`(\w+)`", rule_cell):   # `bench.tasks` and the like are keys
            if rule not in workflow_rules():
                problems.append(f"{stage}: no workflow rule {rule!r}")
        for sub in re.findall(r"`gs2e ([\w-]+)`", cli_cell):
            if sub not in gs2e_subcommands():
                problems.append(f"{stage}: no gs2e subcommand {sub!r}")
    assert not problems, "\n".join(problems)


def test_every_workflow_rule_is_in_the_pipeline_table():
    text = README.read_text(encoding="utf-8").split("## The pipeline", 1)[1].split("\n## ", 1)[0]
    named = set(re.findall(r"`(\w+)`", text))
    assert not (workflow_rules() - {"all"} - named), \
        f"rules missing from the README's pipeline table: {sorted(workflow_rules() - {'all'} - named)}"


# ---------------------------------------------------------------- moved content
def test_bad_input_page_lists_every_probe():
    """docs/reliability.md holds the table `python tests/test_bad_inputs.py` prints."""
    from tests.test_bad_inputs import PROBES

    text = (DOCS / "reliability.md").read_text(encoding="utf-8")
    rows = set(re.findall(r"^\| `([\w-]+)` \|", text, re.M))
    missing = [p.id for p in PROBES if p.id not in rows]
    assert not missing, f"probes without a row in docs/reliability.md: {missing} " \
        "(regenerate the table with `python tests/test_bad_inputs.py`)"
    assert f"({len(PROBES)} probes;" in text, "the probe count in docs/reliability.md is stale"


def test_measured_tables_say_how_to_regenerate_them():
    """Every page with a benchmark figure names the script that regenerates it, and
    the cost model is the one measured on real scenes at the paper's selection."""
    for page in ("sfm", "train", "events", "export", "bench", "scale"):
        text = (DOCS / f"{page}.md").read_text(encoding="utf-8")
        assert "**Regenerate:**" in text or "**Regenerate**" in text, page
    scale = (DOCS / "scale.md").read_text(encoding="utf-8")
    cost = scale.split("## Cost model", 1)[1]
    assert "OUTDATED" not in cost and "**Measured**" in cost
    assert "bench_cost_model.py --run temple_ring llff_fern --sensor davis346" in cost
