"""Configuration: JSON-schema (2020-12) validation with defaults, scenes table,
per-scene overrides.

The schema files are package data (``gs2e/schemas/``, read through
``importlib.resources``), so an installed gs2e validates without the
repository. The Snakefile and the CLI both validate through this module, so a
bad value is rejected before any job runs with a message naming its key
(``sfm.matcher``) or the table cell (``config/scenes.tsv:3: layout``).
"""

from __future__ import annotations

import copy
import csv
import functools
import json
import math
from importlib import resources
from pathlib import Path
from typing import Any, Mapping

import yaml
from jsonschema import Draft202012Validator, validators

from gs2e.common.errors import ConfigError

SCHEMA_DIR = resources.files("gs2e") / "schemas"
CONFIG_SCHEMA = SCHEMA_DIR / "config.schema.yaml"
SCENES_SCHEMA = SCHEMA_DIR / "scenes.schema.yaml"
# Where files are, not what a scene computes: left out of config hashes and params.
LOCATION_KEYS = ("scenes", "results_dir")

SECTIONS = ("demo", "ingest", "sfm", "splat", "trajectory", "light", "render", "events", "metrics", "dataset", "export", "bench")


def _with_defaults(cls):
    """Extend a validator class so 'default' values are filled into instances."""
    validate_props = cls.VALIDATORS["properties"]

    def set_defaults(validator, properties, instance, schema):
        if isinstance(instance, dict):
            for key, sub in properties.items():
                if isinstance(sub, dict) and "default" in sub and key not in instance:
                    instance[key] = copy.deepcopy(sub["default"])
        yield from validate_props(validator, properties, instance, schema)

    return validators.extend(cls, {"properties": set_defaults})


_DefaultingValidator = _with_defaults(Draft202012Validator)


# libyaml's parser where PyYAML has it (same resolver and constructor): the
# schema parses in ~10 ms instead of ~130 ms, a tenth of a short command
_SCHEMA_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


@functools.lru_cache(maxsize=8)
def _schema_cached(path) -> dict:
    schema = yaml.load(path.read_text(), Loader=_SCHEMA_LOADER)
    if path == CONFIG_SCHEMA:
        _add_plugin_names(schema)
    return schema


def _add_plugin_names(schema: dict) -> None:
    """Installed plug-ins' names join the enums of what they add (read from the
    installed packages' metadata; nothing is imported)."""
    from gs2e.common.registry import PLUGIN_GROUPS, plugin_names

    for group, where in PLUGIN_GROUPS.items():
        names = plugin_names(group)
        if not names:
            continue
        node = schema["properties"]
        for k in where[:-1]:
            node = node[k]["properties"] if "properties" in node[k] else node[k]
        enum = node[where[-1]]["enum"]
        enum.extend(n for n in names if n not in enum)


def _as_file(path):
    """A schema location: a resource of the package (Traversable) or a path."""
    return Path(path) if isinstance(path, str) else path


def load_schema(path=CONFIG_SCHEMA) -> dict:
    """The schema (a package resource or a file path) as a dict (a fresh copy;
    the parsed file is cached)."""
    return copy.deepcopy(_schema_cached(_as_file(path)))


@functools.lru_cache(maxsize=8)
def _validator(path):
    return _DefaultingValidator(_schema_cached(path))


def _key_path(err) -> str:
    return ".".join(str(p) for p in err.absolute_path)


def _format_error(err, what: str) -> str:
    key = _key_path(err)
    if err.validator == "additionalProperties":
        extra = sorted(set(err.instance) - set(err.schema.get("properties", {})))
        keys = ", ".join(f"{key + '.' if key else ''}{k}" for k in extra)
        return f"{what}: unknown key {keys}"
    if err.validator == "required":
        return f"{what}: {err.message}" + (f" (in {key})" if key else "")
    return f"{what} key '{key or '<root>'}': {err.message}"


def _non_finite(value, path: tuple = ()):
    """(key path, value) of the first NaN or +-inf number in a nested config, or None."""
    if isinstance(value, float) and not math.isfinite(value):
        return path, value
    items = value.items() if isinstance(value, dict) else \
        enumerate(value) if isinstance(value, list) else ()
    for k, v in items:
        found = _non_finite(v, path + (k,))
        if found:
            return found
    return None


