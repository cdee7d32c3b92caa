"""events.csv, the generic exposure file: columns, defaults, and every rejection located by line and column."""

from __future__ import annotations

import numpy as np
import pytest

from georef.io.camera import TRIGGER_TIME_SIGMA
from georef.io.errors import InputError
from georef.io.events import read_events


def _write(tmp_path, text: str):
    path = tmp_path / "events.csv"
    path.write_text(text, encoding="utf-8")
    return path


def test_times_only_get_frame_numbers_and_the_trigger_sigma_with_a_notice(tmp_path):
    exposures, names = read_events(_write(tmp_path, "time\n100.5\n101.5\n103.0\n"))
    assert exposures.frame.tolist() == ["1", "2", "3"] and names is None
    np.testing.assert_array_equal(exposures.time, [100.5, 101.5, 103.0])
    np.testing.assert_array_equal(exposures.time_sigma, TRIGGER_TIME_SIGMA)
    assert any("no time_sigma column" in n.message for n in exposures.notices)


def test_every_column_in_any_case_and_order(tmp_path):
    text = "Image,TIME_SIGMA,Frame,Time\nA.JPG,0.002,7,10.0\nB.JPG,0.05,9,12.5\n"
    exposures, names = read_events(_write(tmp_path, text))
    assert exposures.frame.tolist() == ["7", "9"]
    np.testing.assert_array_equal(exposures.time_sigma, [0.002, 0.05])
    assert names.names(["7", "9"]) == ["A.JPG", "B.JPG"]
    assert not any("no time_sigma column" in n.message for n in exposures.notices)


def test_a_row_cut_short_is_kept_and_flagged(tmp_path):
    """A line cut before its time (and so its image and sigma) is a flagged row, never an error about what it
    lacks; a row with a time but no image is the user's to fix (below)."""
    text = "time,image,time_sigma\n10.0,A.JPG,0.002\n\n12.0,C.JPG,0.002\n,\n"
    exposures, names = read_events(_write(tmp_path, text))
    assert np.isnan(exposures.time[-1]) and exposures.problem[-1] != ""
    assert exposures.time_sigma[-1] == TRIGGER_TIME_SIGMA
    assert names.names(exposures.frame.tolist())[-1] == ""


@pytest.mark.parametrize(("text", "line", "column", "words"), [
    ("time,image\n10.0,A.JPG\n11.0,\n", 3, "image", "empty cell"),
    ("time,image\n10.0,A.JPG\n11.0\n", 3, "image", "without an image name"),
    ("time\n10.0\n9.5\n", 3, "time", "go backwards"),
    ("time,frame\n10.0,4\n11.0,4\n", 3, "frame", "listed twice"),
    ("time,time_sigma\n10.0,0.1\n11.0,-0.1\n", 3, "time_sigma", "0 or positive"),
])
def test_rejections_name_line_and_column(tmp_path, text, line, column, words):
    with pytest.raises(InputError) as caught:
        read_events(_write(tmp_path, text))
    message = str(caught.value)
    assert "events.csv" in message and words in message
    assert caught.value.line == line and caught.value.column == column, message
