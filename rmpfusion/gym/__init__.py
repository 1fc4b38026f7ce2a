"""rmpfusion's simulated experiments as Gymnasium environments, for the reinforcement-learning libraries that speak
Gymnasium's API (Stable-Baselines3, CleanRL, ...). Importing this package registers ``rmpfusion/<Experiment>-v0``
ids (``registration.py``); it needs the ``rl`` extra (``pip install rmpfusion[rl]``: gymnasium)."""

from .env import RMPfusionEnv, RMPfusionVectorEnv
from .registration import gym_id, register_all, simulated_experiments
from .task import GymTask, TaskError, build_task

IDS = register_all()

__all__ = [
    "IDS",
    "GymTask",
    "RMPfusionEnv",
    "RMPfusionVectorEnv",
    "TaskError",
    "build_task",
    "gym_id",
    "register_all",
    "simulated_experiments",
]
