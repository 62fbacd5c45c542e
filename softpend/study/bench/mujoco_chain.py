"""The PRB chain of :class:`softpend.plant.PRBPlant` as a MuJoCo model (``qpos``/``qvel``: the Exudyn plant's joint
state) for the ``plant`` benchmark; MuJoCo is optional (``pip install softpend[bench]``)."""

from __future__ import annotations

import contextlib
import math
from typing import Mapping

import numpy as np

from softpend.checks import one_of, positive
from softpend.plant.params import RodParams
from softpend.plant.prb import link_inertials
from softpend.study.bench import best_times
from softpend.study.simulators import HubErrorReference, hub_error_inputs

#: Control step of the comparisons [s].
CONTROL_STEP_S = 0.01

#: MuJoCo integrators accepted by :func:`chain_mjcf`.
INTEGRATORS = ("RK4", "implicitfast", "implicit", "Euler")


def chain_mjcf(p: RodParams, timestep_s: float = 0.005, integrator: str = "RK4") -> str:
    """MJCF text of the PRB chain of ``params``: hub and ``n`` links with the Exudyn plant's inertias, joint springs
    and dampers, gravity along ``-y``, a torque-limited hub motor, no contacts."""
    positive("timestep_s", timestep_s)
    one_of("integrator", integrator, INTEGRATORS)
    masses, coms, inertias = link_inertials(p)
    stiffness, damping = p.spring_stiffnesses_nm_per_rad(), p.spring_dampings_nms_per_rad()
    r, limit, hub = repr, p.torque_limit_nm, repr(p.hub_inertia_kgm2)  # repr: the same doubles as RodParams
    body = f"""<body name="hub" pos="0 0 0">
<joint name="hub" type="hinge" axis="0 0 1" damping="{r(p.hub_friction_nms_per_rad)}"/>
<inertial pos="0 0 0" mass="{r(p.mass_kg)}" diaginertia="{hub} {hub} {hub}"/>\n"""
    for i in range(p.n_links):
        inertia = r(float(inertias[i]))
        body += f"""<body name="link{i + 1}" pos="0 {r(0.0 if i == 0 else p.link_length_m)} 0">
<joint name="spring{i + 1}" type="hinge" axis="0 0 1" stiffness="{r(stiffness[i])}" springref="0" \
damping="{r(damping[i])}"/>
<inertial pos="0 {r(float(coms[i]))} 0" mass="{r(float(masses[i]))}" diaginertia="{inertia} {inertia} {inertia}"/>\n"""
    body += "</body>\n" * (p.n_links + 1)
    return f"""<mujoco model="softpend_prb_chain">
<compiler angle="radian" autolimits="true"/>
<option timestep="{r(float(timestep_s))}" integrator="{integrator}" gravity="0 {r(-p.gravity_mps2)} 0">
<flag contact="disable"/>
</option>
<worldbody>
{body}</worldbody>
<actuator>
<motor name="hub_torque" joint="hub" gear="1" ctrlrange="{r(-limit)} {r(limit)}" forcerange="{r(-limit)} {r(limit)}"/>
</actuator>
</mujoco>
"""


