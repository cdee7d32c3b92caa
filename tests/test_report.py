"""The QC report: one self-contained HTML file with every section, readable tables and its plots, rendered in
real headless Chromium; the forward-against-smoothed separation it shows is the forward filter's own solution;
``georef process --report`` writes the table and the report together or neither."""

from __future__ import annotations

import base64
import dataclasses
import hashlib
import html
import io
import os
import re
import resource
import shutil
import stat
import subprocess
import sys
from html.parser import HTMLParser
from importlib.metadata import version
from pathlib import Path

import matplotlib.image as mpimg
import numpy as np
import pandas as pd
import pytest
from PIL import Image

from georef.config import load_config
from georef.evaluate import accuracy, frame_errors
from georef.frames import C_e_n, wrap_pi
from georef.pipeline import process
from georef.report import SECTIONS, utc, write_report

DATA = Path(__file__).resolve().parents[1] / "data"
#: tall enough for the whole report: the screenshot then shows every section, and scroll bars would mean overflow
WINDOW_HEIGHT = 14_000
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
    subprocess.run([*common, f"--window-size=1200,{WINDOW_HEIGHT}", f"--screenshot={shot}", page.as_uri()],
                   capture_output=True, timeout=120, check=True)
    with Image.open(shot) as image:
        return dom, np.asarray(image.convert("RGB"), dtype=np.float32) / 255.0


class _Text(HTMLParser):
    """The visible text of a page, and of each <section> by id."""

    def __init__(self) -> None:
        super().__init__()
        self.parts: list[str] = []
        self.sections: dict[str, list[str]] = {}
        self.current: str | None = None
        self.skip = 0

    def handle_starttag(self, tag, attrs):
        if tag == "section":
            self.current = dict(attrs).get("id")
            self.sections[self.current] = []
        if tag in ("style", "title"):
            self.skip += 1
        if tag in ("td", "th", "p", "tr", "h2", "h3"):
            self.handle_data(" \n ")

    def handle_endtag(self, tag):
        if tag in ("style", "title"):
            self.skip -= 1

    def handle_data(self, data):
        if self.skip:
            return
        self.parts.append(data)
        if self.current is not None:
            self.sections[self.current].append(data)

    def text(self, section: str | None = None) -> str:
        return "".join(self.parts if section is None else self.sections[section])


def _text(page: str) -> _Text:
    parser = _Text()
    parser.feed(page)
    return parser


@pytest.fixture(scope="module")
def rts():
    return process(DATA / "POS.txt", DATA / "Kamera.txt", load_config(DATA / "flight.toml"))


def test_utc_formatting():
    assert utc(24513.0) == "06:48:33.0"
    assert utc(24692.9925, 2) == "06:51:32.99" and utc(59.96) == "00:01:00.0"
    assert utc(86400.0 + 5.0, 0) == "00:00:05 (+1 d)"
    assert utc(float("nan")) == "—"


