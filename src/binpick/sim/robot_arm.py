"""An arm on a pedestal beside the bin, carrying binpick's hand: a Franka Emika Panda (7 joints) or a
Universal Robots UR5e (6 joints), chosen by ``--robot`` (a cell file's ``arm.model`` must agree).

Both are robosuite's models (meshes and kinematics; robosuite ships them, MIT licence; the package is
never imported, only its files are read). Their torque motors are replaced by joint position
actuators, so the arm is driven the way a joint impedance (Panda) or joint position (UR) controller
drives it: a joint target per control step. Gravity is compensated on the links, as the real
controllers do. The hand is the floating gripper's own (palm, fingers, cup: binpick's, or the ones a
cell file describes), on a tool shaft that puts the tool point where the cell file's ``tcp`` says
(binpick's own hand: a 10 cm shaft, so the wrist stays above the tote walls when the fingertips reach
the floor).

:data:`PANDA_LIMITS` are the Panda's published joint limits (Franka Control Interface documentation,
"Robot and interface specifications", Panda): position ranges as in the model, velocity, acceleration
and jerk per joint. :data:`UR5E_LIMITS`: the UR5e's ranges as in the model and its published speeds;
Universal Robots publish no per-joint acceleration or jerk limits, so those are binpick's (stated).

The same arm goes into two models: the bin world (:class:`binpick.sim.bin_scene.BinWorld` with
``robot=RobotArm()``), where it moves products, and the robot cell
(:func:`robot_cell_spec`: arm, table, bin and order tote, no products), the kinematic model inverse
kinematics and collision checks run on.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from binpick.core.errors import ConfigError
from binpick.grippers import TIPS_BELOW, Jaws, SuctionCup
from binpick.sim.mjcf import tote
from binpick.sim.order_tote import order_tote_xml
from binpick.sim.products import package_dir

JOINTS = tuple(f"joint{i}" for i in range(1, 8))


@dataclass(frozen=True)
class JointLimits:
    """Per-joint limits of an arm (radians, rad/s, rad/s², rad/s³) and where they come from."""

    lower: tuple[float, ...]
    upper: tuple[float, ...]
    velocity: tuple[float, ...]
    acceleration: tuple[float, ...]
    jerk: tuple[float, ...]
    source: str


PANDA_LIMITS = JointLimits(
    lower=(-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973),
    upper=(2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973),
    velocity=(2.175, 2.175, 2.175, 2.175, 2.61, 2.61, 2.61),
    acceleration=(15.0, 7.5, 10.0, 12.5, 15.0, 20.0, 20.0),
    jerk=(7500.0, 3750.0, 5000.0, 6250.0, 7500.0, 10000.0, 10000.0),
    source="Franka Control Interface documentation, Robot and interface specifications (Panda): "
           "joint position, velocity, acceleration and jerk limits",
)

# where the arm stands: its base beside the bin (x < 0, out of the overhead camera's view), between
# the bin (centre 0, 0) and the order tote (0, 0.42), facing +x
MOUNT = (-0.52, 0.18, 0.0)
# a posture out of the overhead camera's view, the hand above the arm's own base
HOME = (0.0, -1.12, 0.0, -2.13, 0.0, 1.01, 0.785)
TOOL_SHAFT = 0.10  # from the hand flange to the gripper's palm (m)
PALM_TOP = 0.062  # the palm's top above the fingers' centre, the gripper body's origin (binpick.sim.gripper)
TOOL_LENGTH = TOOL_SHAFT + PALM_TOP  # flange to the fingers' centre
TCP = TOOL_LENGTH + TIPS_BELOW  # flange to the tool point (the fingertips' midpoint) of binpick's own hand
# joint position (N m / rad) and velocity (N m s / rad) gains: at a sixth of these the fingertips overshot
# the end of a descent by 6 mm and scraped the bin floor; at these, by under 2 mm (stable at the 4 ms step)
KP = (27000.0, 27000.0, 21000.0, 21000.0, 12000.0, 12000.0, 6000.0)
KV = (750.0, 750.0, 500.0, 500.0, 250.0, 250.0, 125.0)


UR5E_HOME = (-0.908, -2.19, 1.315, -0.695, -1.571, -2.478)  # the gripper at (-0.35, 0.18, 0.55), pointing down
UR5E_NOMINAL = (-0.574, -1.461, 1.537, -1.647, -1.571, -2.145)
UR5E_LIMITS = JointLimits(  # the elbow's range as robosuite's model has it (the real joint turns further; its cable does not)
    lower=(-6.28319, -6.28319, -3.14159, -6.28319, -6.28319, -6.28319),
    upper=(6.28319, 6.28319, 3.14159, 6.28319, 6.28319, 6.28319),
    velocity=(3.1416,) * 6,
    acceleration=(10.0, 10.0, 10.0, 20.0, 20.0, 20.0),
    jerk=(5000.0, 5000.0, 5000.0, 10000.0, 10000.0, 10000.0),
    source="Universal Robots UR5e technical specifications: joint ranges (the elbow's as in robosuite's model) and "
           "180 deg/s on every joint; acceleration and jerk are not published per joint: binpick's assumptions",
)


@dataclass(frozen=True)
class ArmModel:
    """Which arm: robosuite's model folder, its joints, limits, where it stands, its home and IK postures,
    its controller's gains and the geom that stands on the table."""

    name: str
    folder: str  # robosuite/models/assets/robots/<folder>/robot.xml
    joints: tuple[str, ...]
    limits: JointLimits
    home: tuple[float, ...]  # a posture out of the overhead camera's view, the hand above the arm's own base
    nominal: tuple[float, ...]  # the IK's posture: the gripper 30 cm above the bin centre, pointing down
    kp: tuple[float, ...]
    kv: tuple[float, ...]
    base_geom: str  # its contact with the table is no collision
    dark: tuple[str, ...] = ()  # geoms drawn dark (the rest light grey)

    def assets(self) -> str:
        root = package_dir("robosuite")
        path = root / "models" / "assets" / "robots" / self.folder / "robot.xml" if root else None
        if path is None or not path.is_file():
            raise ConfigError(f"the {self.name} arm needs robosuite's model files: pip install --no-deps robosuite==1.5.2 "
                              "(make setup installs it)")
        return str(path)