class MuJoCoChain:
    """One rod of :func:`chain_mjcf` stepped by control steps of :data:`CONTROL_STEP_S` with the torque held."""

    def __init__(self, params: RodParams, timestep_s: float = 0.005, integrator: str = "RK4") -> None:
        import mujoco

        self.params = params
        ratio = CONTROL_STEP_S / positive("timestep_s", timestep_s)
        self.substeps = int(round(ratio))
        if self.substeps < 1 or abs(ratio - self.substeps) > 1e-9 * ratio:
            raise ValueError(f"timestep_s ({timestep_s!r}) must divide the control step ({CONTROL_STEP_S!r} s)")
        self._mujoco = mujoco
        self.model = mujoco.MjModel.from_xml_string(chain_mjcf(self.params, timestep_s, integrator))
        self.data = mujoco.MjData(self.model)
        kinds = mujoco.mjtWarning
        self._instability_warnings = [int(kinds.mjWARN_BADQPOS), int(kinds.mjWARN_BADQVEL), int(kinds.mjWARN_BADQACC)]

    def set_state(self, q: np.ndarray, q_dot: np.ndarray) -> None:
        """Set the joint state ``(q, q_dot)``; time and control back to zero."""
        self._mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[:], self.data.qvel[:] = q, q_dot

    def hang(self) -> None:
        """Set the state to hanging at rest."""
        self.set_state(np.r_[math.pi, np.zeros(self.params.n_links)], np.zeros(self.params.n_links + 1))

    def step(self, torque_nm: float) -> None:
        """Hold ``torque_nm`` (clamped by the actuator) for one control step."""
        self.data.ctrl[0] = torque_nm
        self._mujoco.mj_step(self.model, self.data, self.substeps)

    @property
    def diverged(self) -> bool:
        """Whether MuJoCo met a bad position, velocity or acceleration since the last :meth:`set_state`."""
        return any(self.data.warning[w].number > 0 for w in self._instability_warnings)

    def hub_trajectory_rad(self, q0: np.ndarray, qd0: np.ndarray, torques_nm: np.ndarray) -> np.ndarray:
        """Hub angle after each control step of ``torques_nm`` from ``(q0, qd0)`` [rad] (``nan`` once diverged),
        MuJoCo's warnings silenced."""
        self.set_state(q0, qd0)
        hub = np.full(len(torques_nm), np.nan)
        before = self._mujoco.get_mju_user_warning()
        self._mujoco.set_mju_user_warning(lambda message: None)
        with contextlib.ExitStack() as restore:
            restore.callback(self._mujoco.set_mju_user_warning, before)
            for i, torque in enumerate(torques_nm):
                self.step(float(torque))
                if self.diverged:
                    break
                hub[i] = self.data.qpos[0]
        return hub


def _chain(params: RodParams | int, integrator: str, substeps: int) -> MuJoCoChain:
    params = RodParams(n_links=params) if isinstance(params, int) else params
    return MuJoCoChain(params, timestep_s=CONTROL_STEP_S / substeps, integrator=integrator)


def diverges(n_links: int, integrator: str, substeps: int, duration_s: float = 1.0, seed: int = 0) -> bool:
    """Whether the MuJoCo chain diverges along the inputs of :func:`~softpend.study.simulators.hub_error_inputs`."""
    params, torques, q0, qd0 = hub_error_inputs(n_links, duration_s, seed)
    chain = _chain(params, integrator, substeps)
    chain.hub_trajectory_rad(q0, qd0, torques)
    return chain.diverged


def steps_per_s(n_links: int, integrator: str, substeps: int, n_steps: int = 4000, repeats: int = 2) -> float:
    """Control steps per second of one MuJoCo rod from hanging under seeded random torques (best of ``repeats``)."""
    chain = _chain(n_links, integrator, substeps)
    torques = (np.random.default_rng(0).uniform(-1, 1, n_steps) * chain.params.torque_limit_nm).tolist()
    step = chain.step

    def run() -> None:
        chain.hang()
        for torque in torques:
            step(torque)

    best, _ = best_times(run, repeats)
    if chain.diverged:
        raise RuntimeError(f"the MuJoCo chain diverged ({integrator}, {substeps} sub-steps, n = {n_links})")
    return n_steps / best


def rollout_rod_steps_per_s(
    n_links: int, integrator: str, substeps: int, batch_size: int = 4096, n_steps: int = 6, repeats: int = 3
) -> float:
    """Rod-steps per second of ``mujoco.rollout`` over ``batch_size`` hanging rods, one thread, seeded random torques
    (best of ``repeats`` after a warm-up)."""
    import mujoco
    from mujoco import rollout

    chain = _chain(n_links, integrator, substeps)
    chain.hang()
    spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
    initial = np.empty(mujoco.mj_stateSize(chain.model, spec))
    mujoco.mj_getState(chain.model, chain.data, initial, spec)
    initial = np.tile(initial, (batch_size, 1))
    torques = np.random.default_rng(0).uniform(-1, 1, (batch_size, n_steps)) * chain.params.torque_limit_nm
    control = np.repeat(torques, substeps, axis=1)[:, :, None]
    state = np.empty((batch_size, n_steps * substeps, initial.shape[1]))
    sensordata = np.empty((batch_size, n_steps * substeps, 0))
    run = lambda: rollout.rollout(chain.model, chain.data, initial, control, state=state, sensordata=sensordata)  # noqa: E731
    run()  # warm-up
    best, _ = best_times(run, repeats)
    if not np.isfinite(state[:, -1]).all():
        raise RuntimeError(f"mujoco.rollout diverged ({integrator}, {substeps} sub-steps, n = {n_links})")
    return batch_size * n_steps / best


