"""Shared fixtures: every test runs headless (MUJOCO_GL=egl unless the caller chose otherwise)."""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import pytest  # noqa: E402

import binpick  # noqa: E402,F401  (registers the envs)

MUJOCO_ENV_IDS = [i for i in binpick.ENV_IDS if not i.endswith("Arm2D-v0")]


@pytest.fixture
def make_env():
    """binpick.make that closes every env it made, so GL contexts never pile up across tests."""
    made = []

    def _make(env_id: str, **kwargs):
        env = binpick.make(env_id, **kwargs)
        made.append(env)
        return env

    yield _make
    for env in made:
        env.close()
