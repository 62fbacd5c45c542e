"""Plant and environment speed and accuracy (``softpend bench --only plant``): Exudyn environment and solver, batched
chain, vector environment, hub-angle errors against a converged run and, where installed, the chain in MuJoCo (the PRB
chain of :class:`softpend.plant.PRBPlant` as a MuJoCo model, ``qpos``/``qvel``: the Exudyn plant's joint state; MuJoCo
is optional: ``pip install softpend[bench]``); the beam plant's speed and accuracy (``--only beam``)."""

from __future__ import annotations

import contextlib
import importlib.util
import math
import sys
import time
import types
from typing import Any, Mapping, NamedTuple, Optional

import gymnasium as gym
import numpy as np

from softpend.checks import one_of, positive
from softpend.fidelity.validation import measured_bending_frequencies, static_tip_sag
from softpend.plant.params import RodParams
from softpend.plant.prb import PRBPlant, link_inertials
from softpend.study.bench import best_times
from softpend.torch_threads import one_torch_thread

N_STEPS = 4000
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


def env_steps_per_s(n_links: int = 4, n_steps: int = N_STEPS, plant: str = "prb", legacy: bool = False) -> float:
    """Steps per second through the Gymnasium API under seeded random actions (``legacy``: :func:`make_legacy`)."""
    import softpend  # noqa: F401

    env = gym.make("softpend/SoftPendulum-v0", params=RodParams(n_links=n_links), plant=plant)
    if legacy:
        make_legacy(env)
    actions = np.random.default_rng(0).uniform(-1, 1, size=(n_steps, 1)).astype(np.float32)
    env.reset(seed=0)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return n_steps / (time.perf_counter() - start)


def _solver_steps_per_s(n_links: int, n_steps: int = N_STEPS) -> float:
    """Steps per second of the bare Exudyn loop: set the joint torque, advance."""
    plant = PRBPlant(RodParams(n_links=n_links))
    plant.reset(*plant.hanging_state())
    torques = np.random.default_rng(0).uniform(-1, 1, size=n_steps) * plant.params.torque_limit_nm
    forces = np.zeros(plant.n_coordinates)
    start = time.perf_counter()
    for torque in torques:
        forces[0] = torque
        plant.set_joint_forces(forces)
        plant.advance()
    return n_steps / (time.perf_counter() - start)


def _legacy_advance(self) -> None:
    import exudyn as exu

    from softpend.plant.base import SolverFailure

    settings, mbs = self._settings, self._mbs
    settings.timeIntegration.startTime = self.time_s
    settings.timeIntegration.endTime = self.time_s + self.dt_s
    self._solver.InitializeSolverInitialConditions(mbs, settings)
    try:
        ok = self._solver.SolveSteps(mbs, settings)
    except exu.ExudynError:
        ok = False
    data = mbs.systemData
    state = data.GetSystemState()
    if not ok or not math.isfinite(float(np.sum(state[0])) + float(np.sum(state[1]))):
        raise SolverFailure(f"Exudyn implicit solver failed at t = {self.time_s:.4f} s")
    self._q, self._q_t = state[0], state[1]
    data.SetSystemState(systemStateList=state, configuration=exu.ConfigurationType.Initial)
    data.SetODE2Coordinates_tt(coordinates=data.GetODE2Coordinates_tt(), configuration=exu.ConfigurationType.Initial)
    self.time_s += self.dt_s


def make_legacy(env) -> None:
    """Give ``env`` (PRB plant) the baseline step path of ``env_steps_per_s_n4_speedup`` (more Python-C++ crossings)."""
    plant = env.unwrapped.plant
    plant.advance = types.MethodType(_legacy_advance, plant)
    plant.observe = lambda: plant.observation_from_state(plant._q.tolist(), plant._q_t.tolist())


#: Rods of the batched chain's timings, environments of the vector environment's.
BATCH_SIZE, NUM_ENVS = 4096, 1024


def batched_rod_steps_per_s(
    n_links: int, n_steps: int = 6, repeats: int = 3, dtype_name: str = "float64", **chain_options: Any
) -> tuple[float, float]:
    """Rod-steps per wall-clock and CPU second of the batched chain on one torch thread (best of ``repeats``)."""
    from softpend.plant.batched import BatchedPRBChain

    with one_torch_thread() as torch:
        dtype = getattr(torch, dtype_name)
        chain = BatchedPRBChain(RodParams(n_links=n_links), batch_size=BATCH_SIZE, dtype=dtype, **chain_options)
        generator = torch.Generator().manual_seed(0)
        torques = ((torch.rand(n_steps, BATCH_SIZE, generator=generator, dtype=torch.float64) * 2 - 1) * 0.06).to(dtype)
        with torch.no_grad():
            q, qd = chain.hanging_state()
            q, qd = chain.step(q, qd, torques[0])  # warm-up (and compilation)

            def run() -> None:
                nonlocal q, qd
                for torque in torques:
                    q, qd = chain.step(q, qd, torque)

            best, best_cpu = best_times(run, repeats)
            if not bool(torch.isfinite(q).all()):
                raise RuntimeError(f"the batched chain diverged in the benchmark ({chain.integrator}, n = {n_links})")
    return BATCH_SIZE * n_steps / best, BATCH_SIZE * n_steps / max(best_cpu, 1e-9)