def validate(instance: dict, schema: dict | Path, what: str = "config") -> dict:
    """Validate ``instance`` in place, filling defaults; raise ConfigError naming the key.
    ``schema`` is a schema dict or the location of a schema file (validator cached).
    Every number must be finite: NaN and inf pass JSON-schema bounds (every
    comparison with NaN is false), so they are rejected here."""
    if not isinstance(instance, dict):
        raise ConfigError(f"{what}: expected a mapping, got {type(instance).__name__}")
    bad = _non_finite(instance)
    if bad:
        key = ".".join(map(str, bad[0]))
        raise ConfigError(f"{what} key '{key}': {bad[1]} is not a finite number")
    v = _DefaultingValidator(schema) if isinstance(schema, dict) else _validator(_as_file(schema))
    # Fill defaults first (a full pass), then report the first error by path order.
    errors = sorted(v.iter_errors(instance), key=lambda e: (list(map(str, e.absolute_path)), e.message))
    if errors:
        raise ConfigError(_format_error(errors[0], what))
    return instance


def load_config(cfg: Mapping | str | Path | None = None) -> dict:
    """Return the validated config with every default filled in.

    ``cfg`` is a mapping (e.g. Snakemake's ``config``), a YAML path, or None
    (the defaults: what ``config/config.yaml`` holds). The input is not modified.
    """
    if cfg is None:
        cfg = {}
    if isinstance(cfg, (str, Path)):
        try:
            with open(cfg) as fh:
                data = yaml.safe_load(fh) or {}
        except OSError as exc:
            raise ConfigError(f"cannot read config file {cfg}: {exc}") from exc
        except yaml.YAMLError as exc:
            raise ConfigError(f"config file {cfg} is not valid YAML: {exc}") from exc
    else:
        data = copy.deepcopy(dict(cfg))
    return check_config(validate(data, CONFIG_SCHEMA, "config"), "config")


def parse_overrides(text: str, where: str = "overrides") -> dict:
    """'sfm.matcher=sequential;ingest.max_views=30' -> nested dict (YAML scalars)."""
    out: dict[str, Any] = {}
    for item in filter(None, (s.strip() for s in (text or "").split(";"))):
        if "=" not in item:
            raise ConfigError(f"{where}: '{item}' is not of the form section.key=value")
        key, val = (s.strip() for s in item.split("=", 1))
        parts = key.split(".")
        if not all(parts):
            raise ConfigError(f"{where}: bad key '{key}'")
        try:
            value = yaml.safe_load(val) if val else None
        except yaml.YAMLError as exc:
            raise ConfigError(f"{where}: value of '{key}' is not valid YAML: {exc}") from exc
        node = out
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ConfigError(f"{where}: '{key}' conflicts with another override")
        node[parts[-1]] = value
    return out


def deep_merge(base: dict, over: Mapping) -> dict:
    """Copy of ``base`` with ``over`` merged in recursively."""
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, Mapping) and isinstance(out.get(k), dict):
            out[k] = deep_merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


# Scene ids become folder names, and with them file names that gs2e extends by up
# to about 130 bytes (an atomic write's .<name>.tmp-<pid>-<start>@<host>-<8 hex>);
# file systems allow 255 bytes a name. (Trajectory, format and task names come
# from the schema's enums: short.)
MAX_NAME_BYTES = 120


