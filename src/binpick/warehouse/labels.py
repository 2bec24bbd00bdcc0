"""Labels from trial grasps: which copies each grasp policy can pick (its own grasp, jittered, majority),
and random grasp candidates from depth executed for the grasp-quality model."""

from __future__ import annotations

from typing import Any

import numpy as np


def trial_ready(sim) -> None:
    """Trials run as the pick pipeline grasps: with the tote's invisible drop guards off. The guards
    keep products in the tote while a scene settles, but a trial's carry takes the product out over
    the walls (what that did to the labels: docs/notes.md, "Tuning notes")."""
    sim.set_guards(False)


def label_offsets(trials: int, jitter: float, rng: np.random.Generator) -> list[tuple[float, float]]:
    """Where a label's grasps put the jaws' centre, relative to the policy's choice: the policy's own
    grasp, then a cross at ``jitter``, then random points within it."""
    cross = [(0.0, 0.0), (jitter, 0.0), (-jitter, 0.0), (0.0, jitter), (0.0, -jitter)]
    extra = [tuple(v) for v in rng.uniform(-jitter, jitter, size=(max(0, trials - len(cross)), 2))]
    return (cross + extra)[:trials]


def grasp_outcomes(sim, state, policy, slot: int, offsets: list) -> list[bool]:
    """Whether ``policy``'s grasp on instance ``slot`` held, from the saved ``state``, once per jaws'
    offset (None: the plain call, so a user's policy without ``offset`` still labels data)."""
    held = []
    for offset in offsets:
        sim.restore(state)
        held.append(bool(policy.attempt(sim, slot) if offset is None else policy.attempt(sim, slot, offset)))
    return held


def label_pickability(sim, scene, record: dict[str, Any], policies, rng: np.random.Generator,
                      trials: int = 1, jitter: float = 0.002) -> None:
    """Thesis §5.4.4: try target instances in random order until one is picked (the query); then,
    from the saved scene state, attempt every remaining instance — with each policy.

    With ``trials`` > 1 each instance gets that many grasps per policy, the jaws' centre moved by
    up to ``jitter``: the label is the majority and ``pickable_rate`` the share that held. One grasp's
    outcome is not quite a property an image shows: moving Policy y's jaws by 2 mm (under a pixel)
    changed it for 18 of 168 target instances of binpick's default bins (11 of the 84 that held, 7 of
    the 84 that did not; 15 worlds, 2 scenes each: `the `label_noise` note (docs/notes.md)`).
    """
    targets = [a for a in record["annotations"] if a["is_target"]]
    if not targets:
        return
    trial_ready(sim)
    order = [targets[i] for i in rng.permutation(len(targets))]
    offsets = label_offsets(trials, jitter, rng) if trials > 1 else [None]
    for policy in policies:
        if hasattr(policy, "prepare"):  # planned grasps read the scene's depth once
            policy.prepare(scene)
        for annotation in order:
            held = grasp_outcomes(sim, scene.state, policy, annotation["slot"], offsets)
            annotation["pickable"][policy.name] = sum(held) * 2 > len(held)
            if trials > 1:
                annotation.setdefault("pickable_rate", {})[policy.name] = round(sum(held) / len(held), 3)
    first_policy = policies[0].name if policies else None
    picked = next((a for a in order if first_policy and a["pickable"][first_policy]), None)
    query = picked or order[0]
    query["is_query"] = True
    record["picked_by"] = first_policy if picked is not None else None


TRIAL_OFFSET = 0.012  # random shifts of the jaws' centre (m) beside the even-squeeze positions
TRIAL_VISIBLE = 0.3  # instances less visible than this get no trials (depth shows too little of them)
SUCTION_LIKELY = 6  # suction trials favour the candidates the prior ranks this high


def record_grasp_trials(sim, scene, record: dict[str, Any], trials: int, rng: np.random.Generator,
                        gripper: str = "jaws", jaws=None, cup=None) -> None:
    """Grasp-quality data (Dex-Net 2.0's recipe, on binpick's bins): per visible instance and tool of
    the hand (``gripper``: jaws, suction or both), ``trials`` candidates from depth alone (jaws:
    :func:`binpick.grasping.grasp_candidates`, all yaws, the even-squeeze centre and random shifts;
    suction: :func:`binpick.grasping.suction.suction_candidates`, points on the instance), three in
    four drawn among the feasible ones, each executed from the saved scene state; the outcome is
    whether that instance rose and stayed in the jaws (on the cup) through a carry at the pick
    pipeline's speed. ``jaws`` and ``cup``: the hand's geometry (a cell file's; default binpick's own),
    which the candidates are judged with and the simulated hand has."""
    from binpick.grasping import DepthFrame, JawGripper, PinholeCamera, grasp_candidates
    from binpick.grasping.instance import instance_surface
    from binpick.grasping.suction import analytic_probability, suction_candidates
    from binpick.grippers import tools_of
    from binpick.sim.gripper import lift_test, trial_timestep

    from binpick.grippers import SuctionCup

    jaws, cup = jaws or JawGripper(), cup or SuctionCup()
    frame = DepthFrame.from_depth(scene.depth, PinholeCamera.from_record(scene.camera))
    trial_ready(sim)
    results = []
    for annotation in record["annotations"]:
        if annotation["visible_fraction"] < TRIAL_VISIBLE:
            continue
        offsets = rng.uniform(-TRIAL_OFFSET, TRIAL_OFFSET, size=(2, 2)) if "jaws" in tools_of(gripper) else None
        surface = instance_surface(frame, annotation["bbox"])
        if surface is None:
            continue
        for tool in tools_of(gripper):
            if tool == "jaws":
                _, candidates = grasp_candidates(frame, annotation["bbox"], jaws, offsets=offsets, surface=surface)
            else:
                candidates = suction_candidates(frame, surface, cup, gripper=gripper, jaws=jaws)
            if not candidates:
                continue
            feasible = [c for c in candidates if c.rejected is None]
            likely = sorted(feasible, key=lambda c: -analytic_probability(c.seal, cup))[:SUCTION_LIKELY] if tool == "suction" else []
            for _ in range(trials):
                draw = rng.random()
                # suction: half the trials among the few the seal-and-wrench prior likes best (most suction
                # candidates fail; the model must learn where the planner chooses), a quarter among the rest
                pool = likely if likely and draw < 0.5 else feasible if feasible and draw < 0.75 else candidates
                candidate = pool[int(rng.integers(len(pool)))]
                sim.restore(scene.state)
                with trial_timestep(sim.model):
                    success = lift_test(sim, annotation["slot"], candidate.position, candidate.yaw, candidate.top, carry=True,
                                        tool=tool)
                trial = {"slot": annotation["slot"], "product": annotation["product"], **candidate.to_json(),
                         "top": round(candidate.top, 4), "support": round(candidate.support, 4), "success": success}
                if tool == "suction":
                    trial["why"] = sim.hand.vacuum.why
                results.append(trial)
    record["grasp_trials"] = results


# ---------------------------------------------------------------------- the whole run
