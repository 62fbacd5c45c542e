"""How closely the batched torch chain and the default Exudyn plant agree with a converged Exudyn run."""

from __future__ import annotations

import math
from typing import NamedTuple, Optional

import numpy as np

from softpend.plant.params import RodParams
from softpend.plant.prb import PRBPlant
from softpend.torch_threads import one_torch_thread

#: Sub-steps of the Exudyn reference run.
REFERENCE_SUBSTEPS = 200


class HubErrorReference(NamedTuple):
    """The converged Exudyn run that :func:`hub_errors_rad` compares simulators against."""

    params: RodParams
    torques_nm: np.ndarray
    q0: np.ndarray
    qd0: np.ndarray
    hub_rad: np.ndarray  # after each control step


def _exudyn_hub_rad(
    params: RodParams, q0: np.ndarray, qd0: np.ndarray, torques: np.ndarray, substeps: int
) -> np.ndarray:
    plant = PRBPlant(params, substeps=substeps)
    plant.reset(q0, qd0)
    return np.array([(plant.step(t), plant.joint_state()[0][0])[1] for t in torques])


def hub_error_inputs(n_links: int, duration_s: float) -> tuple[RodParams, np.ndarray, np.ndarray, np.ndarray]:
    """``(params, torques_nm, q0, qd0)``: random torque (seed 0) from the hanging rod, hub turned and spinning."""
    params = RodParams(n_links=n_links)
    torques = np.random.default_rng(0).uniform(-1, 1, int(round(duration_s / 0.01))) * params.torque_limit_nm
    q0, qd0 = np.zeros(n_links + 1), np.zeros(n_links + 1)
    q0[0], qd0[0] = math.pi - 0.3, 0.5
    return params, torques, q0, qd0


def hub_error_reference(n_links: int, duration_s: float) -> HubErrorReference:
    """The inputs of :func:`hub_error_inputs` and the converged Exudyn plant's hub angle along them."""
    params, torques, q0, qd0 = hub_error_inputs(n_links, duration_s)
    return HubErrorReference(params, torques, q0, qd0, _exudyn_hub_rad(params, q0, qd0, torques, REFERENCE_SUBSTEPS))


def hub_errors_rad(n_links: int, duration_s: float, reference: Optional[HubErrorReference] = None) -> dict[str, float]:
    """Largest hub-angle error against the converged Exudyn run of the batched chain (RK4 float64, Rosenbrock
    float32) and of the default Exudyn plant."""
    from softpend.plant.batched import BatchedPRBChain

    reference = reference if reference is not None else hub_error_reference(n_links, duration_s)
    params, torques, q0, qd0, reference_hub = reference
    error = lambda hub: float(np.abs(hub - reference_hub).max())  # noqa: E731
    figures = {f"exudyn_default_hub_error_rad_n{n_links}": error(_exudyn_hub_rad(params, q0, qd0, torques, 2))}
    with one_torch_thread() as torch:
        for prefix, integrator, dtype in (
            ("batched_chain", "rk4", torch.float64),
            ("batched_rosenbrock", "rosenbrock", torch.float32),
        ):
            chain = BatchedPRBChain(params, batch_size=1, integrator=integrator, dtype=dtype)
            start, speed, torque = (torch.tensor(a, dtype=dtype) for a in (q0, qd0, torques))
            with torch.no_grad():
                qs, _ = chain.rollout(start[None], speed[None], torque[:, None])
            figures[f"{prefix}_hub_error_rad_n{n_links}"] = error(qs[:, 0, 0].double().numpy())
            figures[f"{prefix}_substeps_n{n_links}"] = float(chain.substeps)
    return figures