def load_scenes(path: str | Path) -> list[dict]:
    """Read and validate the scenes TSV; returns one dict per row.

    Columns: scene_id, layout, path (optional), overrides (optional).
    Lines starting with '#' are comments.
    """
    path = Path(path)
    try:
        with open(path, newline="") as fh:
            lines = [ln for ln in fh if ln.strip() and not ln.lstrip().startswith("#")]
    except OSError as exc:
        raise ConfigError(f"cannot read scenes table {path}: {exc}") from exc
    if not lines:
        raise ConfigError(f"scenes table {path} is empty (needs a header and one row)")
    reader = csv.DictReader(lines, delimiter="\t")
    rows, seen = [], set()
    for lineno, raw in enumerate(reader, start=2):
        if None in raw:
            raise ConfigError(f"{path}:{lineno}: more cells than header columns")
        row = {k.strip(): (v or "").strip() for k, v in raw.items() if k is not None}
        row = {k: v for k, v in row.items() if not (v == "" and k in ("path", "overrides"))}
        validate(row, SCENES_SCHEMA, f"{path}:{lineno}")
        if len(row["scene_id"].encode()) > MAX_NAME_BYTES:
            raise ConfigError(f"{path}:{lineno}: scene_id is {len(row['scene_id'].encode())} bytes long; "
                              f"at most {MAX_NAME_BYTES} (it names folders and files, whose names the "
                              "file system limits to 255 bytes with gs2e's temporary suffixes)")
        if row["scene_id"] in seen:
            raise ConfigError(f"{path}:{lineno}: duplicate scene_id '{row['scene_id']}'")
        if row["layout"] != "demo" and not row["path"]:
            raise ConfigError(f"{path}:{lineno}: path is required for layout '{row['layout']}'")
        seen.add(row["scene_id"])
        rows.append(row)
    if not rows:
        raise ConfigError(f"scenes table {path} has no scenes")
    return rows


def scene_config(config: dict, scene: dict) -> dict:
    """Validated config for one scene: global config + the row's overrides."""
    over = parse_overrides(scene.get("overrides", ""), f"scene '{scene['scene_id']}' overrides")
    merged = deep_merge(config, over)
    what = f"scene '{scene['scene_id']}' config"
    return check_config(validate(merged, CONFIG_SCHEMA, what), what, workflow=True)


def section_json(config: dict, section: str) -> str:
    """Canonical JSON of one config section (sorted keys), as passed to the CLI."""
    return json.dumps(config[section], sort_keys=True, separators=(",", ":"))


def load_section(section: str, text: str | None = None, path: str | None = None) -> dict:
    """Validated section for the CLI: from a JSON string, a YAML config file, or defaults."""
    if section not in SECTIONS:
        raise ConfigError(f"unknown config section '{section}'")
    if text:
        try:
            sec = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"--config-json for '{section}' is not valid JSON: {exc}") from exc
        cfg = validate({section: sec}, CONFIG_SCHEMA, "config")
    elif path:
        cfg = load_config(path)
    else:
        cfg = validate({}, CONFIG_SCHEMA, "config")
    # the checks of this section only: the others hold defaults here
    return check_config(cfg, "config", sections=(section,))[section]


# ---------------------------------------------------------------- cross-key checks
# Constraints the schema cannot express (they involve several keys, or parse a
# value). Each check names the sections it reads; all run in scene_config (what
# `gs2e config --validate` and the Snakefile run for every scene, before the
# first job, `snakemake -n` included), those of single sections in load_config
# too, and load_section (a stage's CLI) runs those of its own section. Checks
# that tie stages together (render.trajectories against what the trajectory
# stage writes) concern the workflow only: a stage used on its own, or a test,
# may set one section without the other.

def _check_render(cfg: dict) -> None:
    r = cfg["render"]
    interval_us = 1e6 / r["fps"]
    if r["write_blur"] and r["exposure_us"] > interval_us:
        raise ConfigError(f"render.exposure_us={r['exposure_us']:g} is longer than the frame "
                          f"interval {interval_us:.0f} us at render.fps={r['fps']:g} (lower it, "
                          "lower render.fps, or set render.write_blur=false)")


def _check_trajectory(cfg: dict) -> None:
    import numpy as np

    from gs2e.trajectory.velocity import make_profile, sample_profile

    t = cfg["trajectory"]
    if not t["alpha"] + t["beta"] > 0:
        raise ConfigError("trajectory.alpha / trajectory.beta: at least one must be positive")
    if t["speed_list"]:
        sample_profile(make_profile(t["velocity"], t["speed_list"], t["speed_list_tau"]),
                       np.linspace(0.0, 1.0, 2), "trajectory.speed_list")
    # parsed and checked even when speed_list replaces it: a bad value is a bad value
    sample_profile(make_profile(t["velocity"]), np.linspace(0.0, 1.0, 2), "trajectory.velocity")


