"""Controllers designed on the PRB plant, evaluated on the beam through the shared evaluation."""

import pytest

from softpend.plant import RodParams
from softpend.study.transfer import TransferCase, perturbations, transfer_table


def test_perturbations_change_one_thing_each():
    nominal = RodParams()
    variants = perturbations(nominal, 0.2)
    assert len(variants) == 7
    assert variants["stiffness +20%"].stiffness_scale == pytest.approx(1.2)
    assert variants["mass -20%"].mass_kg == pytest.approx(0.8 * nominal.mass_kg)
    assert variants["damping +20%"].hub_friction_nms_per_rad == pytest.approx(1.2 * nominal.hub_friction_nms_per_rad)
    with pytest.raises(ValueError, match="fraction"):
        perturbations(nominal, 1.5)


def test_lqr_from_prb_balances_the_beam_small_budget():
    from softpend.control.lqr import LQRController

    params = RodParams()
    case = TransferCase(
        "LQR",
        lambda: LQRController.from_params(params, state="observation"),
        start="upright",
        duration_s=2.5,
        start_noise_rad=0.15,
    )
    rows = transfer_table([case], params, plants=("beam",), seeds=(0,), fraction=0.2, progress=False)
    assert len(rows) == 7
    assert {r["plant"] for r in rows} == {"beam"}
    nominal = next(r for r in rows if r["perturbation"] == "nominal")
    assert nominal["success_rate"] == 1.0
    assert nominal["upright_std_rad"] < 0.05
    assert all(r["diverged"] == 0 for r in rows)

    # an open-loop "controller" that does nothing does not balance it: the metric can fail
    idle = TransferCase("idle", lambda: _Idle(), start="upright", duration_s=2.5, start_noise_rad=0.15)
    idle_rows = transfer_table([idle], params, plants=("beam",), seeds=(0,), fraction=0.0, progress=False)
    assert idle_rows[0]["success_rate"] == 0.0


class _Idle:
    def reset(self):
        pass

    def __call__(self, observation, q, q_dot, time_s):
        return 0.0


def test_rl_agents_run_in_the_transfer_study(tmp_path):
    """A (tiny) DQN run becomes a transfer case, evaluated on the beam; a mismatched rod is refused."""
    from softpend.rl.config import DQNConfig
    from softpend.rl.dqn import train_dqn
    from softpend.study.rl_runs import run_folder
    from softpend.study.transfer import rl_transfer_cases, transfer_matrix

    config = DQNConfig(learning_starts=20, episode_s=1.0, eval_every_episodes=100, checkpoint_every_episodes=100)
    train_dqn(config, seed=0, episodes=2, run_dir=run_folder(tmp_path, "dqn", 0), progress=False)
    params = RodParams()
    cases = rl_transfer_cases(tmp_path, algos=("dqn",), seeds=(0,), which="final", params=params, duration_s=2.0)
    assert [c.name for c in cases] == ["model-free DQN (seed 0)"]
    rows = transfer_table(cases, params, plants=("beam",), seeds=(0,), fraction=0.2, progress=False)
    assert len(rows) == 7 and all(r["diverged"] == 0 for r in rows)
    controllers, labels, values = transfer_matrix(rows, "beam", "success_rate")
    assert controllers == ["model-free DQN (seed 0)"] and len(labels) == 7 and values.shape == (1, 7)
    assert ((values >= 0) & (values <= 1)).all()

    with pytest.raises(ValueError, match="n_links"):
        rl_transfer_cases(tmp_path, algos=("dqn",), seeds=(0,), which="final", params=params.replace(n_links=6))
    with pytest.raises(ValueError, match="algos"):
        rl_transfer_cases(tmp_path, algos=("ppo",), seeds=(0,))
    with pytest.raises(FileNotFoundError):
        rl_transfer_cases(tmp_path, algos=("dqn",), seeds=(1,))
    with pytest.raises(ValueError, match="plant"):
        transfer_matrix(rows, "real")
