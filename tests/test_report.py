"""The HTML report: plotting functions, the self-contained HTML, missing
inputs, the real recording comparison, `gs2e report` and the workflow rule."""

from __future__ import annotations

import html.parser
import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gs2e.common.errors import InputError
from gs2e.events.io import H5EventWriter
from gs2e.events.models import Events
from gs2e.events.stats import StatsAccumulator, event_stats
from gs2e.io.images import write_png
from gs2e.report import html as H
from gs2e.report import plots as P
from gs2e.report.build import build_report, n_images
from gs2e.report.io import read_benchmarks, read_real_events
from gs2e.report.settings import MetricsSettings
from tests.conftest import run_cli, run_snakemake, shared_data


def _ev(t, x, y, p) -> Events:
    return Events(np.asarray(t, np.int64), np.asarray(x, np.uint16), np.asarray(y, np.uint16),
                  np.asarray(p, np.uint8))


class _Parsed(html.parser.HTMLParser):
    """Headings, images and 'missing' markers of a report."""

    def __init__(self, text: str):
        super().__init__()
        self.h2, self.h3, self.img_src, self.missing, self.links = [], [], [], [], []
        self._tag, self._cls = None, None
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        self._tag, self._cls = tag, a.get("class")
        if tag == "img":
            self.img_src.append(a["src"])
        if tag in ("link", "script") or (tag == "a" and not a.get("href", "#").startswith("#")):
            self.links.append((tag, a))

    def handle_data(self, data):
        if self._tag in ("h2", "h3") and data.strip():
            getattr(self, self._tag).append(data.strip())
        if self._cls == "missing" and data.strip():
            self.missing.append(data.strip())

    def handle_endtag(self, tag):
        self._tag, self._cls = None, None


# ---------------------------------------------------------------- plots
def test_event_rate_tiles_the_stream_without_a_partial_last_bin():
    # 10 x 10 pixels, one event every 10 us for 1 s: 1000 events/pixel/s everywhere,
    # also in the last bin (a fixed bin width would leave a partial, low last bin)
    t = np.arange(0, 1_000_000, 10)
    c, r = P.event_rate(t, 100, 7)
    assert len(c) == 7 and np.allclose(r, 1000.0, rtol=2e-4)
    assert c[0] == pytest.approx(1e6 / 7 / 2 * 1e-6, rel=1e-5)
    assert P.event_rate(np.zeros(0, np.int64), 100, 5)[0].size == 0


def test_iei_histogram_is_per_pixel_and_normalised_per_decade():
    # two pixels firing alternately every 1 ms: pooled intervals would be 1 ms,
    # per-pixel intervals are 2 ms
    n = 400
    t = np.arange(n) * 1000
    ev = _ev(t, np.arange(n) % 2, np.zeros(n), np.ones(n))
    acc = StatsAccumulator((1, 2))
    acc.update(ev)
    edges, dens = P.iei_histogram(acc, bins_per_decade=10)
    assert np.sum(dens * np.diff(np.log10(edges))) == pytest.approx(1.0, rel=1e-9)
    k = int(np.argmax(dens))
    assert edges[k] <= 2.0 < edges[k + 1]
    assert np.count_nonzero(dens) == 1
    # ~10 bins per decade
    assert np.log10(edges[1] / edges[0]) == pytest.approx(0.1, rel=0.01)
    empty = StatsAccumulator((1, 2))
    assert P.iei_histogram(empty)[1].size == 0


def test_preview_window_centres_on_nearest_frame_and_stays_in_stream():
    ev = _ev([1000, 50_000, 100_000], [0, 0, 0], [0, 0, 0], [1, 1, 1])
    assert P.preview_window_us(ev, np.array([0, 40_000, 70_000]), 10_000) == (35_000, 45_000, 1)
    assert P.preview_window_us(ev, np.array([0]), 10_000) == (1000, 11_000, 0)  # clamped
    assert P.preview_window_us(ev, None, 10_000) == (45_500, 55_500, None)
    assert P.preview_window_us(ev, None, 1e6)[:2] == (1000, 1_001_000)


