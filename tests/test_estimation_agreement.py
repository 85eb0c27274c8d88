"""One estimator: diagnose's fit of a candidate and identify's fit of the same drive with the same
effects are one computation (`vdsbi.estimation.fit_likelihood`), so they give the same estimate,
noise model and χ²/dof."""

import dataclasses

import numpy as np
import pytest
from test_likelihood import THETA, _drive

from vdsbi.discovery._fit import Fitter
from vdsbi.estimation import FitRequest, fit_likelihood
from vdsbi.problem import Box, ProblemSettings, make_problem, parameter_names, prior_box
from vdsbi.simulator import default_vehicle


def test_diagnose_and_identify_fit_one_drive_alike(x64):
    veh = default_vehicle()
    rec = _drive(duration=12.0)
    biased = dataclasses.replace(rec, channels={**rec.channels, "ay": rec.channels["ay"] + 0.3})
    settings = ProblemSettings(longitudinal="torque", max_window=6.0, channels=("ay", "yaw_rate"))
    prob = make_problem(biased, veh, settings)
    effects = ("sensor_bias",)
    # identify: the effects' own model, its prior box
    names = parameter_names(effects)
    box = Box.from_dict(prior_box(veh, effects), names)
    start = np.concatenate([THETA, [0.0, 0.0, 0.0]])
    ident = fit_likelihood(prob, start, box, FitRequest(free=names), effects=effects)
    # diagnose: every candidate effect in one model, the others at their null values
    fitter = Fitter(prob, dt=0.0025)
    z0 = fitter.initial_z(THETA)
    diag = fitter.fit(effects, z0, max_iter=40)
    # The same estimate up to where each fit's iterations stop: the two models round differently
    # (one holds every other candidate at its null value), and a parameter the drive barely
    # informs moves along its ridge by a sliver of its standard deviation.
    sd = np.sqrt(np.diag(ident.cov_z)) * np.asarray(box.dtheta_dz(ident.z))
    got = [diag.effect_params["sensor_bias"][p] for p in ("ax", "ay", "yaw_rate")]
    shift = (np.concatenate([diag.theta, got]) - ident.theta) / sd
    assert np.all(np.abs(shift[~np.isin(names, "sensor_bias.ax")]) < 0.1), shift
    assert got[0] == ident.theta[6] == 0.0  # a_x is not compared: its bias stays at its start
    assert diag.effect_params["sensor_bias"]["ay"] == pytest.approx(0.3, abs=0.05)
    # and the noise model measured at the two ends alike, far inside its own sampling spread
    np.testing.assert_allclose(diag.noise.scale, ident.noise.scale, rtol=1e-3)
    np.testing.assert_allclose(diag.noise.tau, ident.noise.tau, rtol=1e-2)
    assert diag.chi2_dof == pytest.approx(ident.chi2_dof, rel=1e-3)
