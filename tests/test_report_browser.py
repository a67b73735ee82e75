"""The report as a reader sees it: pages rendered by a real headless browser
(Debian's Chromium) and checked on the screenshots, not on the HTML: a table
with missing cells keeps its grid, and a table wider than the page scrolls in
its own box instead of widening the page."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from gs2e.report import html as H

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="no chromium on this machine "
                                "(apt-get install chromium)")
WIDTH = 1280


def screenshot(page: str, tmp: Path, name: str, height: int = 700) -> np.ndarray:
    """(H, W, 3) uint8 screenshot of the HTML ``page`` at WIDTH px."""
    import cv2

    src, png = tmp / f"{name}.html", tmp / f"{name}.png"
    src.write_text(page)
    proc = subprocess.run([CHROMIUM, "--headless=new", "--no-sandbox", "--disable-gpu",
                           "--hide-scrollbars", f"--window-size={WIDTH},{height}",
                           f"--screenshot={png}", src.as_uri()], capture_output=True, text=True,
                          timeout=120)
    assert png.exists(), proc.stderr[-2000:]
    return cv2.imread(str(png))[:, :, ::-1]


def vertical_lines(img: np.ndarray) -> list[int]:
    """x of the table's vertical borders: columns where most rows of the table's
    band are border grey (#ddd) rather than white or text."""
    grey = np.all(np.abs(img.astype(int) - 0xDD) <= 6, axis=2)
    rows = np.where(grey.sum(axis=1) > 20)[0]  # the horizontal borders' rows
    band = grey[rows.min():rows.max() + 1]
    return [int(x) for x in np.where(band.mean(axis=0) > 0.8)[0]]


def test_missing_cells_keep_the_table_s_grid(tmp_path):
    with_missing = pd.DataFrame({"method": ["edi", "blurred"], "mild": [31.25, np.nan],
                                 "medium": [28.5, 22.0], "strong": [np.nan, 19.75]})
    # the same table with the word in plain cells: the grid a reader expects
    filled = with_missing.astype(object).where(with_missing.notna(), "missing")
    a = screenshot(H.assemble("t", [H.Section("s").add(H.table(with_missing))]), tmp_path, "a")
    b = screenshot(H.assemble("t", [H.Section("s").add(H.table(filled))]), tmp_path, "b")
    la, lb = vertical_lines(a), vertical_lines(b)
    assert len(lb) >= 5, lb  # five borders: four columns
    assert la == lb, f"column borders moved by the missing cells: {la} != {lb}"


def test_a_wide_table_scrolls_in_its_own_box(tmp_path):
    wide = pd.DataFrame({f"column_{i:02d}_with_a_long_name": [1.2345, 2.5] for i in range(18)})
    page = H.assemble("t", [H.Section("s").add(H.paragraph("text")).add(H.table(wide))])
    img = screenshot(page, tmp_path, "wide")
    ink = np.where((img < 200).any(axis=2).any(axis=0))[0]
    # the body is at most 1200 px wide, centred: nothing may reach past its right edge
    right_edge = (WIDTH + 1200) // 2
    assert ink.max() <= right_edge, f"content reaches x = {ink.max()} > {right_edge}"
    # and the table is there, filling the box
    assert ink.max() >= right_edge - 60