@pytest.mark.slow  # Chromium renders the page: about 20 s
def test_report_is_one_self_contained_file_and_renders_in_headless_chromium(rts, tmp_path):
    browser = _chromium()
    figures = accuracy(frame_errors(rts.table, pd.read_csv(DATA / "truth.csv")))
    folder = tmp_path / "out"
    page = write_report(rts, folder / "report.html", accuracy=figures,
                        inputs={"configuration": DATA / "flight.toml", "not given": None})
    assert sorted(p.name for p in folder.iterdir()) == ["report.html"]  # one file: no PNGs, no temporary file
    source = page.read_text()

    # nothing outside the file: every image a PNG data URI, every link an anchor, no scripts or style sheets
    images = re.findall(r'<img src="([^"]*)"', source)
    assert len(images) == 9  # separation, accuracy, track, GNSS, innovations, position, attitude, biases, yaw
    for uri in images:
        assert uri.startswith("data:image/png;base64,")
        png = mpimg.imread(io.BytesIO(base64.b64decode(uri.split(",", 1)[1])), format="png")
        assert min(png.shape[:2]) >= 250 and max(png.shape[:2]) >= 500, png.shape  # large enough to read
    assert all(h.startswith("#") for h in re.findall(r'href="([^"]*)"', source))
    assert "<script" not in source and "<link" not in source and "url(" not in source

    dom, screenshot = _render(browser, page, tmp_path, "report")
    text = _text(dom)
    for key, title in SECTIONS:
        assert f'id="{key}"' in dom and title in text.text(key), key
    # the title names the flight (the POS log's folder), not the report file
    assert "<title>georef quality report: flight data</title>" in dom
    assert "Quality report: flight data" in text.text()

    # readable: no Python tuples, lists, None or bare time-of-day seconds in the visible text
    visible = text.text()
    assert not re.search(r"\(\s*-?\d+\.\d+,\s*-?\d+\.\d+\s*\)", visible), "a raw tuple"
    assert not re.search(r"\[\s*\d+(,\s*\d+)*\s*\]", visible), "a raw list"
    assert not re.search(r"\bNone\b|\bTrue\b|\bFalse\b", visible)
    summary = text.text("summary")
    assert "06:48:33.0 – 06:51:33.0 UTC (180.0 s)" in summary and "24513" not in summary
    assert "against the reference: horizontal RMS [m]" in summary
    assert f"{figures['horizontal_rms_m']:.3f}" in summary

    # the verdict and its reasons
    verdict = text.text("verdict")
    assert "QC passed" in verdict and "mean normalised innovation squared" in verdict

    # provenance: version, every input with its size and SHA-256, the mounting and the gate
    provenance = text.text("provenance")
    assert f"georef {version('georef')}" in provenance and "report written" in provenance
    for path in (DATA / "POS.txt", DATA / "Kamera.txt", DATA / "flight.toml"):
        assert hashlib.sha256(path.read_bytes()).hexdigest() in provenance
        assert f"{path.stat().st_size:,} bytes" in provenance
    cfg = rts.config
    assert "GNSS lever arm (IMU → antenna)" in provenance and "x 0.450, y 0.150, z −1.650 m" in provenance
    assert f"roll {cfg.mounting.boresight[0]:.3f}" in provenance and "N 1.00, E 1.00, U 2.00 m" in provenance
    assert "χ² 16.27 on the 3-D position innovation (99.90 % of good fixes pass)" in provenance
    # every setting of the ProcessingConfig, by its flight.toml key
    settings = text.text("settings")
    assert len(cfg.settings()) == 42
    for key in cfg.settings():
        assert key in settings, key

    # the flagged frames, every one of them with its flag and UTC time
    flagged = rts.table[rts.table["flag"] != ""]
    assert len(flagged) == 32
    section = text.text("flagged")
    assert f"{len(flagged)} of {len(rts.table)} frames are flagged" in section
    for frame, time, flag in zip(flagged["frame"], flagged["time"], flagged["flag"], strict=True):
        assert f"{frame} \n {utc(time, 2)} \n {flag}" in re.sub(r"\s*\n\s*", " \n ", section)

    # forward against smoothed, GNSS status from STATUS[HEX], no IMU gap in this log
    separation = text.text("separation")
    assert "inside ±2σ" in separation and "north [m]" in separation and "yaw [deg]" in separation
    gnss = text.text("gnss")
    assert "0x49" in gnss and "8,841" in gnss and "0x0" in gnss and "IMU data gaps: none" in gnss

    # the plots are drawn: the same page with its images removed has almost no coloured pixels
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "report.html").write_text(re.sub(r'src="data:image/png;base64,[^"]*"', 'src=""', source))
    _, empty = _render(browser, bare / "report.html", tmp_path, "bare")

    def coloured(image: np.ndarray) -> float:
        rgb = image[..., :3]
        return float(np.mean(rgb.max(axis=-1) - rgb.min(axis=-1) > 0.25))

    assert coloured(screenshot) > 0.005, coloured(screenshot)
    assert coloured(empty) < 0.1 * coloured(screenshot), (coloured(empty), coloured(screenshot))
    # the whole page fits the window: no scroll bar at the right or the bottom edge (the page is not wider than
    # 1200 px: the navigation wraps, the tables and plots fit), and the bottom of the page is blank
    assert np.all(screenshot[:, -16:] > 0.9) and np.all(screenshot[-16:] > 0.9)