PANDA = ArmModel("panda", "panda", JOINTS, PANDA_LIMITS, HOME, (-0.24, 0.0, -0.09, -2.0, 0.0, 2.0, 0.45), KP, KV,
                 "link0_collision", ("link0_collision", "link7_collision"))
# the UR5e's gains: the Panda's per joint of the same size (shoulder, elbow, wrists); its postures found by the
# IK from the Panda's, elbow up, the wrist over the bin
UR5E = ArmModel("ur5e", "ur5e", ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
                                 "wrist_3_joint"), UR5E_LIMITS,
                home=UR5E_HOME, nominal=UR5E_NOMINAL, kp=(27000.0, 27000.0, 21000.0, 12000.0, 12000.0, 6000.0),
                kv=(750.0, 750.0, 500.0, 250.0, 250.0, 125.0), base_geom="base_col", dark=("base_col", "wrist3_col"))
ARM_MODELS = {model.name: model for model in (PANDA, UR5E)}


def arm_model(name: str) -> ArmModel:
    """The arm called ``name`` (panda or ur5e); another name is one line."""
    if name not in ARM_MODELS:
        raise ConfigError(f"unknown arm {name!r}: choose from {', '.join(ARM_MODELS)}")
    return ARM_MODELS[name]


def shaft_length(tcp: float) -> float:
    """The tool shaft from the flange to the palm's top for a tool point ``tcp`` from the flange (m):
    the hand (palm and fingers, the tips TIPS_BELOW under its origin) fills the rest."""
    shaft = tcp - TIPS_BELOW - PALM_TOP
    if shaft < -1e-9:
        raise ConfigError(f"tcp {tcp:.4f} m: binpick's simulated hand needs at least {TIPS_BELOW + PALM_TOP:.3f} m "
                          "from the flange to the fingertips")
    return max(shaft, 0.0)


def gripper_xml(gripper: str = "jaws", jaws: Jaws = Jaws(), cup: SuctionCup = SuctionCup(), tcp: float = TCP) -> str:
    """binpick's hand as a body of the arm's hand (no free joint, no mocap weld): palm, the fingers and
    the cup ``gripper`` asks for (:mod:`binpick.sim.hand`, ``jaws`` and ``cup`` their geometry), and the
    tool shaft up to the flange, ``tcp`` above the fingertips."""
    from binpick.sim.hand import HAND_GROUP, hand_actuators, hand_contacts, hand_xml

    shaft = shaft_length(tcp)
    shaft_geom = (f'<geom name="shaft" type="cylinder" size="0.022 {shaft / 2}" pos="0 0 {PALM_TOP + shaft / 2}" '
                  f'rgba="0.3 0.3 0.32 1" mass="0.2" group="{HAND_GROUP}"/>') if shaft > 0.001 else ""
    return f"""<mujoco><worldbody>
<body name="gripper">
  <site name="tool" pos="0 0 0" size="0.005" rgba="1 0 0 0"/>
  {shaft_geom}
  {hand_xml(gripper, jaws, cup)}
</body></worldbody>
{hand_actuators(gripper, jaws)}{hand_contacts(gripper)}</mujoco>"""


