"""Your cell in one file: the gripper your robot carries (jaws, a suction cup or both, their geometry
and the tool point's offset from the flange) and the arm, read once and validated. The planner takes
the jaws' stroke and fingers from it (no grasp wider than your jaws open is emitted), the simulator
builds the same hand from it (the floating hand, or an arm carrying it at the file's tool point: the
arm chosen by ``--robot`` must be the file's; without ``tcp`` the arm carries binpick's own hand's), and
the reports name it; ``binpick data generate --cell`` makes grasp trials and labels with it. Your tote
and table are found in your depth by ``binpick cell --frame`` (the workspace in camera.yaml).

    gripper:
      tools: jaws                 # jaws, suction or both
      jaws: {stroke: 0.08, finger_thickness: 0.012, finger_width: 0.02, finger_length: 0.045, margin: 0.005}
      suction: {radius: 0.015, vacuum_force: 30.0}
      tcp: 0.1034                 # the tool point's distance from the flange along its z (m)
    arm: {model: panda, base: [-0.52, 0.18, 0.0]}   # panda, ur5e or none (the default); where its base stands (m)

``binpick plan --cell cell.yaml``, ``binpick pick --cell cell.yaml [--robot panda]``; ``configs/cells/``
has a Franka Hand and a Robotiq 2F-85 on a Panda, and a 2F-85 on a UR5e.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from binpick.core.errors import ConfigError, InputFileError
from binpick.grippers import GRIPPERS, Jaws, SuctionCup

ARMS = ("panda", "ur5e", "none")
MIN_ARM_TCP = 0.102  # m: binpick's simulated hand from its palm's top to the fingertips (binpick.sim.robot_arm)
JAW_FIELDS = {"stroke": (0.01, 0.3), "finger_thickness": (0.002, 0.05), "finger_width": (0.004, 0.08),
              "finger_length": (0.01, 0.2), "margin": (0.0, 0.03)}
CUP_FIELDS = {"radius": (0.004, 0.05), "vacuum_force": (1.0, 500.0), "compliance": (0.0, 0.02), "depth": (0.0, 0.02),
              "max_tilt": (0.0, 80.0), "friction": (0.05, 3.0)}


@dataclass(frozen=True)
class Cell:
    """A picking cell: its hand's ``tools``, the jaws and cup, the tool point's offset from the
    flange, and the arm."""

    tools: str = "both"
    jaws: Jaws = field(default_factory=Jaws)
    cup: SuctionCup = field(default_factory=SuctionCup)
    tcp: float | None = None  # None: not given (a simulated arm carries binpick's own hand's tool point)
    arm: str = "none"
    name: str = "binpick"
    base: tuple[float, float, float] | None = None  # the arm's base in the cell (m; the bin's centre at 0, 0, its floor near z 0)

    @classmethod
    def load(cls, path: str | Path) -> Cell:
        """A cell file; every mistake is one line naming the field and the file."""
        from binpick.core.files import read_yaml

        path = Path(path)
        where = f"cell file {str(path)!r}"
        data = read_yaml(path, "cell file")
        if not isinstance(data, dict):
            raise InputFileError(f"{where} must be a mapping with gripper and arm")
        _only(data, {"gripper", "arm", "name"}, where)
        gripper = data.get("gripper")
        if not isinstance(gripper, dict):
            raise InputFileError(f"{where}: gripper must be a mapping (tools, jaws, suction, tcp)")
        _only(gripper, {"tools", "jaws", "suction", "tcp"}, f"{where}: gripper")
        tools = str(gripper.get("tools", "both"))
        if tools not in GRIPPERS:
            raise InputFileError(f"{where}: gripper.tools {tools!r}: choose from {', '.join(GRIPPERS)}")
        jaws = Jaws(**{("opening" if k == "stroke" else k): v for k, v in
                       _numbers(gripper.get("jaws") or {}, JAW_FIELDS, f"{where}: gripper.jaws").items()})
        if jaws.margin >= jaws.opening:
            raise InputFileError(f"{where}: gripper.jaws.margin ({jaws.margin} m) must be below the stroke ({jaws.opening} m)")
        cup = SuctionCup(**_numbers(gripper.get("suction") or {}, CUP_FIELDS, f"{where}: gripper.suction"))
        tcp = _numbers({"tcp": gripper["tcp"]}, {"tcp": (0.0, 0.5)}, f"{where}: gripper")["tcp"] if "tcp" in gripper else None
        arm = data.get("arm") or {}
        if not isinstance(arm, dict):
            raise InputFileError(f"{where}: arm must be a mapping (model)")
        _only(arm, {"model", "base"}, f"{where}: arm")
        model = str(arm.get("model", "none"))
        if model not in ARMS:
            raise InputFileError(f"{where}: arm.model {model!r}: choose from {', '.join(ARMS)}")
        base = arm.get("base")
        if base is not None:
            if not isinstance(base, list) or len(base) != 3 or not all(
                    isinstance(v, (int, float)) and not isinstance(v, bool) and abs(float(v)) <= 3.0 for v in base):
                raise InputFileError(f"{where}: arm.base must be [x, y, z] in metres, each within 3 m of the bin's centre, got {base!r}")
            base = tuple(float(v) for v in base)
        return cls(tools, jaws, cup, tcp, model, str(data.get("name", path.stem)), base)

    def check_arm(self, robot: str) -> None:
        """One line, before any work, when the arm asked for (``robot``) is not the one this file describes,
        or when its tool point is too close to the flange for the simulated hand on an arm."""
        if robot not in ("floating", self.arm) and self.arm != "none":
            raise ConfigError(f"cell {self.name!r} has a {self.arm} arm; robot {robot} asks for another: give robot {self.arm} "
                              "(or floating for the hand alone)")
        if robot != "floating" and self.tcp is not None and self.tcp < MIN_ARM_TCP - 1e-9:
            raise ConfigError(f"cell {self.name!r}: gripper.tcp {self.tcp} m: binpick's simulated hand on an arm needs at least "
                              f"{MIN_ARM_TCP} m from the flange to the fingertips (its palm and fingers)")

    @property
    def widest(self) -> float:
        """The widest object the jaws take (m): the stroke less the margin."""
        return self.jaws.opening - self.jaws.margin


def _only(data: dict, allowed: set[str], where: str) -> None:
    unknown = set(map(str, data)) - allowed
    if unknown:
        raise InputFileError(f"{where}: unknown field(s) {', '.join(sorted(unknown))} (known: {', '.join(sorted(allowed))})")


def _numbers(data, ranges: dict[str, tuple[float, float]], where: str) -> dict[str, float]:
    if not isinstance(data, dict):
        raise InputFileError(f"{where} must be a mapping of numbers ({', '.join(ranges)})")
    _only(data, set(ranges), where)
    values = {}
    for key, value in data.items():
        low, high = ranges[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= float(value) <= high:
            raise InputFileError(f"{where}.{key} must be a number from {low} to {high} (m, N or degrees), got {value!r}")
        values[key] = float(value)
    return values


def load_cell(path: str | Path | None, robot: str | None = None) -> Cell | None:
    """The cell file at ``path`` (None: no cell given); with ``robot``, checked to fit that arm
    (:meth:`Cell.check_arm`) before anything else is made."""
    if path is None:
        return None
    try:
        cell = Cell.load(path)
    except ConfigError as error:
        raise InputFileError(str(error)) from None
    if robot is not None:
        cell.check_arm(robot)
    return cell