def _missing(key: str, path: str) -> ConfigError:
    """A config key naming a file that is not there."""
    return ConfigError(f"{key}: {path} does not exist (relative paths start at the working "
                       f"directory {Path.cwd()})")


def _check_splat(cfg: dict) -> None:
    s = cfg["splat"]
    if s["budget_min"] > s["budget_max"]:
        raise ConfigError(f"splat.budget_min={s['budget_min']} is larger than "
                          f"splat.budget_max={s['budget_max']}")
    if s["model_source"] == "ply":
        if not s["ply_path"]:
            raise ConfigError("splat.ply_path: must be set when splat.model_source is 'ply'")
        if not Path(s["ply_path"]).exists():
            raise _missing("splat.ply_path", s["ply_path"])
    if s["window"] != "cut" and s["backend"] == "gsplat":
        raise ConfigError(f"splat.window: {s['window']} needs splat.backend cpu or auto (gsplat composites "
                          "with the cut window only: set splat.window: cut to train on it)")


def _check_sensor_size(path: str) -> None:
    """A custom sensor's pixel array, before any job (the event stage reads the
    rest of the file; this module does not import it: every command loads it)."""
    from gs2e.common.camera import size_problem

    try:
        doc = yaml.safe_load(Path(path).read_text())
        size = {k: (doc[k]["value"] if isinstance(doc[k], dict) else doc[k]) for k in ("width", "height")}
        w, h = int(size["width"]), int(size["height"])
    except (OSError, yaml.YAMLError, TypeError, KeyError, ValueError) as exc:
        raise ConfigError(f"events.sensor_file: {path}: no readable width and height ({exc})") from None
    why = size_problem(w, h)
    if why:
        raise ConfigError(f"events.sensor_file: {path}: sensor {why}")


CURVE_SUBSTEPS = 4  # points per step of mode curve where substeps is null (docs/events.md)


def points_per_step(mode: str, substeps: int | None) -> int:
    """``events.sampling.substeps`` resolved: null = :data:`CURVE_SUBSTEPS` in
    mode curve (the cubic its error bound assumes), 1 in the other modes
    (the renders only; mode tile takes no points between renders). Here, not
    in gs2e.events.settings (which uses it), so that the config check needs
    no event module."""
    if substeps is not None:
        return int(substeps)
    return CURVE_SUBSTEPS if mode == "curve" else 1


def _check_events(cfg: dict) -> None:
    e = cfg["events"]
    lo, hi = e["theta_range"]
    if lo > hi:
        raise ConfigError(f"events.theta_range: low {lo:g} is larger than high {hi:g}")
    points = points_per_step(e["sampling"]["mode"], e["sampling"]["substeps"]) > 1
    if points and e["sampling"]["mode"] == "tile":
        raise ConfigError("events.sampling.substeps: points between renders need a whole-image mode "
                          "(fixed, motion, adaptive or curve), not tile")
    if e["sampling"]["slopes"] != "neighbours" and not points:
        raise ConfigError(f"events.sampling.slopes={e['sampling']['slopes']} shapes the points between "
                          "renders: set events.sampling.substeps > 1")
    if e["sampling"]["mode"] == "motion" and e["sampling"]["max_motion_px"] is None:
        raise ConfigError("events.sampling.mode=motion needs events.sampling.max_motion_px "
                          "(the largest image motion between samples, px)")
    if e["theta_mismatch_sigma"] is not None and e["theta_mismatch_rel"] is not None:
        raise ConfigError("events.theta_mismatch_sigma and events.theta_mismatch_rel are both set (set one)")
    if e["sensor"] == "custom":
        if not e["sensor_file"]:
            raise ConfigError("events.sensor=custom needs events.sensor_file (a sensor YAML)")
        if not Path(e["sensor_file"]).is_file():
            raise _missing("events.sensor_file", e["sensor_file"])
        _check_sensor_size(e["sensor_file"])
    elif e["sensor_file"]:
        raise ConfigError(f"events.sensor_file is set but events.sensor is {e['sensor']!r} "
                          "(set events.sensor: custom to use it)")


