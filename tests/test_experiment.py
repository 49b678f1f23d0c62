"""fastslam_edu.experiment's parameter records: every field of FastSLAMParams, no more, no less."""

from __future__ import annotations

import dataclasses
import json

import numpy as np

from fastslam_edu.experiment import params_dict, params_table
from fastslam_edu.fastslam import FastSLAMParams
from fastslam_edu.motion import MotionNoise


def test_params_table_spells_out_every_field():
    p = FastSLAMParams(n_particles=7, motion_noise=MotionNoise(sigma_v=0.03, sigma_omega=0.0),
                       measurement_cov=np.diag([0.1**2, 0.05**2]), measurement_correlation_s=None)
    col = params_table(p, "p")["p"]
    assert col["n_particles"] == 7 and col["measurement_correlation_s"] is None
    assert col["motion_noise.sigma_v"] == 0.03 and "motion_noise.sigma_omega" not in col  # zero entries left out
    assert (col["sigma_r [m]"], col["sigma_phi [rad]"]) == (0.1, 0.05)
    others = {f.name for f in dataclasses.fields(p)} - {"motion_noise", "measurement_cov"}
    assert others <= set(col.index)


def test_params_dict_is_json_and_has_every_setting_that_changes_a_run():
    d = json.loads(json.dumps(params_dict(FastSLAMParams())))
    skipped = {f.name for f in dataclasses.fields(FastSLAMParams)} - set(d)
    assert skipped == {"measurement_cov"}  # given as measurement_std
    assert d["measurement_std"] == [0.07, 0.02]
