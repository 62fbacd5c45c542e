"""The batched torch chain beside the Exudyn plant: how closely the two simulators agree.

:func:`hub_errors_rad` runs both from the same state under the same random torque against the Exudyn plant with
:data:`REFERENCE_SUBSTEPS` sub-steps (Figure 1's agreement section and ``softpend bench --only plant``).
"""

from __future__ import annotations

import math
from typing import NamedTuple, Optional

import numpy as np

from softpend.plant.params import RodParams
from softpend.plant.prb import PRBPlant
from softpend.torch_threads import one_torch_thread

__all__ = ["REFERENCE_SUBSTEPS", "HubErrorReference", "hub_error_inputs", "hub_error_reference", "hub_errors_rad"]

#: Sub-steps of the Exudyn reference run (converged to well below the errors compared).
REFERENCE_SUBSTEPS = 200


class HubErrorReference(NamedTuple):
    """The run that :func:`hub_errors_rad` compares simulators against (control steps of 0.01 s)."""

    params: RodParams
    torques_nm: np.ndarray  # (n_steps,), held over each control step
    q0: np.ndarray  # initial joint angles (hub angle from upright, then the spring angles) [rad]
    qd0: np.ndarray  # initial joint rates [rad/s]
    hub_rad: np.ndarray  # hub angle of the Exudyn plant with REFERENCE_SUBSTEPS sub-steps after each step [rad]


def _exudyn_hub_rad(
    params: RodParams, q0: np.ndarray, qd0: np.ndarray, torques: np.ndarray, substeps: int
) -> np.ndarray:
    plant = PRBPlant(params, substeps=substeps)
    plant.reset(q0, qd0)
    return np.array([(plant.step(t), plant.joint_state()[0][0])[1] for t in torques])


def hub_error_inputs(
    n_links: int, duration_s: float, seed: int = 0
) -> tuple[RodParams, np.ndarray, np.ndarray, np.ndarray]:
    """``(params, torques_nm, q0, qd0)`` of the comparison: the default rod of ``n_links`` links, ``duration_s``
    of random torque from ``seed`` (one value per 0.01 s control step) and the start (the hanging rod, hub
    turned 0.3 rad and spinning at 0.5 rad/s)."""
    params = RodParams(n_links=n_links)
    n_steps = int(round(duration_s / 0.01))
    torques = np.random.default_rng(seed).uniform(-1, 1, n_steps) * params.torque_limit_nm
    q0 = np.zeros(n_links + 1)
    qd0 = np.zeros(n_links + 1)
    q0[0], qd0[0] = math.pi - 0.3, 0.5
    return params, torques, q0, qd0


def hub_error_reference(n_links: int, duration_s: float, seed: int = 0) -> HubErrorReference:
    """The inputs of :func:`hub_error_inputs` and the Exudyn plant's hub angle with :data:`REFERENCE_SUBSTEPS`
    sub-steps along them."""
    params, torques, q0, qd0 = hub_error_inputs(n_links, duration_s, seed)
    return HubErrorReference(params, torques, q0, qd0, _exudyn_hub_rad(params, q0, qd0, torques, REFERENCE_SUBSTEPS))


def hub_errors_rad(
    n_links: int, duration_s: float, seed: int = 0, reference: Optional[HubErrorReference] = None
) -> dict[str, float]:
    """Largest hub-angle error over ``duration_s`` of random torque (from the hanging rod, hub turned 0.3 rad
    and spinning at 0.5 rad/s) against the Exudyn plant with :data:`REFERENCE_SUBSTEPS` sub-steps: of the batched chain (default
    sub-steps, RK4 in float64; the Rosenbrock integrator in float32, the fast configuration of
    ``softpend bench --only plant``) and of the default Exudyn plant (2 sub-steps).  ``reference``: what
    :func:`hub_error_reference` returns for the same arguments (computed when not given)."""
    from softpend.plant.batched import BatchedPRBChain

    if reference is None:
        reference = hub_error_reference(n_links, duration_s, seed)
    elif reference.params.n_links != n_links:
        raise ValueError(f"reference is of a rod of {reference.params.n_links} links, n_links is {n_links}")
    params, torques, q0, qd0 = reference.params, reference.torques_nm, reference.q0, reference.qd0
    reference_hub = reference.hub_rad
    figures = {}
    with one_torch_thread() as torch:
        for prefix, integrator, dtype in (
            ("batched_chain", "rk4", torch.float64),
            ("batched_rosenbrock", "rosenbrock", torch.float32),
        ):
            chain = BatchedPRBChain(params, batch_size=1, integrator=integrator, dtype=dtype)
            with torch.no_grad():
                qs, _ = chain.rollout(
                    torch.tensor(q0, dtype=dtype)[None],
                    torch.tensor(qd0, dtype=dtype)[None],
                    torch.tensor(torques, dtype=dtype)[:, None],
                )
            batched = qs[:, 0, 0].double().numpy()
            figures[f"{prefix}_hub_error_rad_n{n_links}"] = float(np.abs(batched - reference_hub).max())
            figures[f"{prefix}_substeps_n{n_links}"] = float(chain.substeps)
    figures[f"exudyn_default_hub_error_rad_n{n_links}"] = float(
        np.abs(_exudyn_hub_rad(params, q0, qd0, torques, 2) - reference_hub).max()
    )
    return figures
