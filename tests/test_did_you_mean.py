"""A mistyped name gets the name meant: products, grasp policies, shipped weights, config keys and
enum values; a missing data set names the command that makes it; a small data set still has a val split."""

from __future__ import annotations

import pytest

from binpick.core.config import check_choice, from_dict
from binpick.core.errors import ConfigError
from binpick.sim import default_library


@pytest.fixture(scope="module")
def library():
    return default_library()


@pytest.mark.parametrize("given, meant", [("Mug", ["pybullet/mug"]), ("CAN", ["robosuite/can"]),
                                          ("Robosuite/Milk", ["robosuite/milk"])])
def test_product_names_are_taken_whatever_their_case(library, given, meant):
    assert library.resolve(given) == meant


@pytest.mark.parametrize("given, hint", [("mugg", "did you mean 'mug'?"), ("cerael", "did you mean 'cereal'?"),
                                         ("robosuite/milkk", "did you mean 'robosuite/milk'?"),
                                         ("box_0", "did you mean procedural/box_00, procedural/box_03")])
def test_a_mistyped_product_gets_the_one_meant(library, given, hint):
    with pytest.raises(ConfigError, match=f"unknown product or category '{given}'") as error:
        library.resolve(given)
    assert hint in str(error.value)
    with pytest.raises(ConfigError, match="did you mean"):
        library[given]


def test_a_name_near_nothing_says_where_the_names_are(library):
    with pytest.raises(ConfigError, match="binpick products list"):
        library.resolve("zzzz")


def test_grasp_policies_take_case_and_american_spelling_and_suggest_the_rest():
    from binpick.grasping import GraspPlanner
    from binpick.grasping.planner import GraspPolicyName
    from binpick.warehouse.policies import check_policies

    assert GraspPolicyName("Learned") is GraspPolicyName.LEARNT and GraspPolicyName("ANALYTIC") is GraspPolicyName.ANALYTIC
    assert GraspPlanner.load("Analytic").policy is GraspPolicyName.ANALYTIC
    with pytest.raises(ConfigError, match="'analytc' \\(did you mean 'analytic'\\?\\); choose from fixed, analytic, learnt"):
        GraspPlanner.load("analytc")
    with pytest.raises(ConfigError, match="did you mean 'learnt'"):
        check_policies(["lernt"])


def test_a_mistyped_shipped_weights_name_lists_the_shipped_ones():
    from binpick.detection import Detector
    from binpick.detection.detector import shipped_weights

    with pytest.raises(ConfigError, match="did you mean 'rod_tiny_320'\\?\\); shipped: rod_tiny_320, rod_photo_tiny_320"):
        Detector.load("rod_tiny")
    with pytest.raises(ConfigError, match="did you mean 'rod_photo_tiny_320'"):
        shipped_weights("rod_photo_tiny")


def test_config_keys_and_enum_values_get_the_nearest_name():
    from binpick.detection.config import DetectConfig

    with pytest.raises(ConfigError, match="did you mean 'epochs'"):
        from_dict(DetectConfig, {"name": "x", "train": {"epoch": 3}})
    with pytest.raises(ConfigError, match="did you mean 'random'"):
        check_choice("domain", "randm", ["default", "random", "shifted"])


def test_a_missing_data_set_names_the_command_that_makes_it(tmp_path):
    from binpick.detection.data import RepeatedInstances
    from binpick.warehouse.coco import open_dataset

    with pytest.raises(ConfigError, match=f"make one with: binpick data generate --out {tmp_path}"):
        open_dataset(tmp_path)
    with pytest.raises(ConfigError, match="make the data set with: binpick data generate --out"):
        RepeatedInstances(tmp_path / "bins" / "annotations_train.json")


@pytest.mark.parametrize("worlds, fraction", [(2, 0.1), (4, 0.1), (3, 0.05), (1, 0.1), (8, 0.1), (40, 0.25)])
def test_every_set_of_two_worlds_or_more_has_a_val_world_and_big_sets_keep_their_share(worlds, fraction):
    from binpick.warehouse.dataset import val_world

    val = [w for w in range(worlds) if val_world(w, fraction, worlds)]
    assert (len(val) >= 1) == (worlds >= 2)
    if worlds * fraction >= 1:
        assert len(val) == round(worlds * fraction)  # the even rule alone, unchanged