def test_forward_separation_is_the_forward_filter_against_the_smoother(rts):
    """``nav.forward`` holds ``--method ekf``'s own solution (the same forward pass) minus the smoothed one at the
    filter's epochs, and the variances P_forward - P_smoothed."""
    ekf = process(DATA / "POS.txt", DATA / "Kamera.txt", load_config(DATA / "flight.toml").updated(method="ekf"))
    assert ekf.nav.forward is None
    sep = rts.nav.forward
    assert len(sep.time) > 300  # 2 Hz covariance epochs and every GNSS fix over 3 minutes
    rows = np.searchsorted(rts.nav.time, sep.time)
    np.testing.assert_array_equal(rts.nav.time[rows], sep.time)
    s, f = rts.nav, ekf.nav
    assert f.valid[rows].all() and s.valid[rows].all()
    expected = np.einsum("nij,nj->ni", C_e_n(s.lat[rows], s.lon[rows]), f.r_e[rows] - s.r_e[rows])
    np.testing.assert_allclose(sep.position, expected, rtol=0, atol=1e-6)
    for k, angle in enumerate(("roll", "pitch", "yaw")):
        difference = wrap_pi(getattr(f, angle)[rows] - getattr(s, angle)[rows])
        np.testing.assert_allclose(sep.attitude[:, k], difference, rtol=0, atol=1e-9)
    np.testing.assert_allclose(sep.forward_position_sigma**2, f.pos_var_n[rows], rtol=1e-9)
    np.testing.assert_allclose(sep.forward_attitude_sigma, f.att_sigma[rows], rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(sep.position_sigma**2, np.maximum(f.pos_var_n[rows] - s.pos_var_n[rows], 0.0),
                               rtol=1e-9, atol=1e-12)
    # the smoother never claims to be worse than the forward filter, and the separation is not trivially zero
    assert np.all(s.pos_var_n[rows] <= f.pos_var_n[rows] * (1 + 1e-9))
    assert np.sqrt(np.mean(sep.position**2)) > 0.1
    # the separation is as large as the covariances say (measured on this flight: 95.5, 99.2, 95.5 % of the
    # epochs inside +-2 sigma north, east, down; epochs are correlated, so a wide band)
    inside = np.mean(np.abs(sep.position) <= 2 * sep.position_sigma, axis=0)
    assert np.all(inside > 0.85) and np.all(inside <= 1.0), inside


def _gap_log(tmp_path: Path) -> Path:
    """data/POS.txt with 30 rows (0.6 s) cut out after line 5001 and STATUS[HEX] 0x4D on 500 rows."""
    lines = (DATA / "POS.txt").read_text().splitlines(keepends=True)
    kept = lines[:5001] + lines[5031:]
    kept = [line.rsplit("\t", 1)[0] + "\t4D\n" if 6001 <= k <= 6500 else line for k, line in enumerate(kept)]
    path = tmp_path / "gap" / "POS.txt"
    path.parent.mkdir()
    path.write_text("".join(kept))
    return path


@pytest.mark.parametrize("method", ["ekf", "axis"])
def test_report_lists_imu_gaps_and_status_changes_for_every_method(tmp_path, method):
    pos = _gap_log(tmp_path)
    result = process(pos, DATA / "Kamera.txt", load_config(DATA / "flight.toml").updated(method=method))
    page = write_report(result, tmp_path / "report.html")
    text = _text(page.read_text())
    assert "Quality report: flight gap" in text.text()
    log = result.log
    k = int(np.flatnonzero(log.lines == 5001)[0])  # the last row before the cut, by its line in the file
    assert log.lines[k + 1] == 5002 and int(log.data["counter"][k + 1]) - int(log.data["counter"][k]) == 31
    gnss = re.sub(r"\s*\n\s*", " | ", text.text("gnss"))
    assert f"{utc(log.time[k], 2)} | {utc(log.time[k + 1], 2)} | {log.time[k + 1] - log.time[k]:.3f}" in gnss
    status = log.data["status"]
    change = np.flatnonzero(status == 0x4D)
    assert len(change) == 500
    assert (f"0x4D | 500 | 5.6 % | {utc(log.time[change[0]], 0)}–"
            f"{utc(log.time[change[-1]] + 1 / log.sample_rate_hz, 0)}") in gnss
    separation = text.text("separation")
    if method == "ekf":
        assert "Method ekf is the forward filter alone" in separation
    else:
        assert "Method axis has no forward filter pass" in separation
        assert "Not estimated by method axis" in text.text("biases")
    assert "record counter skips 30 record(s)" in text.text("summary")


def test_report_says_when_there_is_no_status_column(rts, tmp_path):
    data = {k: v for k, v in rts.log.data.items() if k != "status"}
    result = dataclasses.replace(rts, log=dataclasses.replace(rts.log, data=data))
    from georef.report import _status_table

    assert "The POS log has no STATUS[HEX] column" in html.unescape(_status_table(result))


def test_process_writes_table_and_report_together_or_neither(tmp_path):
    """A write that fails for lack of space (the kernel's file-size limit, EFBIG, in a child process) while the
    report is written: exit 2, a message naming the report, and neither the table nor any part of the report."""
    out = tmp_path / "out"
    args = ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config", str(DATA / "flight.toml"), "-o",
            str(out / "eo.csv"), "--report", str(out / "report.html"), "-q"]
    code = "import sys; from georef_cli.main import app; sys.argv[0] = 'georef'; app()"

    def limited() -> None:  # the table (about 200 kB) fits, the report (about 600 kB) does not
        resource.setrlimit(resource.RLIMIT_FSIZE, (400_000, 400_000))

    run = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300,
                         preexec_fn=limited)
    assert run.returncode == 2, run.stderr
    assert "report.html: could not write it: File too large" in run.stderr
    assert not out.exists() or sorted(p.name for p in out.iterdir()) == []
    # without the limit both are written, and the report records the command
    run = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    assert sorted(p.name for p in out.iterdir()) == ["eo.csv", "report.html"]
    page = (out / "report.html").read_text()
    assert "georef process" in page and "--report" in page


