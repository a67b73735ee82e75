"""Config validation: defaults, errors that name the key, scenes table, docs."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from gs2e import config as C
from gs2e.common.errors import ConfigError
from tests.conftest import REPO, run_cli


def test_default_config_is_valid_and_declares_no_default_again():
    """Defaults live in the schema alone: config/config.yaml sets only where
    files are (and any key whose value differs from its default)."""
    cfg = C.load_config(REPO / "config" / "config.yaml")
    assert cfg == C.load_config({"scenes": cfg["scenes"], "results_dir": cfg["results_dir"]})
    with open(REPO / "config" / "config.yaml") as fh:
        raw = yaml.safe_load(fh)
    defaults = C.load_config({})

    def same_as_default(node, ref, path=()):
        for k, v in node.items():
            if isinstance(v, dict):
                yield from same_as_default(v, ref[k], path + (k,))
            elif ref.get(k) == v and path + (k,) not in {("scenes",), ("results_dir",)}:
                yield ".".join(path + (k,))

    assert not list(same_as_default(raw, defaults)), "config/config.yaml repeats schema defaults"


def test_defaults_fill_missing_sections_and_keys():
    cfg = C.load_config({"sfm": {"matcher": "sequential"}})
    assert cfg["sfm"]["matcher"] == "sequential"
    assert cfg["sfm"]["min_registered_fraction"] == 0.8
    assert cfg["demo"]["n_views"] == 36


@pytest.mark.parametrize("cfg, key", [
    ({"sfm": {"nonsense": 1}}, "sfm.nonsense"),
    ({"sfm": {"matcher": "bogus"}}, "sfm.matcher"),
    ({"sfm": {"min_registered_fraction": 1.5}}, "sfm.min_registered_fraction"),
    ({"sfm": {"min_registered_fraction": 0}}, "sfm.min_registered_fraction"),
    ({"demo": {"n_views": "many"}}, "demo.n_views"),
    ({"ingest": {"max_views": 0}}, "ingest.max_views"),
    ({"seed": -1}, "seed"),
    ({"toplevel_typo": 1}, "toplevel_typo"),
])
def test_invalid_values_name_the_key(cfg, key):
    with pytest.raises(ConfigError) as exc:
        C.load_config(cfg)
    assert key in str(exc.value)


def test_input_not_modified():
    cfg = {"sfm": {"matcher": "exhaustive"}}
    before = copy.deepcopy(cfg)
    C.load_config(cfg)
    assert cfg == before


def _write_tsv(path: Path, rows: list[str]) -> Path:
    path.write_text("scene_id\tlayout\tpath\toverrides\n" + "\n".join(rows) + "\n")
    return path


def test_scenes_table_and_overrides(tmp_path):
    p = _write_tsv(tmp_path / "s.tsv", ["a\tdemo\t\tdemo.n_views=12;sfm.matcher=sequential",
                                        "# a comment", "b\tfolder\tdata/b\t"])
    rows = C.load_scenes(p)
    assert [r["scene_id"] for r in rows] == ["a", "b"]
    cfg = C.load_config({})
    a = C.scene_config(cfg, rows[0])
    assert a["demo"]["n_views"] == 12 and a["sfm"]["matcher"] == "sequential"
    assert cfg["demo"]["n_views"] == 36  # the global config is untouched
    assert C.scene_config(cfg, rows[1])["demo"]["n_views"] == 36


@pytest.mark.parametrize("row, needle", [
    ("a\tweird\tx\t", "layout"),
    ("bad id\tfolder\tx\t", "scene_id"),
    ("a\tfolder\t\t", "path is required"),
    ("a\tdemo\t\t\textra", "more cells"),
    ("s" * 300 + "\tdemo\t\t", "scene_id is 300 bytes long"),
])
def test_scenes_table_errors_name_the_cell(tmp_path, row, needle):
    p = _write_tsv(tmp_path / "s.tsv", [row])
    with pytest.raises(ConfigError) as exc:
        C.load_scenes(p)
    assert needle in str(exc.value) and "s.tsv:2" in str(exc.value)


def test_duplicate_scene_ids(tmp_path):
    p = _write_tsv(tmp_path / "s.tsv", ["a\tdemo\t\t", "a\tdemo\t\t"])
    with pytest.raises(ConfigError, match="duplicate scene_id 'a'"):
        C.load_scenes(p)


@pytest.mark.parametrize("over, needle", [
    ("sfm.matcher=bogus", "sfm.matcher"),
    ("sfm.nope=1", "sfm.nope"),
    ("justtext", "section.key=value"),
])
def test_bad_overrides_name_the_scene_and_key(tmp_path, over, needle):
    rows = C.load_scenes(_write_tsv(tmp_path / "s.tsv", [f"a\tdemo\t\t{over}"]))
    with pytest.raises(ConfigError) as exc:
        C.scene_config(C.load_config({}), rows[0])
    assert needle in str(exc.value) and "'a'" in str(exc.value)


def test_config_readme_is_generated_from_schema():
    assert (REPO / "config" / "README.md").read_text() == C.schema_markdown(), \
        "config/README.md is stale: run `gs2e config --doc > config/README.md`"


def test_every_schema_key_has_default_and_description():
    schema = C.load_schema()

    def walk(node, path):
        for k, sub in node.get("properties", {}).items():
            assert "description" in sub, f"{path}{k} has no description"
            assert "default" in sub or k in ("scenes",), f"{path}{k} has no default"
            if sub.get("type") == "object":
                assert sub.get("additionalProperties") is False, f"{path}{k} accepts unknown keys"
                walk(sub, f"{path}{k}.")

    walk(schema, "")


def test_derive_seed_is_stable_and_distinct():
    assert C.derive_seed(0, "a", "sfm") == C.derive_seed(0, "a", "sfm")
    assert len({C.derive_seed(0, "a", s) for s in ("sfm", "train", "events")}) == 3
    assert C.derive_seed(1, "a", "sfm") != C.derive_seed(0, "a", "sfm")


def test_long_names_are_refused_before_any_job(tmp_path):
    """A 300-character scene id passed validation and the dry run, then the
    first job failed with "File name too long"; now gs2e config --validate
    and the dry run refuse it, naming the cell."""
    tsv = _write_tsv(tmp_path / "s.tsv", ["x" * 300 + "\tdemo\t\t"])
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"scenes: {tsv}\n")
    proc = run_cli("config", "--validate", str(cfg))
    assert proc.returncode == 2 and "s.tsv:2: scene_id is 300 bytes long" in proc.stderr
    from tests.conftest import REPO, run_snakemake

    dry = run_snakemake("-n", "--cores", "1", "--snakefile", str(REPO / "Snakefile"), "--directory",
                        str(tmp_path), "--config", f"scenes={tsv}")
    assert dry.returncode != 0 and "scene_id is 300 bytes long" in dry.stdout + dry.stderr
    assert not (tmp_path / "results").exists()


def test_cli_validate_reports_bad_config(tmp_path):
    bad = tmp_path / "c.yaml"
    bad.write_text("sfm:\n  matcher: bogus\n")
    proc = run_cli("config", "--validate", str(bad))
    assert proc.returncode == 2
    assert "sfm.matcher" in proc.stderr


def test_section_json_is_canonical():
    cfg = C.load_config({})
    s = C.section_json(cfg, "sfm")
    assert C.load_section("sfm", s) == cfg["sfm"]
