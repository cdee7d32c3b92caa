"""The QC report renders in real headless Chromium with every section and its plots."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pytest

from georef.config import load_config
from georef.evaluate import accuracy, frame_errors
from georef.pipeline import process
from georef.report import SECTIONS, write_report

DATA = Path(__file__).resolve().parents[1] / "data"
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def _chromium() -> str:
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        if os.environ.get("GEOREF_SKIP_BROWSER"):
            pytest.skip("GEOREF_SKIP_BROWSER is set and no chromium is installed")
        pytest.fail("headless Chromium is needed to test the report: `make test` installs Debian's chromium "
                    "(apt-get install chromium); set GEOREF_SKIP_BROWSER=1 to skip deliberately")
    return browser


def _render(browser: str, page: Path, tmp_path: Path, name: str) -> tuple[str, np.ndarray]:
    profile = tmp_path / f"profile-{name}"
    common = [browser, *CHROMIUM_FLAGS, f"--user-data-dir={profile}"]
    dom = subprocess.run([*common, "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=120,
                         check=True).stdout
    shot = tmp_path / f"{name}.png"
    subprocess.run([*common, "--window-size=1200,4200", f"--screenshot={shot}", page.as_uri()],
                   capture_output=True, timeout=120, check=True)
    return dom, mpimg.imread(shot)


def test_report_renders_in_headless_chromium(tmp_path):
    browser = _chromium()
    cfg = load_config(DATA / "flight.toml")
    result = process(DATA / "POS.txt", DATA / "Kamera.txt", cfg)
    import pandas as pd

    figures = accuracy(frame_errors(result.table, pd.read_csv(DATA / "truth.csv")))
    page = write_report(result, tmp_path / "report.html", accuracy=figures)
    for suffix in ("track", "position", "attitude", "innovations", "biases", "yaw_offset"):
        assert (tmp_path / f"report_{suffix}.png").stat().st_size > 10_000

    dom, screenshot = _render(browser, page, tmp_path, "report")
    for key, title in SECTIONS:
        assert f'id="{key}"' in dom
        assert title.split(" ")[0] in dom
    assert "rejected" in dom and "horizontal_rms_m" in dom
    # the quality checks: the verdict and one row per check
    assert "QC passed" in dom and "innovations" in dom and "mean normalised innovation squared" in dom

    # the same page without its PNGs: the coloured plot lines appear only when the plots are rendered
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(page, bare / "report.html")
    _, empty = _render(browser, bare / "report.html", tmp_path, "bare")

    def coloured(image: np.ndarray) -> float:
        rgb = image[..., :3]
        return float(np.mean(rgb.max(axis=-1) - rgb.min(axis=-1) > 0.25))

    assert coloured(screenshot) > 0.005, coloured(screenshot)
    assert coloured(empty) < 0.1 * coloured(screenshot), (coloured(empty), coloured(screenshot))
