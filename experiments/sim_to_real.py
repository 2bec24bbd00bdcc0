"""Sim-to-real stand-in (thesis §6.2, Table 6.1): the Fetch Reach APRiL run's policies in a
second rendering domain that plays the physical robot's camera, before and after retraining
perception on <= 25 episodes recorded there.

    python experiments/sim_to_real.py [--run runs/april/april_fetchreach_w1.0/<time>] [--episodes 25]

Needs the APRiL run (python experiments/april.py --only april_fetchreach_w1.0). Writes
results/sim_to_real.json (the Table 6.1 rows) and its section of docs/RESULTS.md.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import _common  # noqa: E402


NAMES = {"simulated_ground_truth": ("simulated", "GT s̄"), "simulated_encoded": ("simulated", "Enc S (pixels)"),
         "shifted_ground_truth": ("shifted domain", "GT s̄"),
         "shifted_encoded_before_retraining": ("shifted domain", "Enc S, sim perception"),
         "shifted_encoded_retrained": ("shifted domain", "Enc S, perception retrained")}
THESIS = {"simulated_ground_truth": "15 / 2800 / - / 3.38 ± 2.37", "simulated_encoded": "65 / 2800 / - / 10.18 ± 10.84",
          "shifted_ground_truth": "15 / 2800 / 0 / 3.52 ± 2.45", "shifted_encoded_retrained": "65 / 2800 / 23 / 8.14 ± 12.75"}


def section(result: dict) -> str:
    """The Table 6.1 section of docs/RESULTS.md, from results/sim_to_real.json (``--episodes``: the
    retrained row's shifted-domain episodes)."""
    rows = result["rows"]
    episodes = rows["shifted_encoded_retrained"]["physical_episodes"]
    lines = ["## Sim-to-real stand-in (thesis §6.2, Table 6.1)", "",
             f"`python experiments/sim_to_real.py --episodes {episodes}` → `results/sim_to_real.json`. "
             f"Fetch Reach, APRiL run `{_common.repo_relative(result['run'])}`; the 'physical' robot is a second "
             f"rendering domain: {result['domain']}. Control is never retrained; perception is retrained for "
             f"{result['retraining_epochs']} epochs on the shifted domain's images only. {result['eval_episodes']} evaluation "
             "episodes per row.", "",
             "| agent | policy input | simulator episodes (policy) | GP episodes | shifted-domain episodes | avg actions ± std | success | thesis (sim / GP / physical / length) |",
             "|---|---|---|---|---|---|---|---|"]
    for key, (agent, policy_input) in NAMES.items():
        row = rows[key]
        lines.append(f"| {agent} | {policy_input} | {row['simulator_episodes']} | {row['gp_episodes']} | {row.get('physical_episodes', 0)} | "
                     f"{row['avg_actions']:.2f} ± {row['std']:.2f} | {row['success']:.0%} | {THESIS.get(key, '—')} |")
    lines += ["", "The two ground-truth rows are the same episodes: physics and evaluation seeds are unchanged, only the images differ, so control transfers exactly, as in the thesis.", "", "Perception for the pixel rows also used the run's simulator image episodes "
              f"({rows['simulated_encoded'].get('perception_sim_episodes')}); the thesis's 65 simulator episodes for Enc S count those."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=None)
    parser.add_argument("--episodes", type=int, default=25)
    parser.add_argument("--eval-episodes", type=int, default=100)
    args = parser.parse_args()
    from binpick.april.sim_to_real import transfer

    run = args.run or sorted((_common.ROOT / "runs" / "april" / "april_fetchreach_w1.0").glob("*/results.json"))[-1].parent
    out = _common.ROOT / "runs" / "sim_to_real" / time.strftime("%Y%m%d-%H%M%S")
    result = transfer(run, out, real_episodes=args.episodes, eval_episodes=args.eval_episodes)
    result["peak_rss_mib"] = round(_common.peak_rss_mib(), 1)
    _common.write_result("sim_to_real", result)
    print(_common.write_section_of("sim_to_real", section, "sim_to_real.json"))


if __name__ == "__main__":
    main()
