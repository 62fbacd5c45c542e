"""PILCO's state representations built from the plant's observations."""

from __future__ import annotations

import numpy as np
import pytest

from softpend.pilco import state_spec
from softpend.plant import OBSERVATION_NAMES, PRBPlant


def _observations(n_steps: int = 60) -> np.ndarray:
    plant = PRBPlant()
    q, qd = plant.hanging_state()
    qd[0] = 3.0
    rows = [plant.reset(q, qd).as_array()]
    for k in range(n_steps):
        rows.append(plant.step(0.06 if (k // 10) % 2 == 0 else -0.06).as_array())
    return np.array(rows)


def test_tip_bend_state_is_built_from_observed_variables():
    obs = _observations()
    spec = state_spec("tip_bend")
    states = spec.from_observations(obs)
    col = {name: obs[:, OBSERVATION_NAMES.index(name)] for name in OBSERVATION_NAMES}
    bend = (col["phi_rad"] - col["theta_rad"] + np.pi) % (2 * np.pi) - np.pi
    np.testing.assert_allclose(states[:, 0], col["theta_dot_rad_s"])
    np.testing.assert_allclose(states[:, 1], col["phi_dot_rad_s"] - col["theta_dot_rad_s"])
    np.testing.assert_allclose(np.sin(states[:, 2]), np.sin(bend), atol=1e-12)
    # hanging: theta wraps between -pi and pi in the observation but is continuous in the state
    assert np.max(np.abs(np.diff(states[:, 3]))) < 1.0
    np.testing.assert_allclose(np.cos(states[:, 3]), np.cos(col["theta_rad"]), atol=1e-12)
    # the bending is real for the soft rod and the state differences see it
    assert np.max(np.abs(states[:, 2])) > 0.02
    inputs = spec.model_inputs(states)
    assert inputs.shape == (len(obs), spec.n_model_inputs) == (len(obs), 5)
    np.testing.assert_allclose(inputs[:, 3:], np.column_stack([np.sin(states[:, 3]), np.cos(states[:, 3])]))


def test_unknown_state_name_raises():
    with pytest.raises(ValueError, match="state"):
        state_spec("joint")
