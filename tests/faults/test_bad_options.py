"""Fault injection (issue 25, item 8): options that used to be accepted and then stall or
crash the daemon or the replay, each now refused with one line before anything starts.

Before: ``--clock-start 1990-01-01`` started a daemon whose time gate refused every scan
(before 2000), ``9999-12-31`` overflowed (``OverflowError``), ``replay --rate 1e-300`` ended
in the catch-all "this is a bug", and ``--time-scale 1e-300`` killed the lab-folder thread
with a traceback (its poll wait overflowed).
"""

from __future__ import annotations

import pytest
from paths import REPLAY

from softsensor.cli import main

DEMO = REPLAY / "demo-day.mcap"


@pytest.mark.parametrize(("argv", "says"), [
    (["run", "--clock-start", "1990-01-01T00:00:00Z"], "clock_start must be between 2000"),
    (["run", "--clock-start", "9999-12-31T00:00:00Z"], "is not a time between 1970 and 2262"),
    (["run", "--clock-start", "2250-01-01T00:00:00Z"], "clock_start must be between 2000"),
    (["run", "--time-scale", "1e-300"], "service.time_scale must be >= 0.01"),
    (["replay", str(DEMO), "--out", "{tmp}/x.mcap", "--rate", "1e-300"],
     "rate must be between 0.01 and 1e+06"),
    (["replay", str(DEMO), "--out", "{tmp}/x.mcap", "--start", "9999-12-31"],
     "is not a time between 1970 and 2262"),
])
def test_an_option_that_would_stall_or_crash_is_refused_in_one_line(argv, says, tmp_path,
                                                                     capsys):
    argv = [a.replace("{tmp}", str(tmp_path)) for a in argv]
    argv += ["--data-dir", str(tmp_path / "rec"), "--checkpoint", str(tmp_path / "c.json"),
             "--no-record"] if argv[0] == "run" else []
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("softsensor") and says in err and "\n" not in err, err
    assert not (tmp_path / "x.mcap").exists() and not (tmp_path / "rec").exists()