def _check_metrics(cfg: dict) -> None:
    real = cfg["metrics"]["real_events"]
    if real and not Path(real).is_file():
        raise _missing("metrics.real_events", real)


def _check_bench(cfg: dict) -> None:
    import importlib.util

    b = cfg["bench"]
    if b["video_learned"] and importlib.util.find_spec("pie_net") is None:
        raise ConfigError(f"bench.video_learned={b['video_learned']}: the PIE-Net package is not "
                          "installed (pip install --no-deps event-pienet==1.1.3, as make setup "
                          "does; or set bench.video_learned=[])")
    for i, path in enumerate(b["real_video"]):
        if not Path(path).exists():
            raise _missing(f"bench.real_video[{i}]", path)
    if b["sim2real"] is not None:
        for f in ("events.txt", "images.txt", "groundtruth.txt", "calib.txt"):
            if not (Path(b["sim2real"]) / f).is_file():
                raise _missing("bench.sim2real", str(Path(b["sim2real"]) / f))
    # the sensors' names from the schema: importing the presets would put their values
    # into every stage's code version (a refit would rerun every job)
    sensors = [s for s in load_schema()["properties"]["events"]["properties"]["sensor"]["enum"]
               if s not in (None, "custom")]
    for v in b["sim2real_variants"]:
        if v in COLOUR_SENSORS:
            raise ConfigError(f"bench.sim2real_variants: '{v}' has a colour filter, but the recording's "
                              "frames are luminance (choose a grey sensor)")
        if v not in ("scene", "ideal", "voltmeter", *sensors):
            raise ConfigError(f"bench.sim2real_variants: unknown variant '{v}' (choose from scene, "
                              f"ideal, voltmeter, {', '.join(sensors)})")
    if b["edi_theta_min"] >= b["edi_theta_max"]:
        raise ConfigError(f"bench.edi_theta_min={b['edi_theta_min']:g} is not below "
                          f"bench.edi_theta_max={b['edi_theta_max']:g}")
    for spec in b["methods"]:
        mod = spec.split(":")[0]
        try:
            found = importlib.util.find_spec(mod) is not None
        except (ImportError, ValueError):
            found = False
        if not found:
            raise ConfigError(f"bench.methods: module '{mod}' of '{spec}' cannot be found by "
                              "this interpreter (install it or add it to PYTHONPATH)")


# The sensors of the schema with a colour filter over their pixels (by name: importing
# the presets would tie every stage's code version to them; tests/test_light.py holds
# this equal to the presets with a ``cfa``).
COLOUR_SENSORS = frozenset({"color_davis346"})


def trajectory_names(traj_cfg: dict) -> list[str]:
    """Names of the trajectory files the trajectory stage writes for this section."""
    names = [f"base_{p}" for p in traj_cfg["speed_presets"]]
    return names + [f"mini{g:02d}_{traj_cfg['mini_preset']}" for g in range(traj_cfg["mini_groups"])]


def _check_render_trajectories(cfg: dict) -> None:
    made = trajectory_names(cfg["trajectory"])
    for run in cfg["render"]["trajectories"]:
        name = run.partition("@")[0]  # a run is <trajectory>[@<condition>] (gs2e.light)
        if name not in made:
            raise ConfigError(f"render.trajectories: '{name}' is not a trajectory the trajectory "
                              f"stage writes with this config ({', '.join(made) or 'none'}; see "
                              "trajectory.speed_presets, mini_groups, mini_preset)")


def _check_bench_inputs(cfg: dict) -> None:
    # (by name, not through gs2e.bench.tasks: every rule imports this module, and
    # importing the registry would tie every rule's code version to the tasks' code)
    if "flow" in cfg["bench"]["tasks"] and not cfg["render"]["write_depth"]:
        raise ConfigError("bench.tasks: 'flow' needs the rendered depth, but render.write_depth is false")
    if "deblur" in cfg["bench"]["tasks"] and not cfg["render"]["write_blur"]:
        raise ConfigError("bench.tasks: 'deblur' needs blurred frames, but render.write_blur is false")
    if ("recon3d" in cfg["bench"]["tasks"] and "event_blur" in cfg["bench"]["recon3d_variants"]
            and not cfg["render"]["write_blur"]):
        raise ConfigError("bench.recon3d_variants: 'event_blur' needs blurred frames, but "
                          "render.write_blur is false")


