"""The batched torch chain beside the Exudyn plant: how closely the two simulators agree.

:func:`hub_errors_rad` runs both from the same state under the same random torque against the Exudyn plant with
:data:`REFERENCE_SUBSTEPS` sub-steps (Figure 1's agreement section and ``softpend bench --only plant``).
"""

from __future__ import annotations

import math

import numpy as np

from softpend.plant.params import RodParams
from softpend.plant.prb import PRBPlant

__all__ = ["REFERENCE_SUBSTEPS", "hub_errors_rad", "one_torch_thread"]

#: Sub-steps of the Exudyn reference run (converged to well below the errors compared).
REFERENCE_SUBSTEPS = 200


def one_torch_thread():
    """Context: torch on one thread (restored afterwards)."""
    import contextlib

    import torch

    @contextlib.contextmanager
    def scope():
        before = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            yield torch
        finally:
            torch.set_num_threads(before)

    return scope()



def hub_errors_rad(n_links: int, duration_s: float, seed: int = 0) -> dict[str, float]:
    """Largest hub-angle error over ``duration_s`` of random torque (from the hanging rod, hub turned 0.3 rad
    and spinning at 0.5 rad/s) against the Exudyn plant with :data:`REFERENCE_SUBSTEPS` sub-steps: of the batched chain (default
    sub-steps, RK4 in float64; the Rosenbrock integrator in float32, the fast configuration of
    ``softpend bench --only plant``) and of the default Exudyn plant (2 sub-steps)."""
    from softpend.plant.batched import BatchedPRBChain

    params = RodParams(n_links=n_links)
    n_steps = int(round(duration_s / 0.01))
    torques = np.random.default_rng(seed).uniform(-1, 1, n_steps) * params.torque_limit_nm
    q0 = np.zeros(n_links + 1)
    qd0 = np.zeros(n_links + 1)
    q0[0], qd0[0] = math.pi - 0.3, 0.5

    def exudyn_hub(substeps: int) -> np.ndarray:
        plant = PRBPlant(params, substeps=substeps)
        plant.reset(q0, qd0)
        return np.array([(plant.step(t), plant.joint_state()[0][0])[1] for t in torques])

    reference = exudyn_hub(REFERENCE_SUBSTEPS)
    figures = {}
    with one_torch_thread() as torch:
        for prefix, integrator, dtype in (("batched_chain", "rk4", torch.float64),
                                          ("batched_rosenbrock", "rosenbrock", torch.float32)):
            chain = BatchedPRBChain(params, batch_size=1, integrator=integrator, dtype=dtype)
            with torch.no_grad():
                qs, _ = chain.rollout(torch.tensor(q0, dtype=dtype)[None], torch.tensor(qd0, dtype=dtype)[None],
                                      torch.tensor(torques, dtype=dtype)[:, None])
            batched = qs[:, 0, 0].double().numpy()
            figures[f"{prefix}_hub_error_rad_n{n_links}"] = float(np.abs(batched - reference).max())
            figures[f"{prefix}_substeps_n{n_links}"] = float(chain.substeps)
    figures[f"exudyn_default_hub_error_rad_n{n_links}"] = float(np.abs(exudyn_hub(2) - reference).max())
    return figures