def vector_env_steps_per_s(n_links: int = 4, n_steps: int = 40, **env_options: Any) -> tuple[float, float]:
    """Steps per wall-clock and CPU second of the vector environment on one torch thread (best of 3)."""
    from softpend.envs.vector import SoftPendulumVectorEnv

    with one_torch_thread():
        env = SoftPendulumVectorEnv(num_envs=NUM_ENVS, params=RodParams(n_links=n_links), **env_options)
        actions = np.random.default_rng(0).uniform(-1, 1, (n_steps, NUM_ENVS, 1)).astype(np.float32)
        env.reset(seed=0)
        env.step(actions[0])
        best, best_cpu = best_times(lambda: [env.step(action) for action in actions], 3)
    return NUM_ENVS * n_steps / best, NUM_ENVS * n_steps / max(best_cpu, 1e-9)


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

        self.params, self._mujoco = params, mujoco
        ratio = CONTROL_STEP_S / positive("timestep_s", timestep_s)
        self.substeps = int(round(ratio))
        if self.substeps < 1 or abs(ratio - self.substeps) > 1e-9 * ratio:
            raise ValueError(f"timestep_s ({timestep_s!r}) must divide the control step ({CONTROL_STEP_S!r} s)")
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


def diverges(n_links: int, integrator: str, substeps: int, duration_s: float = 1.0) -> bool:
    """Whether the MuJoCo chain diverges along the inputs of :func:`hub_error_inputs`."""
    params, torques, q0, qd0 = hub_error_inputs(n_links, duration_s)
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
#: ``key -> (rate of the plant benchmark, MuJoCo rate)`` of the ratios :func:`mujoco_figures` adds.
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


def mujoco_figures(base: dict[str, float], references: Mapping[int, HubErrorReference]) -> dict[str, float]:
    """The ``mujoco_*`` figures of the ``plant`` benchmark and their ratios to the rates in ``base``;
    ``references``: ``n_links`` (4, 10) -> :func:`hub_error_reference`."""
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


def bench_plant() -> dict[str, float]:
    """The ``plant`` benchmark group (see the module docstring)."""
    env4 = max(env_steps_per_s(4) for _ in range(2))
    solver4 = max(_solver_steps_per_s(4) for _ in range(2))
    env10 = env_steps_per_s(10)
    paths = {False: 0.0, True: 0.0}  # today's step path and the legacy one, interleaved
    for _ in range(3):
        for legacy in paths:
            paths[legacy] = max(paths[legacy], env_steps_per_s(4, legacy=legacy))
    fast: dict[str, Any] = {"integrator": "rosenbrock", "compiled": True}
    batched = {n: batched_rod_steps_per_s(n, dtype_name="float32", **fast) for n in (4, 10)}
    batched64 = {n: batched_rod_steps_per_s(n, **fast)[0] for n in (4, 10)}
    rk4 = {4: batched_rod_steps_per_s(4)[0], 10: batched_rod_steps_per_s(10, n_steps=2, repeats=2)[0]}
    vector4, vector4_cpu = vector_env_steps_per_s(4, **fast)
    vector4_default, _ = vector_env_steps_per_s(4)
    figures = {"env_steps_per_s_n4": env4, "env_steps_per_s_n10": env10, "solver_steps_per_s_n4": solver4}
    figures |= {"realtime_factor_n4": env4 * 0.01, "wrapper_overhead_fraction_n4": solver4 / env4 - 1.0}  # step 0.01 s
    figures |= {"env_steps_per_s_n4_legacy_path": paths[True], "env_steps_per_s_n4_speedup": paths[False] / paths[True]}
    figures |= {f"batched_rod_steps_per_s_n{n}": rate for n, (rate, _) in batched.items()}
    figures |= {f"batched_rod_steps_per_cpu_s_n{n}": cpu for n, (_, cpu) in batched.items()}
    figures |= {f"batched_rod_steps_per_s_n{n}_float64": rate for n, rate in batched64.items()}
    figures |= {f"batched_rk4_rod_steps_per_s_n{n}": rate for n, rate in rk4.items()}
    figures |= {"vector_env_steps_per_s_n4": vector4, "vector_env_steps_per_cpu_s_n4": vector4_cpu}
    figures["vector_env_steps_per_s_n4_default"] = vector4_default
    references = {n: hub_error_reference(n, duration_s=d) for n, d in ((4, 5.0), (10, 1.0))}
    for n, d in ((4, 5.0), (10, 1.0)):
        figures.update(hub_errors_rad(n, duration_s=d, reference=references[n]))
    if importlib.util.find_spec("mujoco") is not None:
        return figures | mujoco_figures(figures, references)
    print("[bench] plant: MuJoCo is not installed (pip install softpend[bench]): no mujoco_* figures", file=sys.stderr)
    return figures


def bench_beam() -> dict[str, float]:
    """Beam environment step rate, real-time factor, frequency and static-sag errors against Euler-Bernoulli [%]."""
    steps = max(env_steps_per_s(n_steps=2000, plant="beam") for _ in range(2))
    freqs = measured_bending_frequencies("beam")
    sag = static_tip_sag("beam", RodParams(stiffness_scale=100.0))
    figures = {"beam_env_steps_per_s": steps, "beam_realtime_factor": steps * 0.01}
    figures |= {f"beam_{nth}_freq_error_pct": abs(freqs[f"f{i}_error_pct"]) for i, nth in ((1, "first"), (2, "second"))}
    return figures | {"beam_static_sag_error_pct": abs(sag["error_pct"])}