def test_event_preview_colours_net_polarity_inside_the_window_only():
    # pixel (0,0): 2 ON 1 OFF -> blue; (1,0): OFF -> red; (2,0): ON+OFF -> background;
    # (3,0): ON outside the window -> background
    ev = _ev([10, 11, 12, 13, 14, 15, 99], [0, 0, 0, 1, 2, 2, 3], [0] * 7, [1, 1, 0, 0, 1, 0, 1])
    bg = np.full((2, 4, 3), 200, np.uint8)
    img = P.event_preview(ev, (2, 4), 10, 50, bg)
    assert tuple(img[0, 0]) == P.ON_RGB and tuple(img[0, 1]) == P.OFF_RGB
    assert tuple(img[0, 2]) == (120, 120, 120) and tuple(img[0, 3]) == (120, 120, 120)
    grey = P.event_preview(ev, (2, 4), 10, 50, None)
    assert tuple(grey[1, 0]) == (128, 128, 128)
    with pytest.raises(ValueError, match="does not match"):
        P.event_preview(ev, (2, 4), 10, 50, np.zeros((4, 2, 3), np.uint8))


def test_figures_empty_inputs_missing_cells_and_deterministic_png():
    assert P.speed_error_figure({}) is None and P.speed_error_figure({"a": None}) is None
    assert P.event_stats_figure([]) is None and P.benchmark_figure(pd.DataFrame()) is None
    curve = pd.DataFrame({"train_time_s": [1.0, 2.0], "psnr": [20.0, 22.0], "ssim": [0.5, 0.6]})
    a, b = (P.fig_png(P.speed_error_figure({"s": curve})) for _ in range(2))
    assert a == b and a[:8] == b"\x89PNG\r\n\x1a\n"
    fig = P.speed_error_figure({"s": curve})
    ax = fig.axes[0]
    assert "(s)" in ax.get_xlabel() and "(dB)" in ax.get_ylabel()
    bench = pd.DataFrame({"rule": ["train", "sfm"], "s": [3.0, 1.0], "cpu_time": [2.0, None],
                          "max_rss": [100.0, 50.0]})
    fig = P.benchmark_figure(bench)
    texts = [t.get_text() for t in fig.axes[1].texts]
    assert texts == [" 2", " missing"]  # each value written; the NaN CPU time marked, not drawn as 0
    # a log axis: the 1 s job's bar is not a sliver beside the 3 s one
    assert all(ax.get_xscale() == "log" for ax in fig.axes)
    assert [ax.get_xlabel() for ax in fig.axes] == [f"{lab}, log scale" for _, lab in P.BENCH_PANELS]


def test_image_png_shrinks_to_max_side():
    import cv2

    img = np.zeros((300, 600, 3), np.uint8)
    png = P.image_png(img, 150)
    dec = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert dec.shape == (75, 150, 3)
    assert cv2.imdecode(np.frombuffer(P.image_png(img), np.uint8), 1).shape == (300, 600, 3)


def test_html_is_self_contained_with_escaping_and_missing_cells():
    df = pd.DataFrame({"name": ["<b>x</b>", "y"], "v": [1.234567, float("nan")], "n": [3, 4]})
    sec = H.Section("Results & more", anchor="r").add(H.table(df)).add(H.missing("a <file>"))
    sec.add(H.image(b"\x89PNG fake", "alt", "cap"))
    text = H.assemble("T", [sec])
    doc = _Parsed(text)
    assert doc.h2 == ["Results & more"] and len(doc.img_src) == 1 and not doc.links
    assert doc.img_src[0].startswith("data:image/png;base64,")
    assert "<b>x</b>" not in text and "&lt;b&gt;x&lt;/b&gt;" in text
    assert "1.235" in text and doc.missing == ["missing", "missing: a <file>"]