def _check_export(cfg: dict) -> None:
    x = cfg["export"]
    T = x["imu_T_cam_imu"]
    if T is not None:
        import numpy as np

        T = np.asarray(T, np.float64)
        R = T[:3, :3]
        if (not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0
                or not np.allclose(T[3], [0, 0, 0, 1])):
            raise ConfigError("export.imu_T_cam_imu: not a rigid transform (a proper rotation, "
                              "last row 0 0 0 1)")
    g = x["imu_gravity"]
    if g != "auto" and not sum(v * v for v in g) > 0:
        raise ConfigError("export.imu_gravity: a zero vector has no direction (give m/s^2 in world "
                          "coordinates, or auto)")


def _check_export_inputs(cfg: dict) -> None:
    x, r = cfg["export"], cfg["render"]
    # the runs gs2e.light.settings.run_names makes (by hand: importing it would tie every
    # rule's code version to gs2e.light)
    runs = list(r["trajectories"]) + [f"{t}@{c}" for c in cfg["light"]["runs"] for t in r["trajectories"]
                                      if "@" not in t]
    for name in x["trajectories"] or ():
        if name not in runs:
            raise ConfigError(f"export.trajectories: '{name}' is not rendered (render.trajectories and "
                              f"light.runs: {', '.join(runs)})")
    if "flow" in x["formats"] and not r["write_depth"]:
        raise ConfigError("export.formats: 'flow' needs the rendered depth, but render.write_depth is false")
    bags = [f for f in x["formats"] if f in ("rosbag", "rosbag2")]
    if bags and x["rosbag_image"] == "blur" and not r["write_blur"]:
        raise ConfigError(f"export.formats: '{bags[0]}' with export.rosbag_image=blur needs blurred "
                          "frames, but render.write_blur is false (or set export.rosbag_image: sharp)")


def _check_render_light(cfg: dict) -> None:
    known = cfg["light"]["conditions"]
    for run in cfg["render"]["trajectories"]:
        cond = run.partition("@")[2]
        if "@" in run and cond not in known:
            raise ConfigError(f"render.trajectories: '{run}' names no lighting condition '{cond}' "
                              f"(light.conditions: {', '.join(sorted(known))})")


CROSS_CHECKS = (
    (("render",), _check_render),
    (("render", "light"), _check_render_light),
    (("trajectory",), _check_trajectory),
    (("splat",), _check_splat),
    (("events",), _check_events),
    (("metrics",), _check_metrics),
    (("export",), _check_export),
    (("bench",), _check_bench),
)


def _check_window_backend(cfg: dict) -> None:
    """A model of the smooth window renders on the cpu only (gsplat has the cut window)."""
    if cfg["splat"]["window"] != "cut" and cfg["render"]["backend"] == "gsplat":
        raise ConfigError(f"render.backend: gsplat composites with the cut window only; splat.window is "
                          f"{cfg['splat']['window']} (use render.backend cpu or auto, or splat.window: cut)")


def _check_window_slopes(cfg: dict) -> None:
    """A render's own slope (by difference or the tangent pass) needs renders
    continuous in time: the smooth window's."""
    slopes = cfg["events"]["sampling"]["slopes"]
    if slopes != "neighbours" and cfg["splat"]["window"] == "cut":
        raise ConfigError(f"events.sampling.slopes: {slopes} needs a model continuous in time "
                          "(splat.window: smooth); the cut window's renders jump where a Gaussian "
                          "crosses its cut-off")


WORKFLOW_CHECKS = (
    (("render", "trajectory"), _check_render_trajectories),
    (("splat", "render"), _check_window_backend),
    (("splat", "events"), _check_window_slopes),
    (("bench", "render"), _check_bench_inputs),
    (("export", "render", "light"), _check_export_inputs),
)


