"""The fleet's page: `accel-calib report --history DB --output fleet.html` writes one self-contained HTML
file (no reference to any other file or host), checked in a real browser (headless chromium): the DOM after
its script ran shows each IMU's status and one chart per IMU, and its screenshot is not blank."""
from __future__ import annotations

import re

import numpy as np

from accel_calibration.cli.main import main
from accel_calibration.io.history import open_history

from helpers.browser import dom_after_scripts, screenshot
from helpers.flight_series import rows, z_series


def write_page(tmp_path, capsys):
    target = str(tmp_path / "fleet.sqlite")
    with open_history(target) as history:
        history.write_evidence(rows("uav07", 0, z_series(1, 60)) + rows("uav07", 1, z_series(2, 41, step_mg=5.0,
                                                                                          step_at=40)) +
                               rows("uav08", 0, z_series(3, 60)) + rows("uav08", 1, z_series(4, 6)))
    page = tmp_path / "fleet.html"
    capsys.readouterr()
    assert main(["report", "--history", target, "--output", str(page)]) == 0
    assert "4 IMUs: 1 moved, 2 hold, 1 cannot tell" in capsys.readouterr().out
    return page


def test_the_page_is_one_file_that_needs_no_network(tmp_path, capsys):
    text = write_page(tmp_path, capsys).read_text(encoding="utf-8")
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//)""", text)  # nothing fetched: no CDN, no host
    assert "<script src" not in text and "<link" not in text
    assert text.count('data-status="moved"') == 2  # its cell in the grid and its section


def test_the_page_in_a_browser_shows_the_statuses_and_draws_every_chart(tmp_path, capsys):
    page = write_page(tmp_path, capsys)
    dom = dom_after_scripts(page)
    assert 'data-charts="4"' in dom  # the script ran and drew one chart per IMU
    cells = re.findall(r'<td class="status [^"]+" data-status="([^"]+)" title="vehicle (\S+) IMU (\d)', dom)
    assert sorted(cells) == [("cannot tell", "uav08", "2"), ("holds", "uav07", "1"), ("holds", "uav08", "1"),
                             ("moved", "uav07", "2")]
    assert "vehicle uav07 IMU 2 (device 1442060): bias z or scale z +" in dom and ": recalibrate" in dom
    assert dom.count('class="flight"') == 60 + 41 + 60 + 6  # a point per flight with evidence
    assert dom.count('class="change"') == 1
    png = screenshot(page, tmp_path / "fleet.png")
    from PIL import Image

    pixels = np.asarray(Image.open(png).convert("RGB"), dtype=float)
    assert pixels.std() > 10  # not blank: text, cells and charts drawn
    moved_red = np.all(np.abs(pixels - [0xF8, 0xC4, 0xC0]) < 4, axis=2)
    assert moved_red.sum() > 200  # the moved IMU's cell is painted


def test_without_a_browser_the_test_skips_saying_why_and_fails_under_ci(monkeypatch):
    import pytest

    from helpers import browser

    monkeypatch.setattr(browser.shutil, "which", lambda name: None)
    monkeypatch.setenv("CI", "false")
    with pytest.raises(pytest.skip.Exception, match="no chromium on PATH"):
        browser.chromium()
    monkeypatch.setenv("CI", "true")
    with pytest.raises(pytest.fail.Exception, match="CI=true"):
        browser.chromium()


def test_a_history_without_flight_evidence_is_one_line(tmp_path, capsys):
    from helpers.history_records import record

    target = str(tmp_path / "calibrations.sqlite")
    with open_history(target) as history:
        history.write([record(0)])
    assert main(["report", "--history", target, "--output", str(tmp_path / "fleet.html")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"accel-calib: error: {target}: no flight evidence of any IMU (write it with 'accel-calib fleet' "
                   "on flight logs)"]
    assert not (tmp_path / "fleet.html").exists()


def test_the_page_shows_the_in_flight_evidence_in_a_browser(tmp_path, capsys):
    """Beside the ground's chart, each IMU's filter bias and its agreement with its siblings, charted per
    flight; the IMU whose filter keeps learning a bias and the one that disagrees are the moved cells."""
    from accel_calibration.core.units import MG

    from helpers.flight_series import (
        AGREEMENT_SCATTER_MPS2,
        AGREEMENT_SIGMA_MPS2,
        ESTIMATOR_SCATTER_MPS2,
        ESTIMATOR_SIGMA_MPS2,
        axis_series,
        with_in_flight,
    )

    flights = 20
    fleet = []
    for imu in range(3):
        learning = axis_series(70 + imu, flights, ESTIMATOR_SIGMA_MPS2, ESTIMATOR_SCATTER_MPS2,
                               change_per_flight=0.5 * MG * (imu == 1), change_from=8)
        fleet += with_in_flight(rows("uav08", imu, z_series(80 + imu, flights)), estimator=learning,
                                agreement=axis_series(90 + imu, flights, AGREEMENT_SIGMA_MPS2, AGREEMENT_SCATTER_MPS2),
                                seed=imu)
        stepping = axis_series(100 + imu, flights, AGREEMENT_SIGMA_MPS2, AGREEMENT_SCATTER_MPS2,
                               step=3.0 * MG * (imu == 2), step_at=14)
        fleet += with_in_flight(rows("uav09", imu, z_series(110 + imu, flights)), agreement=stepping, seed=imu)
    target = str(tmp_path / "fleet.sqlite")
    with open_history(target) as history:
        history.write_evidence(fleet)
    page = tmp_path / "fleet.html"
    capsys.readouterr()
    assert main(["report", "--history", target, "--output", str(page)]) == 0
    assert "6 IMUs: 2 moved, 4 hold, 0 cannot tell" in capsys.readouterr().out
    dom = dom_after_scripts(page)
    # uav08: ground, filter and agreement charts; uav09 logs no filter: ground and agreement.
    assert 'data-charts="15"' in dom
    assert dom.count('data-kind="estimator"') == 3 and dom.count('data-kind="agreement"') == 6
    cells = re.findall(r'<td class="status [^"]+" data-status="([^"]+)" title="vehicle (\S+) IMU (\d)', dom)
    assert sorted(c for c in cells if c[0] == "moved") == [("moved", "uav08", "2"), ("moved", "uav09", "3")]
    assert "vehicle uav08 IMU 2 (device 1442060): the filter keeps learning a bias: accel bias z +" in dom
    assert "vehicle uav09 IMU 3 (device 3801122) disagrees with its siblings: accel z +" in dom
    assert dom.count('class="flight"') == 15 * flights  # a point per flight on every chart
    assert dom.count('class="change"') == 2
    assert dom.count('<td class="estimator">accel ') == 3 * flights  # per flight what the filter said
