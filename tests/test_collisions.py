"""The batched collision check of kinematic rollouts (envs/manipulator/collisions.py): the spheres bound the
simulator's clearance on every shipped robot, and the check finds what the per-configuration replay finds."""

from __future__ import annotations

import pytest
import torch
import yaml

pytest.importorskip("pybullet")

from manipulators import CONF, franka_env, franka_tree_spec, robot, scene

import rmpfusion
from rmpfusion.envs.manipulator import Manipulator
from rmpfusion.envs.manipulator.collisions import (
    CLEARANCE_TOLERANCE,
    SPHERE_SLACK,
    check_collisions,
    cover_spheres,
    replay_collisions,
    sphere_clearance,
)
from rmpfusion.envs.manipulator.worlds import sample_aux
from rmpfusion.envs.manipulator_tree import with_weights

F64 = torch.float64
ROBOTS = sorted(p.stem for p in (CONF / "robot").glob("*.yaml"))
#: one obstacle of each shape, placed per configuration next to the robot
SHAPES = {
    "sphere": {"type": "sphere", "center": [0.5, 0.0, 0.5], "radius": 0.05},
    "box": {"type": "box", "center": [0.5, 0.0, 0.5], "half_extents": [0.03, 0.05, 0.08]},
    "cylinder": {"type": "cylinder", "center": [0.5, 0.0, 0.5], "radius": 0.04, "height": 0.2},
    "capsule": {"type": "capsule", "center": [0.5, 0.0, 0.5], "radius": 0.04, "length": 0.2},
}


def _near_the_robot(env: Manipulator, n: int, seed: int) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    """``n`` configurations within the joint limits, each with the scene's obstacle a few centimetres from one of
    its cover spheres (in contact, or clear by up to 12 cm)."""
    g = torch.Generator().manual_seed(seed)
    lo, hi = env.lower.clamp(min=-torch.pi), env.upper.clamp(max=torch.pi)
    q = lo + (hi - lo) * torch.rand(n, env.dim, generator=g, dtype=F64)
    cover = cover_spheres(env.robot)
    pick = torch.randint(0, len(cover.links), (n,), generator=g)
    poses = env.robot.chain.forward_kinematics(q, sorted(set(cover.links)))
    R = torch.stack([poses[cover.links[j]][0][b] for b, j in enumerate(pick.tolist())])
    p = torch.stack([poses[cover.links[j]][1][b] for b, j in enumerate(pick.tolist())])
    centre = p + (R @ cover.offsets[pick].unsqueeze(-1)).squeeze(-1)
    away = torch.randn(n, 3, generator=g, dtype=F64)
    away = away / away.norm(dim=-1, keepdim=True)
    gap = cover.radii[pick] + 0.12 * torch.rand(n, generator=g, dtype=F64)
    aux = env.sample_envs(n, g)
    aux["obstacle1_center"] = centre + away * gap[:, None]
    return q, aux


@pytest.mark.parametrize("name", ROBOTS)
def test_spheres_bound_the_simulators_clearance_on_every_robot(name):
    """Sphere clearance − SPHERE_SLACK ≤ the simulator's (mesh) clearance wherever that is ≥ 0, each shape and the
    ground: the relation the batched check rests on. A configuration in collision is never clear by the spheres."""
    for shape, obstacle in [*SHAPES.items(), ("ground", SHAPES["sphere"])]:
        ground = 0.0 if shape == "ground" else -0.2
        env = Manipulator(
            robot=robot(name), scene={"obstacles": [obstacle], "ground": {"height": ground}}, clearance_query=1.0
        )
        q, aux = _near_the_robot(env, 40, seed=len(shape))
        if shape == "ground":  # the obstacle out of reach: the ground alone
            aux["obstacle1_center"] = aux["obstacle1_center"] + 5.0
        spheres = sphere_clearance(env, q, aux)
        world, mesh = env.checker(), []
        for b in range(q.shape[0]):
            world.set_env(env.scene, sample_aux(aux, b))
            world.reset(q[b].numpy())
            mesh.append(world.clearance(1.0))
        mesh_t = torch.tensor(mesh, dtype=F64)
        clear = mesh_t >= 0
        assert clear.any() and (~clear).any(), (name, shape)
        worst = float((spheres - mesh_t)[clear].max())
        assert worst <= SPHERE_SLACK, f"{name} {shape}: a sphere is {worst * 1000:.1f} mm farther than the mesh"
        assert (spheres[~clear] - SPHERE_SLACK <= 0).all(), (name, shape)
        env.close()


@pytest.fixture(scope="module")
def env():
    e = franka_env()
    yield e
    e.close()


def _agree(env: Manipulator, policy, q0, qd0, aux, horizon: float):
    """A kinematic rollout recorded at every step, its collisions as the rollout found them (the batched check) and
    as the per-configuration replay finds them from the same configurations."""
    with torch.no_grad():
        ro = env.rollout(policy, q0, qd0, aux, horizon=horizon, record_every=env.dt, mode="kinematic")
    n_steps, B = ro.q.shape[0] - 1, ro.q.shape[1]
    asked: list[int] = []
    world = env.checker()
    count = world.clearance

    def counted(query):
        asked.append(1)
        return count(query)

    world.clearance = counted  # type: ignore[method-assign]
    try:
        batched = check_collisions(env, ro.q, aux, n_steps, [n_steps] * B, [None] * B)
        n_batched = len(asked)
        reference = replay_collisions(env, ro.q, aux, n_steps, [n_steps] * B, [None] * B)
    finally:
        del world.clearance
    for got in (batched, (ro.min_clearance, ro.first_collision_time)):
        assert torch.equal(got[1], reference[1])  # the same first collision times (inf: none)
        assert ((got[0] <= 0) == (reference[0] <= 0)).all()  # the same collision flags
        assert (got[0] >= reference[0]).all() and (got[0] <= reference[0] + CLEARANCE_TOLERANCE).all()
    return ro, reference, n_batched, len(asked) - n_batched


def test_batched_check_equals_the_replay_on_expert_rollouts(env):
    """The Franka expert's rollouts from sampled starts pass the cylinder closely: the same smallest clearances,
    with a fraction of the simulator's queries (a third here, where the arms move for most of the 2 s; a rollout
    that comes to rest is cleared from a few queries, tools/bench.py --only collisions)."""
    weights = yaml.safe_load((CONF / "expert" / "franka.yaml").read_text())
    expert = rmpfusion.build_tree(with_weights(franka_tree_spec(1), weights), aux_dims=env.aux_dims())
    q0, qd0, aux = env.sample(3, 1, seed=3)
    ro, _, asked, replayed = _agree(env, expert, q0, qd0, aux, horizon=2.0)
    assert replayed == ro.q.shape[0] * ro.q.shape[1] and asked < replayed / 2


def test_batched_check_equals_the_replay_where_rollouts_collide():
    """Coasting arms swept through the three-obstacle scene (a sphere moving on its path, a cylinder, a box): every
    collision flag and first collision time of the replay, clearances of colliding samples too."""
    env = franka_env(scene("franka_three_obstacles"))
    g = torch.Generator().manual_seed(5)
    q0, _, aux = env.sample(6, 1, generator=g)
    qd0 = 1.5 * torch.randn(q0.shape, generator=g, dtype=F64)

    def coast(q, qd, aux):
        return torch.zeros_like(q)

    _, ref, asked, replayed = _agree(env, coast, q0, qd0, aux, horizon=1.0)
    assert (ref[0] <= 0).any() and (ref[0] > 0).any() and asked < replayed
    env.close()
