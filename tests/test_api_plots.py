"""Figures: readable units, density contours that hold what they say, a pair plot over the
prior box."""

import numpy as np
import pytest

from vdsbi.api.plots import ParameterAxes, _mass_levels, display_unit, pairplot


def test_stiffness_reads_in_kilonewtons():
    assert display_unit("N/rad") == (1e-3, "kN/rad")
    assert display_unit("N") == (1e-3, "kN")
    assert display_unit("m/s^2") == (1.0, "m/s²")


@pytest.mark.parametrize("mass", [0.5, 0.9])
def test_contour_levels_hold_their_mass(mass):
    h = np.random.default_rng(0).gamma(1.0, size=(40, 40))
    (level,) = _mass_levels(h, (mass,))
    held = h[h >= level].sum() / h.sum()
    assert mass <= held < mass + 0.02


def test_pairplot_over_the_prior_box_with_truth(tmp_path):
    rng = np.random.default_rng(0)
    samples = np.stack([rng.uniform(0.7, 2.0, 500), rng.normal(7e4, 5e3, 500)], 1)
    pairplot(
        samples,
        ["l_f", "C_alpha_f"],
        tmp_path / "p.png",
        truth=np.array([1.5, np.nan]),
        axes=ParameterAxes(box=[(0.7, 2.0), (2e4, 2.2e5)], units=["m", "N/rad"], faded=[True, False]),
    )
    assert (tmp_path / "p.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
