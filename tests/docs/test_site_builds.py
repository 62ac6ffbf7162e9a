"""The documentation site builds with warnings as errors, as ``.ci/run`` builds it.

A page or docstring citing a ``softsensor`` name that is gone, a page no index reaches, a
docstring that is not valid reST: each is a warning, and a warning fails the build. About 45 s
of one core (measured on the development machine, load 4), so the default suite leaves it to
``.ci/run``'s build step, which runs the same command; ``-m slow`` runs it here.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from paths import REPO


@pytest.mark.slow
def test_the_site_builds_without_a_warning(tmp_path):
    pytest.importorskip("sphinx", reason="the docs extra is not installed "
                        "(pip install -e '.[docs]')")
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    done = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
         str(REPO / "docs"), str(tmp_path / "html")],
        capture_output=True, text=True, env=env, timeout=600, check=False)
    assert done.returncode == 0, done.stderr[-5000:]
    assert (tmp_path / "html" / "reference" / "config.html").is_file()
    assert (tmp_path / "html" / "reference" / "generated" / "softsensor.model.dryer.html").is_file()
