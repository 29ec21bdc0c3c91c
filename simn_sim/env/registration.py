"""Gymnasium registration of the simn-sim env ids (lazy string entry points)."""

from __future__ import annotations

import gymnasium as gym

ENV_IDS = {
    "SimnOffice-v0": {},  # realistic sensing (EnvConfig.sensing's default)
    "SimnOfficeIdeal-v0": {"sensing": "ideal"},
    "SimnOfficeFast-v0": {"width": 320, "height": 240},
    "SimnOfficeDynamic-v0": {"n_people": 4},
}


def register_envs() -> None:
    for env_id, kwargs in ENV_IDS.items():
        if env_id in gym.registry:
            continue
        gym.register(
            id=env_id,
            entry_point="simn_sim.env.office:SimnOfficeEnv",
            kwargs=dict(kwargs),
            max_episode_steps=None,  # the env truncates itself at EnvConfig.max_episode_steps
            disable_env_checker=False,
        )