# ---------------------------------------------------------------- a synthetic results tree
def _results_tree(root: Path) -> Path:
    """Scene 'a' complete (curve, benchmarks, frames, events); scene 'b' has
    only a folder. 16 x 12 pixels."""
    res = root / "results"
    H_, W_ = 12, 16
    a = res / "a"
    (a / "splat").mkdir(parents=True)
    pd.DataFrame({"iteration": [10, 20], "train_time_s": [1.0, 2.5], "psnr": [15.0, 18.0],
                  "ssim": [0.3, 0.5]}).to_parquet(a / "splat" / "curve.parquet")
    (a / "benchmarks").mkdir()
    for rule, s in (("train", 2.5), ("render_t1", 1.0), ("sfm", 0.5)):
        (a / "benchmarks" / f"{rule}.tsv").write_text(
            "s\th:m:s\tmax_rss\tcpu_time\n" f"{s}\t0:00:01\t123.4\t{s * 0.9}\n")
    fdir = a / "frames" / "t1"
    rng = np.random.default_rng(0)
    for kind in ("rgb", "blur"):
        (fdir / kind).mkdir(parents=True)
        for i in range(3):
            write_png(fdir / kind / f"{i:06d}.png", rng.integers(0, 255, (H_, W_, 3), dtype=np.uint8))
    pd.DataFrame({"frame": [0, 1, 2], "file": [f"{i:06d}.png" for i in range(3)],
                  "t_us": [0, 10_000, 20_000]}).to_parquet(fdir / "frames.parquet")
    (a / "events" / "t1").mkdir(parents=True)
    n = 2000
    t = np.sort(rng.integers(0, 20_000, n))
    ev = _ev(t, rng.integers(0, W_, n), rng.integers(0, H_, n), rng.integers(0, 2, n))
    with H5EventWriter(a / "events" / "t1" / "events.h5", W_, H_, 0) as w:
        w.append(ev)
    (res / "b").mkdir()
    pd.DataFrame({"scene_id": ["a", "b"], "trajectory": ["t1", "t2"],
                  "train_test_psnr": [18.0, None], "events_n_events": [n, None]}
                 ).to_parquet(res / "summary.parquet")
    return res


def test_report_of_synthetic_tree_shows_sections_images_and_missing(tmp_path):
    res = _results_tree(tmp_path)
    timings = {}
    text = build_report(res, timings=timings)
    doc = _Parsed(text)
    assert doc.h2 == ["Dataset overview", "Dataset card", "Speed against error (training)",
                      "Benchmark: deblurring, video and 3D reconstruction, optical flow", "Real recording",
                      "Scene a", "Scene b"]
    assert doc.h3.count("Event statistics") == 2 and doc.h3.count("Thumbnails") == 2
    # the card's distributions; a: speed-error, costs, event stats, sharp + blur thumbnails,
    # preview; b: nothing
    assert len(doc.img_src) == n_images(text) == 7
    assert all(s.startswith("data:image/png;base64,") for s in doc.img_src) and not doc.links
    joined = "\n".join(doc.missing)
    for what in ("real recording for comparison", "training curve " + str(res / "b" / "splat"),
                 "trajectory plot", "t2: frames", "t2: events", "simulated events of scene b",
                 str(res / "b" / "benchmarks")):
        assert what in joined, what
    assert "over sharp frame 1" in text  # the frame nearest the middle of the events
    assert {"read summary", "speed against error", "scenes (2)"} <= set(timings)
    assert build_report(res) == text  # same results, same bytes (no date in the document)
    # benchmark rows come in pipeline order
    assert list(read_benchmarks(res / "a" / "benchmarks")["rule"]) == ["sfm", "train", "render_t1"]
    # a subset of scenes; an unknown scene is an error naming it
    assert _Parsed(build_report(res, scenes=["b"])).h2[-1] == "Scene b"
    capped = build_report(res, cfg=MetricsSettings.defaults(max_scene_sections=1))
    assert _Parsed(capped).h2[-1] == "Scene a" and "the first 1 of 2 scenes" in capped
    with pytest.raises(InputError, match="nope"):
        build_report(res, scenes=["nope"])


def test_report_without_summary_and_corrupt_inputs(tmp_path):
    res = _results_tree(tmp_path)
    (res / "summary.parquet").unlink()
    doc = _Parsed(build_report(res))
    assert doc.h2[-1] == "Scene a" and any("dataset summary" in m for m in doc.missing)
    (res / "a" / "splat" / "curve.parquet").write_bytes(b"not parquet")
    with pytest.raises(InputError, match="curve.parquet"):
        build_report(res)
    with pytest.raises(InputError, match="does not exist"):
        build_report(tmp_path / "absent")


def test_cli_writes_atomically_and_names_a_missing_recording(tmp_path):
    res = _results_tree(tmp_path)
    out = tmp_path / "out" / "r.html"
    bad = run_cli("report", "--results-dir", str(res), "--out", str(out),
                  "--real-events", str(tmp_path / "none.aedat4"))
    assert bad.returncode == 2 and "none.aedat4" in bad.stderr
    assert not out.parent.exists() or not any(out.parent.iterdir())  # nothing partial
    ok = run_cli("report", "--results-dir", str(res), "--out", str(out),
                 "--config-json", json.dumps({"preview_window_ms": 5.0}), check=True)
    assert out.exists() and "wrote" in ok.stderr and "report done in" in ok.stderr
    assert "events 0.0075-0.0125 s" in out.read_text()  # 5 ms window around frame 1
    assert run_cli("report", "--results-dir", str(res), "--config-json",
                   json.dumps({"preview_window_ms": -1})).returncode == 2


