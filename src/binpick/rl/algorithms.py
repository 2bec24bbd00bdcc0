"""The RL algorithms binpick trains, each declared once, as SB3 keeps one class per algorithm: which
trainer runs it, how its env and its learner are built, what its checkpoints keep and how its policy is
read back. What differs between algorithms is looked up here rather than branched on (entry points,
``"module:name"``, imported when first used)."""

from __future__ import annotations

from dataclasses import dataclass

from binpick.core.jobs import load_entry_point


@dataclass(frozen=True)
class Algorithm:
    name: str
    trainer: str  # "module:Class" with new(config, runs, wrap_env) / resume(run_dir, wrap_env) / run(callback)
    env: str  # "module:function" (config, wrap_env) -> the env a run of it trains on
    policy: str  # "module:function" (checkpoint folder) -> binpick.core.policy.Policy
    learner: str | None = None  # SB3-based: "module:function" (config, env, tensorboard, envs) -> the SB3 model
    reads_semantic_state: bool = False  # with semantic_state: true its policy reads s̄ = (z, g), not the env's observation
    keeps_replay: bool = True  # its checkpoints hold the replay (an image replay is GBs: DQN's refills after a resume)
    simulators_on_ray: bool = False  # learns from several simulators at once (Ray actors feeding one learner)

    def load(self, part: str):
        """The trainer, env, policy or learner this algorithm names (imported now)."""
        return load_entry_point(getattr(self, part))


_SB3_ENV, _SB3_POLICY = "binpick.rl.envs:sb3_env", "binpick.rl.policy:load_sb3_policy"
ALGORITHMS = {algorithm.name: algorithm for algorithm in [
    Algorithm("sac", "binpick.rl.train:Trainer", _SB3_ENV, _SB3_POLICY, "binpick.rl.gp_her.model:build_sac",
              reads_semantic_state=True, simulators_on_ray=True),  # binpick's: episode HER, GP imagination
    Algorithm("sb3_sac_her", "binpick.rl.train:Trainer", _SB3_ENV, _SB3_POLICY, "binpick.rl.gp_her.model:build_sb3_sac_her",
              reads_semantic_state=True),  # the peer it is measured against
    Algorithm("dqn", "binpick.rl.train:Trainer", _SB3_ENV, _SB3_POLICY, "binpick.rl.dqn.model:build_dqn", keeps_replay=False),
    Algorithm("a3c", "binpick.rl.a3c.train:A3CTrainer", "binpick.rl.a3c.envs:make_a3c_env", "binpick.rl.a3c.policy:load_a3c_policy"),
]}
