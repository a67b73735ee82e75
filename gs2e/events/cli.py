"""``gs2e events``: simulate events from any frame sequence;
``gs2e events-stats``: statistics / noise calibration of an event file (and a
sensor preset from it); ``gs2e events-convert``: one container to another."""

from __future__ import annotations

import argparse


def register(subparsers) -> None:
    from gs2e.cli import add_config_args

    p = subparsers.add_parser(
        "events", help="simulate an event camera on a frame sequence",
        description="Simulate events (DVS-Voltmeter or ideal model) from a folder of images "
                    "(+ timestamps file or --fps), a video, or a .npy/.npz array. Writes OUT/ "
                    "with events.h5 (DSEC layout), stats.json and optional preview.mp4, "
                    "events.txt, events.npz and, with --set containers=[aedat4,evt2,dat], "
                    "events.aedat4 / events.raw (EVT2) / events.dat.")
    p.add_argument("input", nargs="?", help="folder of images, video file, or .npy/.npz frames "
                   "(omit with --model/--trajectory)")
    p.add_argument("--model", help="gs2e train output: render the frames on demand (workflow mode)")
    p.add_argument("--trajectory", help="trajectory .npz to render along (with --model)")
    p.add_argument("--background", type=_rgb, default=(0.0, 0.0, 0.0), metavar="R,G,B",
                   help="with --model: colour behind the Gaussians, 0-1 (default 0,0,0)")
    p.add_argument("--scale", type=float, default=1.0,
                   help="with --model: resolution relative to the trajectory's camera (default 1)")
    p.add_argument("--backend", default="cpu", choices=["cpu", "gsplat", "auto"],
                   help="with --model: rasterizer (default cpu)")
    p.add_argument("--order-step-px", type=float, default=2.0,
                   help="with --model and a model trained with the smooth window: px of image motion "
                        "between the continuous renderer's depth-order knots (render.order_step_px)")
    p.add_argument("--light-json", default=None, metavar="JSON",
                   help="with --model: the run's lighting condition (gs2e.light; the workflow "
                        "passes a run <trajectory>@<condition>'s): the luminance is scaled by its "
                        "illuminance over light.reference_lux")
    p.add_argument("--threads", type=int, default=None,
                   help="CPU threads for rendering and simulation (default events.num_threads; "
                        "-1 = the CPUs this process may use)")
    p.add_argument("-o", "--out", required=True, help="output folder (replaced atomically)")
    p.add_argument("--timestamps", help="text file, one frame time per line (see --time-unit)")
    p.add_argument("--time-unit", default="us", choices=["us", "ms", "s"],
                   help="unit of the timestamps file (default us)")
    p.add_argument("--fps", type=float, help="frame rate when there is no timestamps file")
    p.add_argument("--encoding", choices=["srgb", "linear"],
                   help="pixel encoding (default: srgb for images/videos, linear for arrays)")
    p.add_argument("--seed", type=int, default=0, help="seed (the workflow derives it per scene)")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                   help="override an events config key, e.g. --set model=ideal (repeatable)")
    add_config_args(p)
    p.set_defaults(func=run)

    q = subparsers.add_parser(
        "events-stats", help="statistics and noise calibration of an event file",
        description="Event statistics (count, rate, ON fraction, per-pixel density, "
                    "inter-event intervals) and a noise calibration of a recording: "
                    "background-activity rate (Hz per pixel), ON/OFF balance and refractory "
                    "period, each with a 95 %% interval (methods: gs2e.events.stats."
                    "calibrate_noise). Reads .aedat4, .raw (Prophesee EVT2/EVT3), .dat, "
                    ".h5 (DSEC), .npz and 't x y p' text; prints JSON. --write-preset saves "
                    "the fitted values as a custom sensor preset (YAML).")
    q.add_argument("events_file")
    q.add_argument("--width", type=int, help="sensor width, for files whose header gives no size "
                                              "and names no known camera (text, DSEC, some RAW)")
    q.add_argument("--height", type=int, help="sensor height (as --width)")
    q.add_argument("--ba-window-us", type=int, default=10000,
                   help="support window of the background-activity criterion (us, default 10000)")
    q.add_argument("-o", "--out", help="write the JSON here instead of stdout")
    q.add_argument("--write-preset", metavar="FILE.yaml",
                   help="also write the fitted values (size, shot_noise_rate_hz = the "
                        "background-activity rate, shot_noise_on_fraction, refractory_us; each "
                        "with its interval, method and source) as a sensor file for "
                        "events.sensor=custom")
    q.add_argument("--preset-name", help="the preset's name (default: the recording's file stem)")
    q.add_argument("--aps", action="store_true",
                   help="the recording has APS frames (an .aedat4 file with a frame stream, or an ECD "
                        "sequence folder): also measure background activity and hot pixels in its still "
                        "region against the APS brightness (gs2e.events.stats.still_background); "
                        "--write-preset then takes leak, shot noise and hot pixels from there")
    q.add_argument("--still-std", type=float, default=0.01,
                   help="with --aps: a pixel is still where its APS std over the frames is below this "
                        "(APS in [0, 1]; default 0.01)")
    q.set_defaults(func=run_stats)

    c = subparsers.add_parser(
        "events-convert", help="copy an event file into another container",
        description="Read any event file gs2e reads (.aedat4, .raw EVT2/EVT3, .dat, .h5 DSEC, "
                    ".npz, 't x y p' text) and write it as OUT, whose suffix picks the "
                    "container: .aedat4, .raw (Prophesee EVT2), .dat (Prophesee DAT), .h5 (DSEC "
                    "layout, t_offset = the first event's time), .npz or .txt. The sensor size "
                    "comes from the input's header (or --width/--height) and goes into OUT's; "
                    "OUT appears only when complete.")
    c.add_argument("input", help="event file to read")
    c.add_argument("output", help="event file to write (suffix picks the container)")
    c.add_argument("--width", type=int, help="sensor width, for inputs whose header gives no size "
                                              "and names no known camera (text, DSEC, some RAW)")
    c.add_argument("--height", type=int, help="sensor height, for inputs without a size (text, DSEC)")
    c.set_defaults(func=run_convert)

    r = subparsers.add_parser(
        "events-presets", help="list the target sensors and DVS-Voltmeter presets, with sources",
        description="Target sensors (events.sensor): pixel array and pixel non-idealities, each "
                    "value with its source (datasheet, paper, measured, or assumed). "
                    "DVS-Voltmeter presets (events.preset): k1..k6, their units, and the "
                    "relative-intensity change dL/L that crosses a threshold theta at several "
                    "luminances.")
    r.add_argument("--theta", type=float, default=1.0, help="threshold (normalised voltage)")
    r.set_defaults(func=run_presets)


