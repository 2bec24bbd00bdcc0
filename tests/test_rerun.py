"""``--rerun`` records every order in 3D: read back, the file holds per order the colour image, the
depth as an image and as points, the detections, the grasp candidates, the gripper's pose at its
grasp and the outcome."""

from __future__ import annotations

import json

import numpy as np
import pytest
import cli_zygote

pytest.importorskip("rerun")
from rerun.chunk import RrdReader  # noqa: E402

from binpick.viz.recording import read_entities  # noqa: E402

PER_ORDER = {"/world/camera/image/rgb": "Image", "/world/camera/image/depth": "DepthImage", "/world/bin/points": "Points3D",
             "/world/camera/image/detections": "Boxes2D", "/world/grasps/candidates": "Points3D", "/world/gripper": "Transform3D",
             "/world/outcome": "TextDocument", "/world/camera": "Transform3D", "/world/camera/image": "Pinhole"}


def values(path, entity: str, component: str) -> dict[int, list]:
    """order -> the component's values logged at ``entity`` for that order."""
    found: dict[int, list] = {}
    for chunk in RrdReader(str(path)).stream():
        if chunk.entity_path != entity:
            continue
        batch = chunk.to_record_batch()
        if component not in batch.schema.names:
            continue
        for order, value in zip(batch.column("order").to_pylist(), batch.column(component).to_pylist()):
            found[order] = value
    return found


def test_demo_rerun_records_each_order_in_3d(tmp_path):
    ran = cli_zygote.run(["demo", "--orders", "2", "--rerun", "--out", str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert ran.returncode == 0, ran.stderr[-2000:]
    path = tmp_path / "orders.rrd"
    assert f"3D recording: {path}" in " ".join(ran.stdout.split())
    entities = read_entities(path)
    for entity, archetype in PER_ORDER.items():
        assert archetype in entities.get(entity, set()), (entity, sorted(entities))
        assert set(values(path, entity, next(c for c in _components(path, entity)))) == {0, 1}, entity
    results = json.loads((tmp_path / "results.json").read_text())
    outcomes = values(path, "/world/outcome", "TextDocument:text")
    for order in results["orders"]:
        assert f"order {order['order']}: {order['product']}" in outcomes[order["order"]][0]
        assert order["reason"] in outcomes[order["order"]][0]
    points = np.asarray(values(path, "/world/bin/points", "Points3D:positions")[0])
    assert len(points) > 5000 and np.isfinite(points).all() and np.ptp(points[:, 2]) < 0.5  # a bin, not a cloud of noise
    gripper = values(path, "/world/gripper", "Transform3D:translation")
    planned = [a for a in results["orders"][0]["attempts"] if a["grasp_point"]]
    if planned:
        assert np.allclose(gripper[0][0], planned[0]["grasp_point"], atol=0.03)


def test_plan_rerun_records_the_frame_it_planned_on(tmp_path):
    ran = cli_zygote.run(["plan", "--sample", "--out", str(tmp_path), "--rerun"], capture_output=True, text=True, timeout=300)
    assert ran.returncode == 0, ran.stderr
    plan = json.loads((tmp_path / "plan.json").read_text())
    boxes = values(tmp_path / "plan.rrd", "/world/camera/image/detections", "Boxes2D:half_sizes")[0]
    assert len(boxes) == plan["detections"] >= 1
    translation = values(tmp_path / "plan.rrd", "/world/gripper", "Transform3D:translation")[0][0]
    assert np.allclose(translation, next(p for p in plan["plans"] if p["position"])["position"], atol=1e-4)


def _components(path, entity: str) -> list[str]:
    for chunk in RrdReader(str(path)).stream():
        if chunk.entity_path == entity:
            names = [n for n in chunk.to_record_batch().schema.names if ":" in n]
            if names:
                return names
    return []
