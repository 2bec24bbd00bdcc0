"""A user's own products end to end, as the README's "Your own products" section runs them: a YAML of
two meshes -> `products list` -> a small data set -> a tiny photo-conditioned detector -> `pick`."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

from conftest import binpick_here

ROOT = Path(__file__).resolve().parents[1]


def write_box(path: Path, sx: float, sy: float, sz: float) -> None:
    vertices = [(x * sx / 2, y * sy / 2, z * sz / 2) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]
    quads = [(1, 2, 4, 3), (5, 7, 8, 6), (1, 5, 6, 2), (3, 4, 8, 7), (1, 3, 7, 5), (2, 6, 8, 4)]
    lines = [f"v {x:g} {y:g} {z:g}" for x, y, z in vertices]
    lines += [f"f {a} {b} {c}\nf {a} {c} {d}" for a, b, c, d in quads]
    path.write_text("\n".join(lines) + "\n")


def write_prism(path: Path, radius: float, height: float, sides: int = 6) -> None:
    lines = [f"v {radius * math.cos(2 * math.pi * k / sides):g} {radius * math.sin(2 * math.pi * k / sides):g} {z:g}"
             for z in (-height / 2, height / 2) for k in range(sides)]
    for k in range(sides):
        a, b = k + 1, (k + 1) % sides + 1
        lines += [f"f {a} {b} {b + sides}", f"f {a} {b + sides} {a + sides}"]
    for k in range(1, sides - 1):
        lines += [f"f 1 {k + 2} {k + 1}", f"f {sides + 1} {sides + k + 1} {sides + k + 2}"]
    path.write_text("\n".join(lines) + "\n")


PRODUCTS = """products:
  - {id: acme/soap, category: soap, mesh: soap.obj, longest_side: 0.09, mass: 0.15, rgba: [0.9, 0.3, 0.3, 1.0],
     photos: [soap_front.png, soap_top.png]}
  - {id: acme/tin, category: tin, mesh: tin.obj, longest_side: 0.07, mass: 0.2, rgba: [0.2, 0.4, 0.9, 1.0]}
"""


def run(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    result = binpick_here(list(args), cwd=cwd)
    assert result.returncode == 0, (args, result.stderr[-2000:])
    return result


def test_your_own_products_from_yaml_to_a_pick(tmp_path):
    write_box(tmp_path / "soap.obj", 0.09, 0.05, 0.03)
    write_prism(tmp_path / "tin.obj", 0.03, 0.07)
    (tmp_path / "products.yaml").write_text(PRODUCTS)
    from PIL import Image, ImageDraw

    for name, box in (("soap_front.png", (20, 40, 108, 88)), ("soap_top.png", (30, 30, 98, 98))):  # two shop photos
        photo = Image.new("RGB", (128, 128), (250, 250, 250))
        ImageDraw.Draw(photo).rectangle(box, fill=(230, 70, 70))
        photo.save(tmp_path / name)

    listed = run("products", "list", "--products", "products.yaml", cwd=tmp_path).stdout
    assert "acme/soap" in listed and "acme/tin" in listed

    run("data", "generate", "--out", "mine", "--scenes", "4", "--products", "products.yaml", "--only-products",
        "--size", "128", "--workers", "1", "--policies", "y", "--scenes-per-world", "1", "--val-fraction", "0.25",
        "--copies", "2,4", "--distractors", "0,1", "--photo-views", "1", cwd=tmp_path)
    card = json.loads((tmp_path / "mine" / "annotations.json").read_text())
    assert {c["name"] for c in card["categories"]} == {"acme/soap", "acme/tin"}
    assert {i["split"] for i in card["images"]} == {"train", "val"}  # a 4-scene set still splits
    assert (tmp_path / "mine" / "photos" / "acme_soap.png").is_file()  # the shop's first photo, as given
    assert (tmp_path / "mine" / "photos" / "acme_soap" / "0.png").is_file()  # and one from a randomised studio

    run("detect", "train", str(ROOT / "configs" / "detection" / "rod_warehouse_photo.yaml"), "--runs", "runs",
        "--set", "name=mine", "--set", "data.train=mine/annotations_train.json",
        "--set", "data.val=mine/annotations_val.json", "--set", "data.image_size=128", "--set", "data.targets=all",
        "--set", "train.epochs=1", "--set", "train.batch_size=2", "--set", "train.workers=0", cwd=tmp_path)
    (run_dir,) = (tmp_path / "runs" / "mine").iterdir()

    picked = run("pick", "--products", "products.yaml", "--product", "soap", "--orders", "1", "--weights", str(run_dir),
                 "--out", "orders", cwd=tmp_path)
    results = json.loads((tmp_path / "orders" / "results.json").read_text())
    (order,) = results["orders"]
    assert order["product"] == "acme/soap" and order["seen"] is not None  # the weights list what they trained on
    assert (tmp_path / "orders" / "report.html").is_file() and "acme/soap" in picked.stdout