def test_process_refuses_a_device_or_protected_output_before_processing(tmp_path):
    from georef_cli.main import app
    from typer.testing import CliRunner

    protected = tmp_path / "report.html"
    protected.write_text("delivered\n")
    protected.chmod(0o444)
    result = CliRunner().invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "--config",
                                      str(DATA / "flight.toml"), "-o", str(tmp_path / "eo.csv"), "--report",
                                      str(protected), "-q"])
    assert result.exit_code == 2, result.output
    assert "report.html: is write-protected (mode 0444)" in result.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.html"] and protected.read_text() == "delivered\n"
    fifo = tmp_path / "eo.csv"
    os.mkfifo(fifo)
    result = CliRunner().invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "-o", str(fifo)])
    assert result.exit_code == 2 and "eo.csv: is a FIFO (named pipe), not a regular file" in result.output
    # -o /dev/null as root: a node with /dev/null's numbers in our folder, so that a regression replaces only it
    null = tmp_path / "null"
    try:
        os.mknod(null, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    except PermissionError:
        return  # not root: the FIFO above took the same path (tests/io/test_atomic.py says so when it skips)
    result = CliRunner().invoke(app, ["process", str(DATA / "POS.txt"), str(DATA / "Kamera.txt"), "-o", str(null)])
    assert result.exit_code == 2 and "null: is a character device, not a regular file" in result.output
    assert stat.S_ISCHR(os.lstat(null).st_mode)
