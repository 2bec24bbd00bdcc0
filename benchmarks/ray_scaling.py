"""Ray simulator workers on this machine (thesis §6.1): env steps/s with 1 and 2 workers,
and a SAC + HER run in which one worker is killed midway.

    python benchmarks/ray_scaling.py [--seconds 40] [--run-steps 3000]

Writes results/ray_scaling.json ({steps_per_s {"1", "2"}, worker_killed_run_finished, ...}) and the
Ray section of docs/RESULTS.md. Throughput: workers play FetchReach episodes with an untrained SAC
policy (inference included) and stream them to the driver, which only counts them.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import time

os.environ.setdefault("MUJOCO_GL", "egl")
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "experiments"))  # _common: results and docs

import _common  # noqa: E402

ENV = "binpick/FetchReach-v0"


def throughput(workers: int, seconds: float) -> dict:
    from stable_baselines3 import SAC
    from stable_baselines3.common.vec_env import DummyVecEnv

    from binpick.integrations.ray.rollouts import DistributedRollouts
    from binpick.envs import make

    local = make(ENV)
    policy = SAC("MultiInputPolicy", DummyVecEnv([lambda: local]), device="cpu", seed=0).policy
    rollouts = DistributedRollouts(ENV, workers)
    try:
        rollouts.set_policy(policy)
        stream = rollouts.stream()
        for _ in range(2 * workers):  # warm-up: worker start-up and first episodes
            next(stream)
        steps, started = 0, time.perf_counter()
        while time.perf_counter() - started < seconds:
            steps += next(stream).steps
        elapsed = time.perf_counter() - started
    finally:
        rollouts.close()
        local.close()
    return {"steps_per_s": round(steps / elapsed, 1), "steps": steps, "seconds": round(elapsed, 1)}


def killed_run(steps: int) -> dict:
    from binpick.integrations.ray.learner import DistributedConfig, train_distributed

    killed = {}

    def on_episode(episode, rollouts, model):
        if not killed and model.num_timesteps >= steps // 3:
            pid = rollouts.worker_pids()[0]
            os.kill(pid, signal.SIGKILL)
            killed.update(pid=pid, at_step=int(model.num_timesteps))

    metrics = train_distributed(DistributedConfig(env=ENV, workers=2, total_timesteps=steps, learning_starts=500,
                                                  eval_episodes=50), on_episode=on_episode)
    finished = bool(killed) and metrics["env_steps"] >= steps
    return {"finished": finished, "killed_at_step": killed.get("at_step"), **{k: v for k, v in metrics.items() if k != "config"}}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=40.0)
    parser.add_argument("--run-steps", type=int, default=3000)
    args = parser.parse_args()
    rates = {str(n): throughput(n, args.seconds) for n in (1, 2)}
    for n, rate in rates.items():
        print(f"{n} worker(s): {rate['steps_per_s']} env steps/s", flush=True)
    run = killed_run(args.run_steps)
    print(f"killed run: {run}", flush=True)
    result = {"steps_per_s": {n: r["steps_per_s"] for n, r in rates.items()}, "throughput": rates,
              "worker_killed_run_finished": run["finished"], "killed_run": run, "load_average": round(os.getloadavg()[0], 2),
              "peak_rss_mib": round(_common.peak_rss_mib(), 1)}
    path = _common.write_result("ray_scaling", result)
    lines = ["## Ray simulator workers (thesis §6.1)", "",
             f"`python benchmarks/ray_scaling.py --seconds {args.seconds:g} --run-steps {args.run_steps}` → "
             f"`{path.relative_to(_common.ROOT)}`. Local Ray cluster on 127.0.0.1, one Fetch Reach simulator per worker "
             "process, untrained SAC policy in the workers.", "",
             "| workers | env steps/s |", "|---|---|"]
    lines += [f"| {n} | {r['steps_per_s']} |" for n, r in rates.items()]
    lines += ["", f"SAC + HER learner fed by 2 workers for {args.run_steps} env steps; worker 0's process was killed "
              f"(SIGKILL) at step {run['killed_at_step']}: the run {'finished' if run['finished'] else 'did NOT finish'} with "
              f"{run['env_steps']} steps from {run['episodes']} episodes, {run['lost_episodes']} episode lost, "
              f"{run['worker_restarts']} restart, {run['wall_s']} s; final success {run['final_success']:.0%} "
              f"({run['final_avg_actions']:.1f} actions, 50 episodes).", "",
             f"This machine has 2 cores: the learner, the workers and Ray's own processes share them. Load average at the end: {result['load_average']}."]
    _common.write_section("ray_scaling", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