def arm_spec(limits: JointLimits | None = None, gripper: str = "jaws", jaws: Jaws = Jaws(), cup: SuctionCup = SuctionCup(),
             tcp: float = TCP, model: ArmModel = PANDA) -> mujoco.MjSpec:
    """The arm ``model`` with binpick's hand (``gripper``: jaws, suction or both; ``jaws``, ``cup`` and the
    tool point ``tcp`` from the flange as a cell file gives them): position actuators on its joints,
    gravity compensated."""
    limits = model.limits if limits is None else limits
    arm = mujoco.MjSpec.from_file(model.assets())
    for actuator in list(arm.actuators):
        arm.delete(actuator)
    # the collision meshes are drawn too: the visual ones (170 files on the Panda) cost 2.5x the rendering time of a frame
    for geom in list(arm.geoms):
        if geom.contype == 0 and geom.conaffinity == 0:
            arm.delete(geom)
        else:
            geom.material = ""
            geom.rgba = [0.25, 0.25, 0.27, 1] if geom.name in model.dark else [0.92, 0.92, 0.93, 1]
    meshes = {geom.meshname for geom in arm.geoms}
    for asset in [*[m for m in arm.meshes if m.name not in meshes], *arm.materials]:
        arm.delete(asset)
    for body in arm.bodies:
        if body.name not in ("", "world", "base"):
            body.gravcomp = 1.0
    for index, name in enumerate(model.joints):
        joint = arm.joint(name)
        joint.armature = 0.1
        actuator = arm.add_actuator(name=f"arm_{name}", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        actuator.set_to_position(kp=model.kp[index])
        actuator.ctrlrange = [limits.lower[index], limits.upper[index]]
        actuator.ctrllimited = True
        # the velocity loop (damping on the error to the trajectory's velocity), as in a joint impedance controller
        damper = arm.add_actuator(name=f"arm_{name}_velocity", target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        damper.set_to_velocity(kv=model.kv[index])
        damper.ctrlrange = [-limits.velocity[index], limits.velocity[index]]
        damper.ctrllimited = True
    for camera in list(arm.cameras):
        arm.delete(camera)
    site = arm.body("right_hand").add_site(name="flange", pos=[0, 0, tcp - TIPS_BELOW], quat=[0, 1, 0, 0])
    arm.attach(mujoco.MjSpec.from_string(gripper_xml(gripper, jaws, cup, tcp)), prefix="", site=site)
    return arm


@dataclass
class RobotArm:
    """An arm (``model``: :data:`PANDA` or :data:`UR5E`) in a scene: ``attach(spec)`` puts it in before
    compiling; ``bind(model)`` finds its joints and actuators; ``hold(data)`` sets it to its home
    posture, at rest."""

    model: ArmModel = PANDA
    mount: tuple[float, float, float] = MOUNT
    gripper: str = "jaws"  # the hand's tools: jaws, suction or both
    jaws: Jaws = field(default_factory=Jaws)  # their geometry (a cell file's; default binpick's own)
    cup: SuctionCup = field(default_factory=SuctionCup)
    tcp: float = TCP  # the flange to the tool point (m)
    qpos: np.ndarray = field(default_factory=lambda: np.zeros(0, int), repr=False)
    dof: np.ndarray = field(default_factory=lambda: np.zeros(0, int), repr=False)
    actuators: np.ndarray = field(default_factory=lambda: np.zeros(0, int), repr=False)
    geoms: np.ndarray = field(default_factory=lambda: np.zeros(0, int), repr=False)

    @classmethod
    def carrying(cls, model: ArmModel, gripper: str, jaws: Jaws, cup: SuctionCup, tcp: float | None = None,
                 mount: tuple[float, float, float] | None = None) -> RobotArm:
        """``model`` carrying a hand (a cell file's: None for its tool point or base means binpick's own)."""
        return cls(model=model, mount=MOUNT if mount is None else tuple(mount), gripper=gripper, jaws=jaws, cup=cup,
                   tcp=TCP if tcp is None else tcp)

    @property
    def name(self) -> str:
        return self.model.name

    @property
    def home(self) -> tuple[float, ...]:
        return self.model.home

    @property
    def limits(self) -> JointLimits:
        return self.model.limits

    @property
    def joints(self) -> tuple[str, ...]:
        return self.model.joints

    def attach(self, spec: mujoco.MjSpec) -> None:
        frame = spec.worldbody.add_frame(pos=list(self.mount))
        spec.attach(arm_spec(self.limits, self.gripper, self.jaws, self.cup, self.tcp, self.model), prefix="", frame=frame)
        spec.worldbody.add_geom(name="pedestal", type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.12, 0.005, 0],
                                pos=[self.mount[0], self.mount[1], 0.005], rgba=[0.3, 0.3, 0.33, 1], contype=0, conaffinity=0)
        overview = next((c for c in spec.cameras if c.name == "overview"), None)
        if overview is not None:  # the pick GIFs' camera steps back to take in the arm too
            overview.pos = [0.97, 0.2, 1.5]
            overview.fovy = 52.0

    def bind(self, model: mujoco.MjModel) -> RobotArm:
        joints = [model.joint(name).id for name in self.joints]
        self.qpos = np.array([model.jnt_qposadr[j] for j in joints])
        self.dof = np.array([model.jnt_dofadr[j] for j in joints])
        self.actuators = np.array([model.actuator(f"arm_{name}").id for name in self.joints])
        self.velocity_actuators = np.array([model.actuator(f"arm_{name}_velocity").id for name in self.joints])
        self.hand_joints = np.array([model.jnt_qposadr[model.joint(n).id] for n in ("finger_a", "finger_b", "bellows")
                                     if _has_joint(model, n)], dtype=int)
        self.hand = None  # bind_hand: once the scene's product slots are known
        self.gripper_body = model.body("gripper").id
        self.tool_site = model.site("tool").id
        base = model.body("base").id
        robot_bodies = {b for b in range(model.nbody) if _descends(model, b, base)}
        self.geoms = np.array([g for g in range(model.ngeom) if model.geom_bodyid[g] in robot_bodies
                               and (model.geom_contype[g] or model.geom_conaffinity[g])])
        return self

    def hold(self, model: mujoco.MjModel, data: mujoco.MjData, q=None) -> None:
        q = np.asarray(self.home if q is None else q, dtype=float)
        data.qpos[self.qpos] = q
        data.qvel[self.dof] = 0.0
        data.ctrl[self.actuators] = q
        data.ctrl[self.velocity_actuators] = 0.0
        data.qpos[self.hand_joints] = 0.0
        if self.hand is not None:
            self.hand.reset(data)

    def bind_hand(self, model: mujoco.MjModel, slot_bodies: list[int] | None = None) -> None:
        """The arm's hand (:class:`binpick.sim.hand.Hand`), its vacuum welded to ``slot_bodies``."""
        from binpick.sim.hand import Hand

        self.hand = Hand(model, self.gripper, slot_bodies, self.cup)

    def joint_positions(self, data: mujoco.MjData) -> np.ndarray:
        return data.qpos[self.qpos].copy()


def _has_joint(model: mujoco.MjModel, name: str) -> bool:
    return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name) >= 0


def _descends(model: mujoco.MjModel, body: int, ancestor: int) -> bool:
    while body > 0:
        if body == ancestor:
            return True
        body = model.body_parentid[body]
    return False


def robot_cell_spec(arm: RobotArm | None = None, tote_tilt: tuple[float, float] = (0.0, 0.0)) -> mujoco.MjSpec:
    """The arm and what it must not hit (table, bin, order tote), no products: the model inverse
    kinematics and collision checks run on."""
    xml = f"""<mujoco model="robot_cell"><compiler angle="radian" autolimits="true"/>
  <asset><material name="bin" rgba="0.2 0.35 0.6 1"/></asset>
  <worldbody><geom name="table" type="box" pos="0 0 -0.01" size="1.5 1.5 0.01"/>
  {tote(tilt=tote_tilt).replace('name="bin_guard', 'contype="0" conaffinity="0" name="bin_guard')}
  {order_tote_xml(camera=False)}</worldbody></mujoco>"""
    spec = mujoco.MjSpec.from_string(xml)
    (arm or RobotArm()).attach(spec)
    return spec
