"""Plant units and local clock time for what people read (``[display]``, issue 13)."""

from __future__ import annotations

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from softsensor.errors import ConfigError  # noqa: E402
from softsensor.plantconfig import default_config_path, load_plant_config  # noqa: E402
from softsensor.presentation.calibration_figures import clock_axis  # noqa: E402
from softsensor.presentation.display import (  # noqa: E402
    DisplaySettings,
    celsius,
    display_settings,
    local_times,
    moisture_pct,
    moisture_pct_points,
)


def _cfg(tmp_path, table: str):
    p = tmp_path / "plant.toml"
    p.write_text(default_config_path().read_text() + "\n[display]\n" + table)
    return load_plant_config(p)


def test_the_table_is_validated_with_the_key_named(tmp_path):
    d = display_settings(_cfg(tmp_path, 'time_zone = "Europe/Stockholm"\n'))
    assert d.time_zone == "Europe/Stockholm" and d.moisture_basis == "wet"
    assert d.moisture_unit == "% wb"
    with pytest.raises(ConfigError, match=r"display\.time_zone 'Mars/Olympus'"):
        display_settings(_cfg(tmp_path, 'time_zone = "Mars/Olympus"\n'))
    with pytest.raises(ConfigError, match=r"display\.moisture_basis"):
        display_settings(_cfg(tmp_path, 'moisture_basis = "as received"\n'))
    with pytest.raises(ConfigError, match=r"display\.colour is not a known key"):
        display_settings(_cfg(tmp_path, 'colour = "red"\n'))
    assert display_settings(load_plant_config()) == DisplaySettings()


def test_local_clock_time_follows_daylight_saving():
    d = DisplaySettings(time_zone="Europe/Stockholm")
    # 2026-03-29 00:30 UTC (CET, +1) and 01:30 UTC (CEST, +2): the clocks go forward at 01:00
    t = np.array([1774744200, 1774747800]) * 10**9
    a, b = local_times(t, d)
    assert (a.hour, a.minute, a.utcoffset().total_seconds()) == (1, 30, 3600)
    assert (b.hour, b.minute, b.utcoffset().total_seconds()) == (3, 30, 7200)


def test_units_a_person_reads():
    assert celsius(348.15) == pytest.approx(75.0)
    np.testing.assert_allclose(moisture_pct(np.array([0.1, 1.0]), "wet"), [100 / 11, 50.0])
    np.testing.assert_allclose(moisture_pct(np.array([0.1, 1.0]), "dry"), [10.0, 100.0])


def test_figure_axis_shows_the_plant_clock():
    d = DisplaySettings(time_zone="America/New_York")
    t = local_times(np.arange(0, 2 * 3600, 600) * 10**9 + 1767607200 * 10**9, d)  # 10:00 UTC
    fig, ax = plt.subplots()
    ax.plot(t, np.arange(t.size))
    clock_axis(ax, d)
    fig.canvas.draw()
    labels = [x.get_text() for x in ax.get_xticklabels()]
    plt.close(fig)
    assert "05:00" in labels or "06:00" in labels, labels  # 10:00 UTC is 05:00 EST
    assert "10:00" not in labels, labels


def test_moisture_in_percent_on_either_basis():
    assert moisture_pct(0.1, "dry") == pytest.approx(10.0)
    assert moisture_pct(0.1, "wet") == pytest.approx(100 * 0.1 / 1.1)
    assert moisture_pct(1.0, "wet") == pytest.approx(50.0)
    assert moisture_pct_points(0.01, 0.1, "dry") == pytest.approx(1.0)
    assert moisture_pct_points(0.01, 0.1, "wet") == pytest.approx(100 * (0.11 / 1.11 - 0.1 / 1.1))
    with pytest.raises(ValueError, match="basis"):
        moisture_pct(0.1, "as received")
