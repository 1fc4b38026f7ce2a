"""rmpfusion's experiments as Gymnasium environments: the API contract (gymnasium's own checker), what a step
computes (the same trajectory and task cost as one rollout of the environment; a residual adds exactly its scaled
q̈), how episodes end, the vector version, bad settings, and one Stable-Baselines3 training iteration."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch
from gymnasium.utils.env_checker import check_env

import rmpfusion.gym as rgym
from rmpfusion.gym import RMPfusionEnv, RMPfusionVectorEnv, TaskError, build_task
from rmpfusion.learn.task_cost import rollout_costs, total


@pytest.fixture(scope="module")
def task():
    return build_task("2d1level", decision_interval=0.5)


def test_every_simulated_experiment_has_a_versioned_id_and_recorded_data_has_none():
    for name, env_id in (
        ("2d1level", "rmpfusion/2d1level-v0"),
        ("franka", "rmpfusion/Franka-v0"),
        ("franka_three_obstacles", "rmpfusion/FrankaThreeObstacles-v0"),
        ("reach", "rmpfusion/Reach-v0"),
    ):
        assert rgym.gym_id(name) == env_id and env_id in gym.registry and env_id in rgym.IDS
    assert "rmpfusion/Lasa-v0" not in gym.registry  # recorded demonstrations: no task to simulate
    assert set(rgym.IDS) == {rgym.gym_id(e) for e in rgym.simulated_experiments()}


def test_gymnasiums_checker_passes_on_the_particle(task):
    check_env(RMPfusionEnv(task), skip_render_check=True)


def test_a_step_is_the_environments_rollout_for_one_interval_and_the_reward_its_task_cost(task):
    """Zero actions on the unit-weight tree, decision by decision, retrace one long rollout of that tree from the
    same start, and the rewards sum to minus its task cost."""
    env = RMPfusionEnv(task)
    obs, _ = env.reset(seed=3)
    q0, qd0, aux = (x.clone() if isinstance(x, torch.Tensor) else dict(x) for x in env._state)
    n = 6
    rewards, states = [], []
    for _ in range(n):
        obs, r, terminated, truncated, _ = env.step(np.zeros(2, dtype=np.float32))
        rewards.append(r)
        states.append(torch.as_tensor(obs[:2], dtype=torch.float64))
        assert not (terminated or truncated)
    h = task.decision_interval
    ro = task.env.rollout(task.base, q0, qd0, aux, horizon=n * h, record_every=h)
    torch.testing.assert_close(torch.stack(states), ro.q[1:, 0], rtol=0, atol=1e-5)  # observations are float32
    cost = total(rollout_costs(task.cost, ro, final=False)).sum()
    assert sum(rewards) == pytest.approx(-float(cost), rel=1e-9)


def test_without_a_base_tree_the_action_is_the_scaled_acceleration():
    t = build_task("2d1level", base="none", decision_interval=0.5, action_scale=2.0)
    env = RMPfusionEnv(t)
    env.reset(seed=0)
    q0, qd0, _ = env._state
    a = np.array([0.5, -1.0], dtype=np.float32)
    obs, *_ = env.step(a)
    h, qdd = 0.5, 2.0 * torch.tensor([0.5, -1.0], dtype=torch.float64)
    torch.testing.assert_close(
        torch.as_tensor(obs[:2], dtype=torch.float64), q0[0] + qd0[0] * h + 0.5 * qdd * h**2, rtol=0, atol=1e-6
    )
    torch.testing.assert_close(torch.as_tensor(obs[2:4], dtype=torch.float64), qd0[0] + qdd * h, rtol=0, atol=1e-6)


def test_an_episode_ends_at_the_goal_and_a_collision_costs_the_rest_of_the_horizon():
    t = build_task("2d1level", decision_interval=0.5)
    env = RMPfusionEnv(t)
    env.reset(seed=0)
    for _ in range(t.decisions):
        _, _, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
        if terminated or truncated:
            break
    assert terminated and info["reached"] and info["is_success"] and info["goal_distance"] <= 0.1

    crash = build_task("2d1level", base="none", decision_interval=0.5, action_scale=5.0)
    env = RMPfusionEnv(crash)
    env.reset(seed=0)
    q, _, aux = env._state
    toward = (aux["obstacle1_center"][0] - q[0]) / (aux["obstacle1_center"][0] - q[0]).norm()
    for _ in range(crash.decisions):
        _, r, terminated, truncated, info = env.step(toward.numpy().astype(np.float32))
        if terminated or truncated:
            break
    assert terminated and info["collided"] and not info["is_success"]
    remaining = crash.horizon - info["time"]
    assert -r >= info["goal_distance"] * remaining  # the collision's cost: the distance held until the time-out


def test_the_same_seed_gives_the_same_episode(task):
    def episode(seed):
        env = RMPfusionEnv(task)
        obs, _ = env.reset(seed=seed)
        out = [obs]
        for k in range(3):
            out.append(env.step(np.full(2, 0.3 * (k - 1), dtype=np.float32))[0])
        return np.stack(out)

    np.testing.assert_array_equal(episode(7), episode(7))
    assert not np.array_equal(episode(7), episode(8))


def test_the_vector_version_steps_every_episode_in_one_rollout_and_resets_on_the_next_step(task):
    venv = RMPfusionVectorEnv(task, num_envs=3)
    obs, _ = venv.reset(seed=1)
    assert obs.shape == (3, task.observation_dim) and venv.single_action_space.shape == (2,)
    single = RMPfusionEnv(task)  # the same starts, drawn in one batch from the same seed
    starts = single.stepper.starts(3, torch.Generator().manual_seed(1))
    np.testing.assert_allclose(obs, task.observe(*starts).numpy(), atol=1e-6)
    ended_at = None
    for k in range(task.decisions + 1):
        obs, rewards, terminated, truncated, _ = venv.step(np.zeros((3, 2), dtype=np.float32))
        if ended_at is None and (terminated | truncated).any():
            ended_at, who = k, int(np.flatnonzero(terminated | truncated)[0])
        elif ended_at is not None and k == ended_at + 1:
            assert rewards[who] == 0.0 and not terminated[who] and not truncated[who]  # the restart step
            assert venv._t[who] == 0.0
            break
    assert ended_at is not None


def test_gymnasium_make_and_make_vec_build_them_with_their_settings():
    env = gym.make("rmpfusion/2d2level-v0", decision_interval=0.2, action_scale=1.0)
    assert isinstance(env.unwrapped, RMPfusionEnv) and env.unwrapped.task.decision_interval == 0.2
    venv = gym.make_vec("rmpfusion/2d2level-v0", num_envs=2, vectorization_mode="vector_entry_point")
    assert isinstance(venv, RMPfusionVectorEnv) and venv.num_envs == 2


@pytest.mark.parametrize(
    "kwargs, says",
    [
        ({"experiment": "lasa"}, "recorded demonstrations"),
        ({"experiment": "2d1level", "decision_interval": 0.015}, "whole number of the environment's integration"),
        ({"experiment": "2d1level", "action_scale": 0.0}, "action_scale=0.0 must be positive"),
        ({"experiment": "2d1level", "base": "learner"}, "give unit_weights, expert or none"),
        ({"experiment": "2d1level", "split": "holdout"}, "train, val or test"),
    ],
)
def test_a_task_that_cannot_be_built_says_why(kwargs, says):
    with pytest.raises(TaskError, match=says):
        build_task(**kwargs)


@pytest.mark.slow
def test_gymnasiums_checker_passes_on_the_franka():
    env = RMPfusionEnv(build_task("franka", horizon=1.0))
    try:
        check_env(env, skip_render_check=True)
    finally:
        env.close()


@pytest.mark.slow
def test_one_stable_baselines3_ppo_iteration_on_the_particle(tmp_path, request):
    """What a user of an RL library does: PPO on rmpfusion/2d1level-v0, one rollout-and-update iteration, the
    policy saved and loaded, its action a valid one."""
    sb3 = pytest.importorskip("stable_baselines3")
    torch.set_default_dtype(torch.float32)  # a user's default: the test suite computes in float64 (conftest)
    request.addfinalizer(lambda: torch.set_default_dtype(torch.float64))
    env = gym.make("rmpfusion/2d1level-v0", decision_interval=0.5)
    model = sb3.PPO("MlpPolicy", env, n_steps=64, batch_size=32, n_epochs=1, seed=0, device="cpu", verbose=0)
    before = [p.detach().clone() for p in model.policy.parameters()]
    model.learn(total_timesteps=64)
    assert model.num_timesteps == 64
    assert any(not torch.equal(a, b.detach()) for a, b in zip(before, model.policy.parameters(), strict=True))
    model.save(tmp_path / "ppo")
    action, _ = sb3.PPO.load(tmp_path / "ppo", device="cpu").predict(env.reset(seed=0)[0], deterministic=True)
    assert env.action_space.contains(action.astype(np.float32))


@pytest.mark.slow
def test_a_moving_obstacle_is_observed_where_it_is_now():
    """franka_three_obstacles' sphere moves at 0.1 m/s: after three decisions of 0.1 s the observation shows it
    3 cm further along its path (the environment's aux_at), and nothing else of the scene moved."""
    env = RMPfusionEnv(build_task("franka_three_obstacles"))
    try:
        task = env.task
        obs0, _ = env.reset(seed=0)
        for _ in range(3):
            obs, *_ = env.step(np.zeros(task.env.dim, dtype=np.float32))
        q0, qd0, aux0 = env._state
        expected = task.env.aux_at(aux0, 0.3)
        now = task.observe(q0, qd0, expected)[0].numpy()
        start = 2 * task.env.dim
        np.testing.assert_allclose(obs[start:], now[start:], atol=1e-6)
        moved = np.flatnonzero(~np.isclose(obs0[start:], obs[start:], atol=1e-7))
        dims = task.env.aux_dims()
        offsets = np.cumsum([0] + [dims[n] for n in task.aux_names])
        names = {task.aux_names[int(np.searchsorted(offsets, i, side="right")) - 1] for i in moved}
        assert names == {"obstacle2_center"}
        assert float(np.linalg.norm(obs[start:] - obs0[start:])) == pytest.approx(0.03, abs=1e-6)
    finally:
        env.close()
