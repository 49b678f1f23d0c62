"""Parameter sets as values (compare, hash, copy, JSON) and fastslam_edu.app.experiment's table of them."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from fastslam_edu.app.experiment import params_table
from fastslam_edu.landmark.fastslam import FastSLAMParams
from fastslam_edu.grid.gridslam import GridSLAMParams
from fastslam_edu.core.motion import MotionNoise


def test_params_table_spells_out_every_field():
    p = FastSLAMParams(n_particles=7, motion_noise=MotionNoise(sigma_v=0.03, sigma_omega=0.0),
                       measurement_cov=np.diag([0.1**2, 0.05**2]), measurement_correlation_s=None)
    col = params_table(p, "p")["p"]
    assert col["n_particles"] == 7 and col["measurement_correlation_s"] is None
    assert col["motion_noise.sigma_v"] == 0.03 and "motion_noise.sigma_omega" not in col  # zero entries left out
    assert (col["sigma_r [m]"], col["sigma_phi [rad]"]) == (0.1, 0.05)
    others = {f.name for f in dataclasses.fields(p)} - {"motion_noise", "measurement_cov"}
    assert others <= set(col.index)


def test_parameter_sets_are_values_json_and_copied_one_way():
    """FastSLAMParams and GridSLAMParams: ==, hash, read-only arrays, replace() validated, to_dict() round trip."""
    a, b = FastSLAMParams(), FastSLAMParams()
    assert a == b and hash(a) == hash(b) and len({a, b}) == 1
    with pytest.raises(ValueError, match="read-only"):
        a.measurement_cov[0, 0] = 1.0  # the default instance cannot be changed in place
    c = a.replace(measurement_cov=np.diag([0.1**2, 0.03**2]))
    assert c != a and hash(c) != hash(a) and a.measurement_cov[0, 0] == 0.07**2
    assert a.replace(motion_noise=a.motion_noise.replace(sigma_v=0.03)) != a
    with pytest.raises(ValueError, match="unknown setting"):
        a.replace(particles=3)
    with pytest.raises(ValueError, match="n_particles"):
        a.replace(n_particles=0)
    d = json.loads(json.dumps(a.to_dict()))
    assert set(d) == {f.name for f in dataclasses.fields(FastSLAMParams)}
    assert d["measurement_cov"] == [[0.07**2, 0.0], [0.0, 0.02**2]] and d["motion_noise"]["sigma_omega"] == 0.05
    rebuilt = FastSLAMParams(**{**d, "motion_noise": MotionNoise(**d["motion_noise"]),
                                "odometry_scale": tuple(d["odometry_scale"])})
    assert rebuilt == a
    g = GridSLAMParams(extent=(0.0, 1.0, 0.0, 2.0))
    assert g == GridSLAMParams(extent=(0.0, 1.0, 0.0, 2.0)) and g != GridSLAMParams()
    assert json.loads(json.dumps(g.to_dict()))["extent"] == [0.0, 1.0, 0.0, 2.0]