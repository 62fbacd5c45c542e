"""The design figures of the default rod (softpend.study.rod_design), checked against beam theory."""

from __future__ import annotations

import math

import numpy as np
import pytest

from softpend.plant import RodParams
from softpend.study.rod_design import clamped_upright_buckling_factor, rod_design, rod_poses_m
from softpend.task import Task


def test_default_rod_meets_the_design_targets():
    design = rod_design()
    assert 0.10 <= design.tip_sag_fraction <= 0.30
    assert design.torque_ratio < 1.0  # swing-up must pump
    assert design.buckling_load_factor > 1.0  # clamped upright rod stands
    table = design.to_markdown()
    assert table.count("\n") == 8 and all(line.count(" | ") == 2 for line in table.splitlines())  # 7 rows
    assert f"{100 * design.tip_sag_fraction:.0f} % of L" in table


def test_stiff_rod_sag_matches_euler_bernoulli():
    # small deflections: the PRB statics must approach the clamped-beam formula (trapezoidal error ~1/n^2)
    design = rod_design(RodParams(n_links=8, stiffness_scale=10.0))
    assert design.tip_sag_horizontal_m == pytest.approx(design.tip_sag_euler_bernoulli_m, rel=0.03)


def test_buckling_factor_matches_greenhill_self_weight_column():
    # uniform column clamped at the base, own weight only: (w L) L^2 / EI = 7.837 at buckling
    params = RodParams(n_links=16, tip_mass_kg=0.0)
    weight_per_m = params.mass_kg * params.gravity_mps2 / params.length_m
    greenhill = 7.837 * params.bending_stiffness_nm2 / (weight_per_m * params.length_m**3)
    assert clamped_upright_buckling_factor(params) == pytest.approx(greenhill, rel=0.01)


def test_buckling_factor_limits_and_scaling():
    base = clamped_upright_buckling_factor(RodParams())
    assert clamped_upright_buckling_factor(RodParams(stiffness_scale=3.0)) == pytest.approx(3 * base, rel=1e-4)
    assert clamped_upright_buckling_factor(RodParams(stiffness_scale=0.0)) == 0.0
    assert math.isinf(clamped_upright_buckling_factor(RodParams(gravity_mps2=0.0)))


def test_poses_come_from_the_plant_geometry():
    params = RodParams(n_links=4)
    poses = rod_poses_m(Task(rod=params))
    for name, points in poses.items():
        assert points.shape == (5, 2), name
        segment_lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
        np.testing.assert_allclose(segment_lengths, params.link_length_m, rtol=1e-9, err_msg=name)
    np.testing.assert_allclose(poses["hanging"][-1], [0.0, -params.length_m], atol=1e-12)
    np.testing.assert_allclose(poses["upright"][-1], [0.0, params.length_m], atol=1e-12)
    tip = poses["horizontal"][-1]
    assert tip[0] > 0.9 * params.length_m and tip[1] < 0  # points along +x and sags down
    assert np.all(np.diff(poses["horizontal"][:, 1]) < 0)  # every joint lower than the previous one


def test_beam_poses_agree_with_the_prb_chain():
    """The same three poses from the continuum beam's nodes: straight poses coincide, and the horizontal sag
    of the beam and of a fine PRB chain agree within a few percent (issue 8: the beam chapter measures it)."""
    params = RodParams(n_links=16)
    beam = rod_poses_m(Task(plant="beam", rod=params))
    prb = rod_poses_m(Task(rod=params))
    np.testing.assert_allclose(beam["hanging"][-1], prb["hanging"][-1], atol=1e-9)
    np.testing.assert_allclose(beam["upright"][-1], prb["upright"][-1], atol=1e-9)
    sag_beam, sag_prb = -beam["horizontal"][-1, 1], -prb["horizontal"][-1, 1]
    assert sag_beam > 0.1 * params.length_m
    assert sag_prb == pytest.approx(sag_beam, rel=0.03)
    with pytest.raises(ValueError, match="plant"):
        rod_poses_m(Task(plant="rubber", rod=params))
