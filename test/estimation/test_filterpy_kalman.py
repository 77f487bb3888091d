"""``estimation.filterpy_kalman``: filterpy's KalmanFilter without ``scipy.stats`` at import.

Each check runs in a fresh interpreter (what a module imported decides what a process holds).
"""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

pytestmark = pytest.mark.e2e  # a fresh interpreter per check, a subprocess


def run(code: str) -> str:
    result = subprocess.run([sys.executable, '-c', textwrap.dedent(code)], capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_the_attitude_filter_does_not_import_scipy_stats() -> None:
    out = run("""
        import sys
        import enbarr_core.estimation.attitude_filter
        import filterpy.kalman
        print(sorted(m for m in sys.modules if m.startswith(('scipy.stats', 'filterpy.stats'))))
        print(filterpy.kalman.KalmanFilter is enbarr_core.estimation.attitude_filter.KalmanFilter)
    """)
    assert out.split('\n')[:2] == ['[]', 'True']


def test_the_likelihood_and_later_imports_get_filterpy_own_stats() -> None:
    out = run("""
        import sys
        import numpy as np
        from enbarr_core.estimation.filterpy_kalman import KalmanFilter
        kf = KalmanFilter(dim_x=2, dim_z=1)
        kf.x = np.array([[0.5], [1.0]])
        kf.F = np.array([[1.0, 0.1], [0.0, 1.0]])
        kf.H = np.array([[1.0, 0.0]])
        kf.P = np.diag([2.0, 3.0])
        kf.R = np.array([[0.4]])
        kf.predict()
        kf.update(np.array([[0.9]]))
        print('scipy.stats' in sys.modules)
        got = kf.log_likelihood                 # the stand-in's logpdf: imports the real one
        from scipy.stats import multivariate_normal
        want = multivariate_normal.logpdf(kf.y.ravel(), np.zeros(1), kf.S, allow_singular=True)
        print(abs(got - want) < 1e-12, np.isfinite(got))
        import filterpy.stats, filterpy.stats.stats
        print(filterpy.stats.logpdf is filterpy.stats.stats.logpdf,
              filterpy.stats.__file__.endswith('__init__.py'))
    """)
    assert out.split('\n')[:3] == ['False', 'True True', 'True True']


def test_an_already_imported_filterpy_is_left_alone() -> None:
    out = run("""
        import filterpy.stats
        real = filterpy.stats
        from enbarr_core.estimation.filterpy_kalman import KalmanFilter
        import sys, filterpy.kalman.kalman_filter as kfm
        print(sys.modules['filterpy.stats'] is real, kfm.logpdf is real.logpdf)
    """)
    assert out.split('\n')[0] == 'True True'
