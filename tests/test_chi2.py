"""facecorr.chi2 (the χ² tail without scipy) against scipy.special.chdtrc."""

import numpy as np
import pytest
from scipy.special import chdtrc, chdtri

from facecorr.chi2 import chi2_sf
from facecorr.landmarks.patches import RUNAWAY_M2


@pytest.mark.parametrize("df", [1, 2, 3, 4, 5, 8, 13, 39, 40, 41, 80])
def test_matches_scipy(df):
    for x in np.concatenate([[0.0, 1e-12, 1e-3], np.linspace(0.01, 3 * df + 60, 400), [500.0, 1400.0, 5000.0]]):
        want = float(chdtrc(df, x))
        got = chi2_sf(df, x)
        assert got == pytest.approx(want, rel=1e-12, abs=1e-300), (df, x, got, want)


def test_edges():
    assert chi2_sf(3, -1.0) == 1.0 and chi2_sf(40, 0.0) == 1.0
    assert chi2_sf(3, np.inf) == 0.0 and chi2_sf(40, np.inf) == 0.0
    assert np.isnan(chi2_sf(3, np.nan))
    with pytest.raises(ValueError):
        chi2_sf(2.5, 1.0)


def test_the_patch_runaway_threshold_is_scipys():
    assert RUNAWAY_M2 == float(chdtri(3, 0.001))