#: ``(key stem, integrator, MuJoCo steps per control step)`` timed and compared at ``n = 4``.
CONFIGURATIONS_N4 = (("mujoco_rk4_5ms", "RK4", 2), ("mujoco_implicitfast_2p5ms", "implicitfast", 4))

#: The same at ``n = 10`` (``None``: the batched chain's :func:`~softpend.plant.batched.stable_substeps`).
CONFIGURATIONS_N10 = (("mujoco_rk4_stable", "RK4", None), ("mujoco_implicitfast_0p5ms", "implicitfast", 20))

#: A converged RK4 run: the check that both models are the same chain.
CONVERGED = ("mujoco_rk4_0p25ms", "RK4", 40)

_RK4_N4, _RK4_N10 = "mujoco_rk4_5ms_steps_per_s_n4", "mujoco_rk4_stable_steps_per_s_n10"
_ROLLOUT_N4 = "mujoco_rollout_rk4_5ms_rod_steps_per_s_n4"
#: ``key -> (rate of the plant benchmark, MuJoCo rate)`` of the ratios :func:`bench_figures` adds.
RATIOS = {
    "exudyn_env_over_mujoco_rk4_n4": ("env_steps_per_s_n4", _RK4_N4),
    "exudyn_solver_over_mujoco_rk4_n4": ("solver_steps_per_s_n4", _RK4_N4),
    "batched_over_mujoco_rk4_n4": ("batched_rod_steps_per_s_n4", _RK4_N4),
    "batched_over_mujoco_rk4_n10": ("batched_rod_steps_per_s_n10", _RK4_N10),
    "batched_rk4_over_mujoco_rk4_n4": ("batched_rk4_rod_steps_per_s_n4", _RK4_N4),
    "batched_rk4_over_mujoco_rk4_n10": ("batched_rk4_rod_steps_per_s_n10", _RK4_N10),
    "batched_over_mujoco_rollout_n4": ("batched_rod_steps_per_s_n4", _ROLLOUT_N4),
    "batched_rk4_over_mujoco_rollout_n4": ("batched_rk4_rod_steps_per_s_n4", _ROLLOUT_N4),
}


def bench_figures(base: dict[str, float], references: Mapping[int, HubErrorReference]) -> dict[str, float]:
    """The ``mujoco_*`` figures of the ``plant`` benchmark and their ratios to the rates in ``base``;
    ``references``: ``n_links`` (4, 10) -> :func:`~softpend.study.simulators.hub_error_reference`."""
    from softpend.plant.batched import stable_substeps

    figures: dict[str, float] = {}
    n10 = tuple((stem, kind, k or stable_substeps(RodParams(n_links=10))) for stem, kind, k in CONFIGURATIONS_N10)
    for n_links, configurations in ((4, CONFIGURATIONS_N4), (10, n10)):
        for stem, integrator, substeps in configurations:
            n_steps = 4000 if n_links == 4 else 1000
            figures[f"{stem}_steps_per_s_n{n_links}"] = steps_per_s(n_links, integrator, substeps, n_steps=n_steps)
            figures[f"{stem}_substeps_n{n_links}"] = float(substeps)
        ref = references[n_links]  # the hub-angle error against the Exudyn run (inf if diverged)
        for stem, integrator, substeps in configurations + (CONVERGED,):
            chain = _chain(ref.params, integrator, substeps)
            hub = chain.hub_trajectory_rad(ref.q0, ref.qd0, ref.torques_nm)
            error = math.inf if chain.diverged else float(np.abs(hub - ref.hub_rad).max())
            figures[f"{stem}_hub_error_rad_n{n_links}"] = error
    for stem, integrator, substeps in CONFIGURATIONS_N4:
        figures[f"{stem}_diverges_n10"] = float(diverges(10, integrator, substeps))
    figures[_ROLLOUT_N4] = rollout_rod_steps_per_s(4, "RK4", 2)
    return figures | {key: base[ours] / figures[theirs] for key, (ours, theirs) in RATIOS.items()}