# ---------------------------------------------------------------- the real recording
def test_real_recording_series_matches_exact_statistics(tmp_path):
    path = shared_data("events", "dvxplorer_sample.aedat4")
    ev, shape, label = read_real_events(path)
    assert shape == (240, 320) and "DVXplorer" in label and "320x240" in label
    s = P.event_series(ev, shape, label, real=True)
    exact = event_stats(ev, shape)
    # the histogram-based median (0.5 % bins) agrees with the exact one
    assert s.stats["iei_median_ms"] == pytest.approx(exact["iei_median_ms"], rel=0.01)
    assert exact["iei_median_ms"] == pytest.approx(26.6, abs=0.1)
    assert np.sum(s.iei_density * np.diff(np.log10(s.iei_edges_ms))) == pytest.approx(1.0)
    # the rate integrates back to the event count
    dt_s = s.t_s[1] - s.t_s[0]
    assert np.sum(s.rate_hz) * dt_s * shape[0] * shape[1] == pytest.approx(len(ev), rel=1e-9)
    res = _results_tree(tmp_path)
    text = build_report(res, real_events=path)
    assert "real: DVXplorer 320x240 (dvxplorer_sample.aedat4)" in text
    assert n_images(text) == 7
    assert not any("real recording" in m for m in _Parsed(text).missing)


def test_real_recording_errors_name_the_file(tmp_path):
    with pytest.raises(InputError, match="x.aedat4"):
        read_real_events(tmp_path / "x.aedat4")
    p = tmp_path / "x.txt"
    p.write_text("1 0 0 1\n2 1 0 0\n")
    with pytest.raises(InputError, match="sensor size"):
        read_real_events(p)


# ---------------------------------------------------------------- the workflow
def test_workflow_builds_report_and_snakemake_report(tiny_pipeline, tmp_path):
    wd, args = tiny_pipeline
    report = wd / "results" / "report.html"
    assert report.exists()
    doc = _Parsed(report.read_text())
    assert "Scene tiny" in doc.h2 and len(doc.img_src) >= 5 and not doc.links
    # trajectory.plot=false in the tiny run: shown as missing, not faked
    assert any("trajectories.png" in m for m in doc.missing)
    # fixed sampling records how far the image moved per sample; the overview shows it
    summ = pd.read_parquet(wd / "results" / "summary.parquet")
    assert (summ["events_sampling_step_motion_px_max"] > 0).all()
    assert "events_sampling_step_motion_px_max" in report.read_text()
    assert (wd / "results" / "benchmarks" / "report.tsv").exists()
    out = tmp_path / "sm_report.html"
    proc = run_snakemake(*args, "--report", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert out.stat().st_size > 10_000 and "Dataset report" in out.read_text()
    # a configured real recording that does not exist is an error naming the key
    bad = run_snakemake(*args[:-1], args[-1], "metrics={real_events: no/such.aedat4}", "-n")
    msg = bad.stdout + bad.stderr
    assert bad.returncode != 0 and "metrics.real_events: no/such.aedat4 does not exist" in msg


def test_bench_table_shows_flow_as_endpoint_error():
    """The flow task's cells are "AEE px / share over 3 px", the others'
    "PSNR / SSIM"."""
    import math

    import pandas as pd

    from gs2e.report.build import bench_tables

    rows = []
    for task, method, v in (("flow", "zero", 5.0), ("flow", "contrast_max", 2.5), ("video", "integrate", 20.0)):
        for sp in ("mild", "strong"):
            rows.append({"scene_id": "a", "trajectory": f"base_{sp}", "preset": sp, "task": task,
                         "model": "ideal", "method": method, "psnr": math.nan if task == "flow" else v,
                         "ssim": math.nan if task == "flow" else 0.5, "motion_px_median": 1.0,
                         "aee_px": v if task == "flow" else math.nan,
                         "out_3px": 0.25 if task == "flow" else math.nan})
    tabs = bench_tables(pd.DataFrame(rows))
    flow = tabs["flow"].set_index("method")
    assert flow.loc["contrast_max", "mild"] == "2.50 px / 25.0%"
    assert tabs["video"].set_index("method").loc["integrate", "strong"] == "20.00 / 0.500"