def _rgb(text: str) -> tuple[float, float, float]:
    vals = tuple(float(v) for v in text.split(","))
    if len(vals) != 3 or not all(0.0 <= v <= 1.0 for v in vals):
        raise argparse.ArgumentTypeError(f"expected R,G,B in [0, 1], got {text!r}")
    return vals


def _section(args) -> dict:
    import json

    import yaml

    from gs2e.common.errors import ConfigError
    from gs2e.config import load_section

    cfg = load_section("events", text=args.config_json, path=args.config)
    for item in args.set:
        if "=" not in item:
            raise ConfigError(f"--set '{item}': expected KEY=VALUE")
        k, v = item.split("=", 1)
        cfg[k.strip()] = yaml.safe_load(v)
    return load_section("events", text=json.dumps(cfg))


def run(args) -> int:
    import logging

    from gs2e.common.log import timed
    from gs2e.events.frames import open_frame_source
    from gs2e.events.simulate import simulate_to_folder

    log = logging.getLogger("gs2e.events")
    from gs2e.common.errors import ConfigError
    from gs2e.common.threads import pick_threads, set_threads

    from gs2e.events.settings import event_settings

    cfg = event_settings(_section(args))  # resolved once; the stage passes it on
    set_threads(pick_threads(args.threads, cfg.num_threads))
    if args.model or args.trajectory:
        if not (args.model and args.trajectory) or args.input:
            raise ConfigError("workflow mode needs both --model and --trajectory and no INPUT")
        from gs2e.events.rendered import RenderedSource

        from gs2e.light.settings import Condition

        light = Condition.from_json(args.light_json) if args.light_json else None
        src = RenderedSource(args.model, args.trajectory, cfg, background=args.background,
                             scale=args.scale, backend=args.backend, batch_frames=cfg.batch_frames,
                             order_step_px=args.order_step_px, light=light)
        extra = {"model_dir": str(args.model), "trajectory": str(args.trajectory),
                 "render": {"background": list(args.background), "scale": args.scale,
                            "backend": args.backend, "order_step_px": args.order_step_px,
                            "window": src.window}, "camera": src.camera}
    else:
        if not args.input:
            raise ConfigError("give INPUT (frames) or --model and --trajectory")
        from gs2e.events.sensors import resolve_cfa

        if args.light_json or resolve_cfa(cfg) is not None:
            raise ConfigError("--light-json and a colour filter (events.cfa, color_davis346) need rendered "
                              "input (--model and --trajectory): frame files are luminance")
        src = open_frame_source(args.input, args.timestamps, args.fps, args.encoding, args.time_unit)
        extra = None
        if cfg.sensor is not None:
            from gs2e.events.frames import SensorFrames

            src = SensorFrames(src, cfg)
            extra = {"camera": src.camera}
    with timed(f"events {cfg.model} on {src.name}", log):
        simulate_to_folder(src, cfg, args.out, args.seed, extra_meta=extra)
    if getattr(src, "stats", None) is not None:
        st = src.stats
        log.info("sampling (%s): %d renders, %d tile renders, %.1f M pixel values rendered, "
                 "%d samples used, %d rejected, %d forced", src.sc.mode, st.renders,
                 st.tiles_rendered, st.pixel_samples * 1e-6, st.accepted, st.rejected, st.forced)
    return 0