def check_config(cfg: dict, what: str = "config", sections: tuple[str, ...] | None = None,
                 workflow: bool = False) -> dict:
    """Run the cross-key checks (all, or those reading only ``sections``; with
    ``workflow`` also those tying stages together) on a validated config;
    ConfigError prefixed with ``what`` names the key(s)."""
    for needs, check in CROSS_CHECKS + (WORKFLOW_CHECKS if workflow else ()):
        if sections is None or set(needs) <= set(sections):
            try:
                check(cfg)
            except ConfigError as exc:
                raise ConfigError(f"{what}: {exc}" if what != "config" else str(exc)) from None
    return cfg


def scene_params_json(config: dict) -> str:
    """Canonical JSON of a scene's whole config without its file locations
    (``LOCATION_KEYS``): moving the scenes table or results changes nothing."""
    return json.dumps({k: v for k, v in config.items() if k not in LOCATION_KEYS}, sort_keys=True)


def derive_seed(seed: int, scene_id: str, stage: str) -> int:
    """Stable per-(scene, stage) seed in [0, 2^31) from the global seed."""
    import hashlib

    h = hashlib.sha256(f"{seed}\0{scene_id}\0{stage}".encode()).digest()
    return int.from_bytes(h[:4], "little") & 0x7FFFFFFF


def _type_str(sub: dict) -> str:
    if "anyOf" in sub:
        return " \\| ".join(f"`{a['const']}`" if "const" in a else _type_str(a) for a in sub["anyOf"])
    if "enum" in sub:
        return " \\| ".join("`null`" if v is None else f"`{v}`" for v in sub["enum"])
    t = sub.get("type", "")
    t = " \\| ".join(t) if isinstance(t, list) else t
    rng = []
    for k, sym in (("minimum", ">="), ("exclusiveMinimum", ">"), ("maximum", "<="),
                   ("exclusiveMaximum", "<")):
        if k in sub:
            rng.append(f"{sym} {sub[k]}")
    return t + (f" ({', '.join(rng)})" if rng else "")


def schema_markdown(schema: dict | None = None) -> str:
    """config/README.md, generated from the schema's descriptions (one source of truth)."""
    schema = schema or load_schema()
    lines = [
        "# Configuration reference",
        "",
        "<!-- generated by `gs2e config --doc > config/README.md`; do not edit by hand -->",
        "",
        "`config/config.yaml` is validated against `gs2e/schemas/config.schema.yaml` "
        "(JSON Schema 2020-12) before any job runs; missing keys take the defaults below, "
        "unknown keys, wrong types and out-of-range values are errors naming the key. "
        "Per-scene overrides go in the `overrides` column of `config/scenes.tsv` "
        "(`section.key=value;...`, YAML values) and are validated the same way.",
        "",
        "## Scenes table (`config/scenes.tsv`)",
        "",
        "| column | type | default | description |",
        "|---|---|---|---|",
    ]
    scenes = load_schema(SCENES_SCHEMA)
    for key, sub in scenes["properties"].items():
        req = " (required)" if key in scenes.get("required", []) else ""
        lines.append(f"| `{key}` | {_type_str(sub)}{req} | `{json.dumps(sub.get('default', ''))}` | "
                     f"{' '.join(sub.get('description', '').split())} |")
    lines += ["", "## Top-level keys", "", "| key | type | default | description |", "|---|---|---|---|"]
    sections = []
    for key, sub in schema["properties"].items():
        if sub.get("type") == "object":
            sections.append((key, sub))
            continue
        lines.append(f"| `{key}` | {_type_str(sub)} | `{json.dumps(sub.get('default'))}` | "
                     f"{' '.join(sub.get('description', '').split())} |")
    for key, sub in sections:
        lines += ["", f"## `{key}`", "", " ".join(sub.get("description", "").split()), ""]
        props = sub.get("properties", {})
        if not props:
            lines.append("_No keys yet._")
            continue
        lines += ["| key | type | default | description |", "|---|---|---|---|"]

        def rows(prefix: str, props: dict) -> None:
            for k, s in props.items():
                lines.append(f"| `{prefix}.{k}` | {_type_str(s)} | `{json.dumps(s.get('default'))}` | "
                             f"{' '.join(s.get('description', '').split())} |")
                if s.get("type") == "object" and s.get("properties"):
                    rows(f"{prefix}.{k}", s["properties"])

        rows(key, props)
    return "\n".join(lines) + "\n"