def _size_arg(args) -> tuple[int, int] | None:
    """--width/--height: the size of files whose header gives none and names no known camera."""
    from gs2e.common.errors import InputError

    if (args.width is None) != (args.height is None):
        raise InputError("give both --width and --height, or neither")
    if args.width is None:
        return None
    if not (0 < args.width <= 65536 and 0 < args.height <= 65536):
        raise InputError(f"--width/--height {args.width}x{args.height}: outside 1..65536")
    return args.width, args.height


def run_stats(args) -> int:
    import json
    from pathlib import Path

    import numpy as np

    from gs2e.common.atomic import check_writable, json_safe, write_json_atomic
    from gs2e.common.errors import InputError
    from gs2e.events.io import read_events
    from gs2e.events.containers import size_origin
    from gs2e.events.stats import calibrate_noise, event_stats, sensor_preset, write_sensor_preset

    if args.write_preset:
        check_writable(args.write_preset)  # before the work (gs2e.cli checks --out)
    rec = None
    if args.aps:
        from gs2e.events.recordings import read_recording

        rec = read_recording(args.events_file)
        ev, shape = rec.events, rec.shape
    else:
        ev, shape = read_events(args.events_file, _size_arg(args))
    if not shape or not all(shape):
        if len(ev) == 0:
            raise InputError(f"{args.events_file}: no events and no sensor size")
        shape = (int(ev.y.max()) + 1, int(ev.x.max()) + 1)
    if np.any(ev.t[1:] < ev.t[:-1]):
        raise InputError(f"{args.events_file}: timestamps are not sorted")
    cal = calibrate_noise(ev, shape, args.ba_window_us)
    out = {"stats": event_stats(ev, shape, name=str(args.events_file)), "noise_calibration": cal}
    still = None
    if rec is not None:
        from gs2e.events.stats import still_background

        still = still_background(ev, shape, rec.frames, still_std=args.still_std)
        out["still_background"] = {k: v for k, v in still.items() if not k.startswith("_")}
    if args.write_preset:
        if not len(ev) > 1 or not np.isfinite(cal["ba_rate_hz"]):
            raise InputError(f"{args.events_file}: too few events to fit a sensor preset")
        name = args.preset_name or Path(args.events_file).stem
        origin = (f"the APS frames of {args.events_file}" if rec is not None
                  else size_origin(args.events_file, _size_arg(args)))
        write_sensor_preset(args.write_preset, sensor_preset(cal, name, shape, str(args.events_file),
                                                             origin, still))
    if args.out:
        write_json_atomic(args.out, out)
    else:
        print(json.dumps(json_safe(out), indent=2))  # NaN -> null: valid JSON
    return 0


def run_convert(args) -> int:
    from pathlib import Path

    import numpy as np

    from gs2e.common.atomic import check_writable
    from gs2e.common.errors import InputError
    from gs2e.events.containers import SUFFIX_CONTAINER, container_limits, write_container
    from gs2e.events.io import H5EventWriter, read_events, write_npz, write_text

    out = Path(args.output)
    suf = out.suffix.lower()
    writable = (*SUFFIX_CONTAINER, ".h5", ".hdf5", ".npz", ".txt")
    if suf not in writable:
        raise InputError(f"{out}: unknown output container '{suf or 'no suffix'}' "
                         f"(one of {', '.join(writable)})")
    check_writable(out)
    ev, shape = read_events(args.input, _size_arg(args))
    if not shape or not all(shape):
        raise InputError(f"{args.input}: the file gives no sensor size: pass --width and --height")
    if np.any(ev.t[1:] < ev.t[:-1]):
        raise InputError(f"{args.input}: timestamps are not sorted")
    H, W = shape
    if suf in SUFFIX_CONTAINER:
        why = container_limits(SUFFIX_CONTAINER[suf], W, H)
        if why:
            raise InputError(f"{out}: {why}")
        write_container(out, SUFFIX_CONTAINER[suf], ev, W, H)
    elif suf in (".h5", ".hdf5"):
        with H5EventWriter(out, W, H, int(ev.t[0]) if len(ev) else 0) as w:
            w.append(ev)
    elif suf == ".npz":
        write_npz(out, ev, W, H)
    else:
        write_text(out, ev)
    return 0


def run_presets(args) -> int:
    import json

    from gs2e.events.presets import PRESETS, effective_threshold_report
    from gs2e.events.sensors import sensor_table

    rows = effective_threshold_report(args.theta)
    for r in rows:
        r["k"] = list(PRESETS[r["preset"]].k)
    print(json.dumps({"sensors": sensor_table(), "voltmeter_presets": rows}, indent=2))
    return 0
