"""A humanoid upper body that bends under its own weight: default `platkit calibrate`, then
`platkit diagnose`, on settled poses from the elastic tree simulator (platkit.simulate.elastic_tree).

    .venv/bin/python benchmarks/trees_humanoid.py [--robot talos|icub|tiago_dual|g1|pr2|baxter|romeo|centauro|alex]
        [--seeds 1] [--poses 300 --heldout 200] [--bare] [--later N] [--compliance-scale F]

The robot (``--robot``, each a :class:`Robot` in ROBOTS_TABLE; IIT's iCub, PAL's TIAGo++ on its
torso lift, Unitree's G1, Willow Garage's PR2 on its torso lift, Rethink's Baxter (two arms on a
fixed torso), Aldebaran's Romeo, IIT's Centauro (two arms on a turning torso) and Boardwalk's Alex
(a three-joint spine) the others, from the same package): by default PAL's Talos
(example-robot-data's talos_reduced.urdf, with its inertias: a public description not written
here), legs removed, grippers fixed, both 7-joint arms and the head on a
torso whose last joint is coupled to the one before it as a URDF mimic joint (torso_3_joint, half
of torso_2_joint's pitch, 10 cm above it). The true robot, drawn per seed: origin errors (0.5 mm,
1 mrad RMS), zero offsets (2 mrad RMS), elastic torso and shoulder/elbow joints (the coupled one
too) and bending links at the torso and the shoulders (stiffer one way than the other by up to
25%: the effect fits one compliance for both), three markers on each hand, mocap noise
0.1 mm (``--compliance-scale F``: every true compliance times F). The calibration sees the nominal
URDF (``--bare``: with every inertia stripped).

Per seed and hand, the held-out mean marker error (mm, against the recorded noisy markers) of:
the rigid calibration, the calibration diagnose writes, and the true elastic model itself (the
noise floor); plus the effects diagnose names, and the places they name scored against the truth
(:func:`named_places`, :func:`right`: a joint of the every-joint compliance term counts where its
compliance is 3 standard deviations from zero; a link bending told apart from a joint's compliance
within that term, ``bending_<joint>``, counts as link bending at that joint). ``--later N``: also a
later session of the same robot, N new poses drawn from a stream of their own (the same truth,
markers and mocap; the first session's poses and noise unchanged), predicted by both calibrations
and never seen by calibrate or diagnose. ``--keep DIR`` keeps each seed's folders. Over the
seeds: the places named right, the true places no named place is (missed), the held-out error's
median fall per hand, and the share of the rigid calibration's excess over the noise floor that
diagnosis removes (the fall itself is bounded by the floor where the rigid calibration absorbs
most of the sag).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from platkit.cli import main as cli  # noqa: E402
from platkit.simulate.elastic_tree import (  # noqa: E402
    ElasticTruth,
    simulate_elastic_tree,
    write_elastic_session,
)
from platkit.urdf import read_urdf  # noqa: E402

ROBOTS = Path(metadata.distribution("example-robot-data").locate_file("cmeel.prefix/share/example-robot-data")) / "robots"


@dataclass(frozen=True)
class Robot:
    """A public humanoid's upper body: its URDF (under example-robot-data's robots folder), the
    hands the mocap tracks (hand -> link), the recorded joints, the truth's elastic joints with
    their nominal compliance (rad/(N m); drawn per seed within 0.5-1.5 of it), the bent links (at
    these joints, nominal bending compliance; drawn within 0.3-1.0 of it), the subtrees removed (at
    these joints: the legs), the trunk's joints (commanded over 35 % of their range, the arms 60 %),
    link bending that names the same place as another joint (same_place), the coupled joint
    added as a URDF mimic joint, if any, and the prefixes of the joints fixed (grippers, hands)."""

    name: str
    urdf: str
    hands: dict[str, str]
    recorded: list[str]
    elastic: dict[str, float]
    bent: dict[str, float]
    removed: tuple[str, ...]
    trunk: tuple[str, ...]
    same_place: dict[str, set[str]] = field(default_factory=dict)
    coupled: Callable[[ET.Element], None] | None = None
    fixed: tuple[str, ...] = ("gripper_",)


def talos_torso_3(robot: ET.Element) -> None:
    """torso_3: a pitch coupled to torso_2's, 10 cm above it, carrying what torso_2_link carried."""
    for j in robot.findall("joint"):
        if j.find("parent").get("link") == "torso_2_link":
            j.find("parent").set("link", "torso_3_link")
            o = j.find("origin")
            xyz = np.array([float(v) for v in (o.get("xyz") or "0 0 0").split()]) - [0, 0, 0.1]
            o.set("xyz", " ".join(f"{v:.6g}" for v in xyz))
    ET.SubElement(robot, "link", name="torso_3_link")
    tj = ET.SubElement(robot, "joint", name="torso_3_joint", type="revolute")
    ET.SubElement(tj, "parent", link="torso_2_link")
    ET.SubElement(tj, "child", link="torso_3_link")
    ET.SubElement(tj, "origin", xyz="0 0 0.1", rpy="0 0 0")
    ET.SubElement(tj, "axis", xyz="0 1 0")
    ET.SubElement(tj, "limit", lower="-1", upper="1", effort="100", velocity="1")
    ET.SubElement(tj, "mimic", joint="torso_2_joint", multiplier="0.5", offset="0")


_TALOS_ARMS = [f"arm_{s}_{i}_joint" for s in ("left", "right") for i in range(1, 8)]
_ICUB_ARMS = [f"{s}_{j}" for s in "lr" for j in ("shoulder_pitch", "shoulder_roll", "shoulder_yaw", "elbow",
                                                  "wrist_prosup", "wrist_pitch", "wrist_yaw")]
ROBOTS_TABLE = {
    # PAL's Talos: the torso's last joint coupled to the one before it (torso_3_joint, half of
    # torso_2_joint's pitch); torso_2_joint's origin is torso_1_joint's (a link of zero length), so
    # a bend before torso_2 is one after torso_1
    "talos": Robot(
        "talos", "talos_data/robots/talos_reduced.urdf", {"left": "arm_left_7_link", "right": "arm_right_7_link"},
        ["torso_1_joint", "torso_2_joint", "head_1_joint", "head_2_joint", *_TALOS_ARMS],
        {j: 1e-4 for j in ["torso_1_joint", "torso_2_joint", "torso_3_joint"]
         + [f"arm_{s}_{i}_joint" for s in ("left", "right") for i in (1, 2, 4)]},
        {j: 1e-4 for j in ["torso_2_joint", "arm_left_2_joint", "arm_right_2_joint"]},
        ("leg_left_1_joint", "leg_right_1_joint"), ("torso", "head"),
        {"torso_2_joint": {"torso_1_joint"}}, talos_torso_3),
    # IIT's iCub (about 28 kg): torso_pitch, torso_roll, torso_yaw, two 7-joint arms, the neck fixed
    # in this description. Its torso's tendon coupling acts between the motors and the joints (the
    # joints stay three independent degrees of freedom), so it is no mimic joint: none here. Elastic:
    # the torso's three joints (harmonic drives: 2e-4 rad/(N m) nominal) and each arm's shoulder
    # pitch and roll and elbow (tendon-driven: 1e-3); bent: the chest where each shoulder hangs on
    # it (1e-3), at the shoulder pitch joint.
    "icub": Robot(
        "icub", "icub_description/robots/icub_reduced.urdf", {"left": "l_hand", "right": "r_hand"},
        ["torso_pitch", "torso_roll", "torso_yaw", *_ICUB_ARMS],
        {"torso_pitch": 2e-4, "torso_roll": 2e-4, "torso_yaw": 2e-4,
         **{f"{s}_{j}": 1e-3 for s in "lr" for j in ("shoulder_pitch", "shoulder_roll", "elbow")}},
        {"l_shoulder_pitch": 1e-3, "r_shoulder_pitch": 1e-3},
        ("l_hip_pitch", "r_hip_pitch"), ("torso",)),
    # PAL's TIAGo++ (tiago_dual.urdf, 98 kg with its base): two 7-joint arms and the head on one
    # prismatic torso lift (0-0.35 m) above a fixed column on the mobile base; the base's wheels,
    # suspension and casters removed, the hands' fingers fixed, a marker triad on each palm. The
    # lift's own compliance is left out of the truth: its load (the weight of all above it, along
    # its vertical axis) never changes, so its give is one constant offset, which no session can
    # see. Elastic: each arm's shoulder and elbow joints that hold the arm's weight (arm_2, arm_3,
    # arm_4: harmonic drives, 2e-4 rad/(N m) nominal; arm_1 turns about the vertical and holds
    # none); bent: the lift's telescoping column under the moment of both arms and the head (at
    # torso_lift_joint, 5e-5 nominal), and each shoulder's first link, a 12.5 cm bracket the arm
    # hangs on (at arm_2, 2e-4).
    "tiago_dual": Robot(
        "tiago_dual", "tiago_description/robots/tiago_dual.urdf",
        {"left": "hand_left_palm_link", "right": "hand_right_palm_link"},
        ["torso_lift_joint", "head_1_joint", "head_2_joint", *_TALOS_ARMS],
        {f"arm_{s}_{i}_joint": 2e-4 for s in ("left", "right") for i in (2, 3, 4)},
        {"torso_lift_joint": 5e-5, "arm_left_2_joint": 2e-4, "arm_right_2_joint": 2e-4},
        ("suspension_right_joint", "suspension_left_joint", "caster_front_right_1_joint",
         "caster_front_left_1_joint", "caster_back_right_1_joint", "caster_back_left_1_joint"),
        ("torso", "head"), fixed=("gripper_", "hand_")),
    # Unitree's G1 (g1_29dof_rev_1_0.urdf, 35 kg): a three-joint waist (yaw about the vertical,
    # then roll and pitch at one point: pitch at roll's origin, across it) carrying the torso, the
    # head (fixed) and two 7-joint arms with three-joint wrists; the legs removed, markers on the
    # rubber hands. Elastic: the waist's roll and pitch, which hold the whole upper body (its yaw
    # turns about the vertical and holds none), 1e-4 rad/(N m) nominal, and each arm's shoulder
    # pitch and roll and elbow (low-ratio drives under position control: 5e-4); bent: the torso
    # where each shoulder hangs on it (at *_shoulder_pitch_joint, 5e-4).
    "g1": Robot(
        "g1", "g1_description/urdf/g1_29dof_rev_1_0.urdf", {"left": "left_rubber_hand", "right": "right_rubber_hand"},
        ["waist_yaw_joint", "waist_roll_joint", "waist_pitch_joint",
         *[f"{s}_{j}_joint" for s in ("left", "right") for j in ("shoulder_pitch", "shoulder_roll", "shoulder_yaw",
                                                                  "elbow", "wrist_roll", "wrist_pitch", "wrist_yaw")]],
        {"waist_roll_joint": 1e-4, "waist_pitch_joint": 1e-4,
         **{f"{s}_{j}_joint": 5e-4 for s in ("left", "right") for j in ("shoulder_pitch", "shoulder_roll", "elbow")}},
        {"left_shoulder_pitch_joint": 5e-4, "right_shoulder_pitch_joint": 5e-4},
        ("left_hip_pitch_joint", "right_hip_pitch_joint"), ("waist",)),
    # Willow Garage's PR2 (pr2.urdf, 257 kg with its base): two 7-joint arms (shoulder pan, lift,
    # upper-arm roll, elbow flex, forearm roll, wrist flex, wrist roll: the two rolls continuous,
    # commanded over 60 % of -pi..pi) and the head on a prismatic torso lift (0-0.31 m) on the
    # fixed base; the laser's tilt and the grippers fixed, a marker triad on each gripper's palm.
    # The lift's own give is left out as on TIAGo++ (its load never changes). Elastic: each arm's
    # shoulder lift, upper-arm roll and elbow flex (the joints that hold the arm's weight; the
    # description carries no counterbalance spring, so the truth's torques are the bare arm's:
    # 1e-4 rad/(N m) nominal); bent: the lift's column under both arms and the head (at
    # torso_lift_joint, 5e-5) and each shoulder's pan link, the 10 cm bracket the arm hangs on (at
    # *_shoulder_lift_joint, 1e-4; the upper-arm roll's axis passes through its pivot).
    "pr2": Robot(
        "pr2", "pr2_description/urdf/pr2.urdf", {"left": "l_gripper_palm_link", "right": "r_gripper_palm_link"},
        ["torso_lift_joint", "head_pan_joint", "head_tilt_joint",
         *[f"{s}_{j}_joint" for s in "lr" for j in ("shoulder_pan", "shoulder_lift", "upper_arm_roll", "elbow_flex",
                                                     "forearm_roll", "wrist_flex", "wrist_roll")]],
        {f"{s}_{j}_joint": 1e-4 for s in "lr" for j in ("shoulder_lift", "upper_arm_roll", "elbow_flex")},
        {"torso_lift_joint": 5e-5, "l_shoulder_lift_joint": 1e-4, "r_shoulder_lift_joint": 1e-4},
        (), ("torso", "head"), fixed=("l_gripper_", "r_gripper_", "laser_tilt_")),
    # Rethink's Baxter (baxter.urdf, 137 kg with its pedestal): two 7-joint arms (s0 about the
    # vertical, s1 pitch, e0 roll, e1 pitch, w0 roll, w1 pitch, w2 roll) and the head's pan on a
    # fixed torso; the grippers' fingers fixed, a marker triad on each gripper's base. Its joints
    # are series elastic, but the output encoders see the springs' give and the servo takes it out:
    # what is left is the give of the drive trains and bearings, as on the others. Elastic: each
    # arm's s1, e0 and e1 (the shoulder pitch, the roll along the upper arm and the elbow pitch that
    # hold the arm's weight: 2e-4 rad/(N m) nominal); bent: the torso's arm mount where each arm
    # hangs on it (at *_s0, 1e-4) and the upper shoulder, the 27 cm bracket from s0 to s1 (at *_s1,
    # 2e-4; e0's axis passes through s1's pivot, as TIAGo++'s arm_3 through arm_2's).
    "baxter": Robot(
        "baxter", "baxter_description/urdf/baxter.urdf", {"left": "left_gripper_base_link", "right": "right_gripper_base_link"},
        ["head_pan", *[f"{s}_{j}" for s in ("left", "right") for j in ("s0", "s1", "e0", "e1", "w0", "w1", "w2")]],
        {f"{s}_{j}": 2e-4 for s in ("left", "right") for j in ("s1", "e0", "e1")},
        {"left_s0": 1e-4, "right_s0": 1e-4, "left_s1": 2e-4, "right_s1": 2e-4},
        (), ("head",), fixed=("l_gripper_", "r_gripper_")),
    # Aldebaran's Romeo (romeo.urdf, 40.5 kg; 17 kg above the hips): a trunk yaw about the vertical
    # (TrunkYaw: holds no gravity torque), a four-joint neck and head, two 7-joint arms (shoulder
    # pitch, shoulder yaw, elbow roll, elbow yaw, wrist roll, yaw, pitch; 2.4 kg each); the legs
    # removed, the hands fixed (LHand, RHand and their 22 fingers, mimic joints of the hand's joint in
    # the description, all massless), sensor frames kept, a marker triad on each wrist (l_wrist,
    # r_wrist). Its light arms load their joints little (2 N m RMS at a shoulder pitch), so the
    # truth's joints are soft (1e-3 rad/(N m) nominal, as iCub's tendons) at each arm's shoulder pitch
    # and yaw and elbow roll; bent: the trunk's column at TrunkYaw (the moment of both arms and the
    # head across it, 5e-4) and the shoulder mount at *ShoulderPitch (1e-3; the shoulder yaw's axis
    # passes through its pivot).
    "romeo": Robot(
        "romeo", "romeo_description/urdf/romeo.urdf", {"left": "l_wrist", "right": "r_wrist"},
        ["TrunkYaw", "NeckYaw", "NeckPitch", "HeadPitch", "HeadRoll",
         *[f"{s}{j}" for s in "LR" for j in ("ShoulderPitch", "ShoulderYaw", "ElbowRoll", "ElbowYaw", "WristRoll",
                                             "WristYaw", "WristPitch")]],
        {f"{s}{j}": 1e-3 for s in "LR" for j in ("ShoulderPitch", "ShoulderYaw", "ElbowRoll")},
        {"TrunkYaw": 5e-4, "LShoulderPitch": 1e-3, "RShoulderPitch": 1e-3},
        ("LHipYaw", "RHipYaw"), ("Trunk", "Neck", "Head"),
        fixed=("LHand", "RHand", "LFinger", "RFinger", "LThumb", "RThumb")),
    # IIT's Centauro (centauro.urdf, 117 kg; 36 kg above the pelvis): a dual-arm torso on a yaw
    # joint about the vertical (torso_yaw: holds no gravity torque) on the four-legged wheeled base
    # (the legs and wheels removed; the wheels are revolute joints without limits in the
    # description), two 6-joint arms of 10.7 kg each (j_armN_1 shoulder pitch, _2 roll, _3 yaw,
    # _4 elbow, _5 and _6 the wrist), a fixed neck with two sensor tilts (velodyne, d435: one holds
    # no load), a marker triad on each hand's ball (ball1, ball2). Elastic: each arm's _1, _2 and
    # _4, which hold the arm's weight (2e-4 rad/(N m) nominal); bent: the torso's column under the
    # moment of both arms at torso_yaw (43 N m RMS, 2e-5) and the shoulder mount at j_armN_1 (1e-4).
    "centauro": Robot(
        "centauro", "centauro_description/urdf/centauro.urdf", {"left": "ball1", "right": "ball2"},
        ["torso_yaw", "velodyne_joint", "d435_head_joint", *[f"j_arm{a}_{i}" for a in (1, 2) for i in range(1, 7)]],
        {f"j_arm{a}_{i}": 2e-4 for a in (1, 2) for i in (1, 2, 4)},
        {"torso_yaw": 2e-5, "j_arm1_1": 1e-4, "j_arm2_1": 1e-4},
        ("hip_yaw_1", "hip_yaw_2", "hip_yaw_3", "hip_yaw_4"), ("torso", "velodyne", "d435")),
    # Boardwalk Robotics' Alex (alex_nub_hands.urdf, 47 kg, 43 kg above the fixed pelvis): a
    # three-joint spine (yaw about the vertical, roll, pitch) under a 17.6 kg torso, a two-joint
    # neck and two 7-joint arms of 10.1 kg each, a marker triad on each nub hand (leftNub,
    # rightNub). Elastic: the spine's roll and pitch, which hold the whole upper body (40 N m RMS at
    # the pitch; 1e-4 rad/(N m) nominal) and each arm's shoulder pitch and roll and elbow (2e-4);
    # bent: the torso where each shoulder hangs on it (at *ShoulderPitch, 2e-4).
    "alex": Robot(
        "alex", "alex_description/urdf/alex_nub_hands.urdf", {"left": "leftNub", "right": "rightNub"},
        ["SpineYaw", "SpineRoll", "SpinePitch", "NeckYaw", "NeckPitch",
         *[f"{s}{j}" for s in ("Left", "Right") for j in ("ShoulderPitch", "ShoulderRoll", "ShoulderYaw", "ElbowPitch",
                                                          "WristYaw", "WristRoll", "GripperYaw")]],
        {"SpineRoll": 1e-4, "SpinePitch": 1e-4,
         **{f"{s}{j}": 2e-4 for s in ("Left", "Right") for j in ("ShoulderPitch", "ShoulderRoll", "ElbowPitch")}},
        {"LeftShoulderPitch": 2e-4, "RightShoulderPitch": 2e-4},
        (), ("Spine", "Neck")),
}
#: the robot of this run (``--robot``)
ROBOT = ROBOTS_TABLE["talos"]


def upper_body(out: Path, bare: bool = False, robot: Robot | None = None) -> Path:
    """The robot's upper body (see :class:`Robot`): transmissions, gazebo tags, the description's
    own mimic tags, visuals and collisions dropped, grippers (hands) fixed, the removed subtrees gone, the
    coupled joint added (``bare``: every inertia stripped too)."""
    robot = robot or ROBOT
    tree = ET.parse(ROBOTS / robot.urdf)
    root = tree.getroot()
    for tag in ("transmission", "gazebo"):
        for e in root.findall(tag):
            root.remove(e)
    for j in root.findall("joint"):
        for m in j.findall("mimic"):
            j.remove(m)
        if j.get("name").startswith(robot.fixed) and j.get("type") != "fixed":
            j.set("type", "fixed")
    children: dict[str, list[ET.Element]] = {}
    for j in root.findall("joint"):
        children.setdefault(j.find("parent").get("link"), []).append(j)
    cut = [j for j in root.findall("joint") if j.get("name") in robot.removed]
    gone: set[str] = set()
    while cut:
        j = cut.pop()
        root.remove(j)
        link = j.find("child").get("link")
        gone.add(link)
        cut.extend(children.get(link, []))
    for link in root.findall("link"):
        if link.get("name") in gone:
            root.remove(link)
    if robot.coupled is not None:
        robot.coupled(root)
    if bare:
        for link in root.findall("link"):
            for e in link.findall("inertial"):
                link.remove(e)
    for link in root.findall("link"):
        for tag in ("visual", "collision"):
            for e in link.findall(tag):
                link.remove(e)
    tree.write(out)
    return out


def limits(path: Path) -> dict[str, tuple[float, float]]:
    """The limits of every revolute and prismatic joint (rad, m), in the URDF's order; a continuous
    joint's -pi..pi, and a revolute joint's whose limits are left out or equal (the URDF's 0..0,
    which platkit.urdf reads as no limit: Centauro's wheels) too."""
    out = {}
    for j in ET.parse(path).getroot().findall("joint"):
        kind, lim = j.get("type"), j.find("limit")
        if kind == "continuous":  # no limits: a turn either way
            out[j.get("name")] = (-np.pi, np.pi)
        elif lim is not None and kind in ("revolute", "prismatic"):
            lo, hi = (float(lim.get(end) or 0.0) for end in ("lower", "upper"))  # left out: the URDF's 0
            out[j.get("name")] = (lo, hi) if lo < hi or kind == "prismatic" else (-np.pi, np.pi)
    return out


def draw(seed: int, nominal: Path, n: int, scale: float = 1.0) -> tuple[ElasticTruth, np.ndarray]:
    """The true robot and the first session's commands (``scale``: every compliance times it)."""
    rng = np.random.default_rng(seed)
    lim = limits(nominal)
    moving = [j for j in lim]
    truth = ElasticTruth(
        joint_compliance={j: float(rng.uniform(0.5, 1.5) * c * scale) for j, c in ROBOT.elastic.items()},
        bending={j: (float(k), float(k * rng.uniform(0.8, 1.25))) for j, c in ROBOT.bent.items()
                 for k in [rng.uniform(0.3, 1.0) * c * scale]},
        origin_error={j: (rng.normal(0, 0.5e-3, 3), rng.normal(0, 1e-3, 3)) for j in moving},
        offset={j: float(rng.normal(0, 2e-3)) for j in ROBOT.recorded})
    return truth, commands(rng, lim, n)


def later_commands(seed: int, nominal: Path, n: int) -> np.ndarray:
    """The poses of a later session of the same robot: drawn like the first session's, from a
    stream of their own (the truth, the markers and the mocap as they were)."""
    return commands(np.random.default_rng([seed, 2]), limits(nominal), n)


def commands(rng: np.random.Generator, lim: dict[str, tuple[float, float]], n: int) -> np.ndarray:
    cmd = np.zeros((n, len(ROBOT.recorded)))
    for i, j in enumerate(ROBOT.recorded):
        lo, hi = lim[j]
        share = 0.35 if j.startswith(ROBOT.trunk) else 0.6
        mid, half = (lo + hi) / 2, (hi - lo) / 2 * share
        cmd[:, i] = rng.uniform(mid - half, mid + half, n)
    return cmd


def predicted(cal: Path, commands: np.ndarray, names: list[str], work: Path) -> dict[str, np.ndarray]:
    """The markers ``predict`` puts at ``commands`` (a prismatic joint's in m, written in the
    session's mm as the simulator's sessions have them)."""
    joints = read_urdf(work / f"{ROBOT.name}_upper.urdf").joints
    commands = commands * np.array([1e3 if joints[j].type == "prismatic" else 1.0 for j in ROBOT.recorded])
    csv = work / "commands.csv"
    csv.write_text("\n".join([",".join(["t", *ROBOT.recorded])] + [",".join([f"{k}.0", *(f"{v:.10g}" for v in row)])
                                                            for k, row in enumerate(commands)]) + "\n")
    out = work / "predicted.csv"
    if cli(["predict", "--calibration", str(cal), "--commands", str(csv), "--out", str(out)]):
        raise SystemExit(f"predict failed on {cal}")
    data = np.genfromtxt(out, delimiter=",", names=True)
    return {n: np.stack([data[f"{n}_x"], data[f"{n}_y"], data[f"{n}_z"]], axis=1) for n in names}


def per_hand(pred: dict[str, np.ndarray], recorded: np.ndarray, sim) -> dict[str, float]:
    out = {}
    for hand, link in ROBOT.hands.items():
        errs = [np.linalg.norm(pred[n] - 1e3 * recorded[:, m], axis=1)
                for m, (n, lk) in enumerate(zip(sim.marker_names, sim.marker_links)) if lk == link]
        out[hand] = float(np.mean(errs))
    return out


#: a fitted parameter counts as named when it is this many of its standard deviations from zero
NAMED_SIGMA = 3.0


def named_places(findings: list[dict]) -> list[tuple[str, str]]:
    """(effect, joint) of every place a finding names: one per finding, and for a term of many
    joints (compliance of every loaded joint) each joint whose compliance is NAMED_SIGMA from zero
    (its estimated mass moments, on a URDF without inertias, name no place)."""
    out = []
    for f in findings:
        w = f["where"]
        if "joints" in w:  # compliance_<actuator>, then the link bending told apart from one: bending_<joint>[_u|_v]
            joint_of = dict(zip(w["actuators"], w["joints"]))
            for name, par in f["parameters"].items():
                if not (par.get("std") and abs(par["value"]) > NAMED_SIGMA * par["std"]):
                    continue
                if name.startswith("mass_moments_"):  # the tree's mass moments, estimated: no place
                    continue
                if name.startswith("bending_"):
                    place = ("link_bending", name[len("bending_"):].removesuffix("_u").removesuffix("_v"))
                else:
                    place = (f["effect"], joint_of[name[len("compliance_"):]])
                if place not in out:
                    out.append(place)
        else:
            out.append((f["effect"], str(w.get("actuator") or w.get("joint") or "")))
    return out


def right(effect: str, joint: str) -> bool | None:
    """Whether a named place is a true one (None: an effect this benchmark does not plant)."""
    if effect == "compliance":
        return joint in ROBOT.elastic
    if effect == "link_bending":
        return joint in ROBOT.bent or any(joint in ROBOT.same_place.get(b, ()) for b in ROBOT.bent)
    return False


def missed(places: list[tuple[str, str]]) -> list[tuple[str, str]]:
    """The true places (an elastic joint's compliance, a link bent at a joint) no named place is."""
    truth = [("compliance", j) for j in ROBOT.elastic] + [("link_bending", b) for b in ROBOT.bent]
    return [(e, j) for e, j in truth if not any(
        e == f and (j == k or (e == "link_bending" and k in ROBOT.same_place.get(j, ()))) for f, k in places)]


def run(seed: int, n_fit: int, n_held: int, bare: bool, root: Path, n_later: int = 0, scale: float = 1.0) -> dict:
    nominal = upper_body(root / f"{ROBOT.name}_upper.urdf")
    model_urdf = upper_body(root / f"{ROBOT.name}_upper_bare.urdf", bare=True) if bare else nominal
    truth, cmd = draw(seed, nominal, n_fit + n_held, scale)
    # a later session's poses after the first's: the simulator draws the noise row by row, so the
    # first session's poses and noise are the same with or without them
    cmd = np.vstack([cmd, later_commands(seed, nominal, n_later)])
    markers = {f"{h[0].upper()}{k}": link for h, link in ROBOT.hands.items() for k in range(1, 4)}
    sim = simulate_elastic_tree(nominal, truth, cmd, ROBOT.recorded, markers, seed=seed + 1000, workdir=root)
    fit, held = np.arange(n_fit), np.arange(n_fit, n_fit + n_held)
    moving = dict(markers)
    train = write_elastic_session(sim, model_urdf, root / "train", moving, fit)
    test = write_elastic_session(sim, model_urdf, root / "test", moving, held)
    t0 = time.perf_counter()
    if cli(["calibrate", str(train), "--out", str(root / "cal"), "--quiet", "--no-report"]):
        raise SystemExit("calibrate failed")
    t1 = time.perf_counter()
    if cli(["diagnose", str(train), "--calibration", str(root / "cal" / "calibration.yaml"), "--heldout", str(test),
            "--out", str(root / "diag"), "--quiet"]):
        raise SystemExit("diagnose failed")
    t2 = time.perf_counter()
    d = json.loads((root / "diag" / "diagnosis.json").read_text())
    rigid, after, floor, unmodelled = scores(root, cmd, held, sim)
    names = "; ".join(f"{f['effect']} ({f['where'].get('actuator') or f['where'].get('joint') or ''})"
                      for f in d["findings"])
    places = named_places(d["findings"])
    good = [p for p in places if right(*p)]
    lost = missed(places)
    names += (f"\n  places named: {len(places)}, right {len(good)}"
              f" ({', '.join(f'{e} {j}' for e, j in places if not right(e, j)) or 'none wrong'});"
              f" missed {len(lost)} of {len(ROBOT.elastic) + len(ROBOT.bent)}"
              f" ({', '.join(f'{e} {j}' for e, j in lost) or 'none'})")
    for f in d["findings"]:  # the tree's mass moments estimated (no inertias): the data against the prior
        said = f["where"].get("mass_prior") or {}
        if "determined_by_data" in said:
            bad = {**said["negative_masses_kg"], **said["centres_beyond_twice_length_m"]}
            names += (f"\n  mass moments: {said['determined_by_data']} of {len(said['posterior_std'])} combinations "
                      f"determined by the data beyond the prior; "
                      + ("physical" if said["physical"] else f"not physical at {', '.join(bad)}"))
    print(f"seed {seed}{' (no inertias)' if bare else ''}: held-out mean per hand, mm (left / right)\n"
          f"  elastic sag itself (rigid true robot vs elastic): {unmodelled['left']:.2f} / {unmodelled['right']:.2f}\n"
          f"  rigid calibration:     {rigid['left']:.2f} / {rigid['right']:.2f}\n"
          f"  after diagnose:        {after['left']:.2f} / {after['right']:.2f}\n"
          f"  true elastic model:    {floor['left']:.2f} / {floor['right']:.2f} (noise floor)\n"
          f"  findings: {names or 'none'}\n  calibrate {t1 - t0:.0f} s, diagnose {t2 - t1:.0f} s", flush=True)
    out = {"rigid": rigid, "after": after, "floor": floor, "places": len(places), "right": len(good),
           "missed": len(lost)}
    if n_later:
        rigid, after, floor, unmodelled = scores(root, cmd, np.arange(n_fit + n_held, len(cmd)), sim)
        out.update(later_rigid=rigid, later_after=after, later_floor=floor)
        print(f"  later session ({n_later} new poses, never seen by calibrate or diagnose), mm (left / right):\n"
              f"    elastic sag itself: {unmodelled['left']:.2f} / {unmodelled['right']:.2f}\n"
              f"    rigid calibration:  {rigid['left']:.2f} / {rigid['right']:.2f}\n"
              f"    after diagnose:     {after['left']:.2f} / {after['right']:.2f}\n"
              f"    true elastic model: {floor['left']:.2f} / {floor['right']:.2f} (noise floor)", flush=True)
    return out


def summary(results: list[dict]) -> str:
    """The goals over the seeds: places named right, the held-out error's median fall per hand,
    hands made worse; the same fall on the later session."""
    def falls(before: str, after: str) -> list[float]:
        return [1 - r[after][h] / r[before][h] for r in results if before in r for h in ROBOT.hands]

    right, places = sum(r["right"] for r in results), sum(r["places"] for r in results)
    down = falls("rigid", "after")
    text = (f"over {len(results)} seeds: places named right {right} of {places} ({100 * right / max(places, 1):.0f} %, "
            f"goal 90 %); held-out error down by a median of {100 * np.median(down):.1f} % per hand (goal 80 %), "
            f"{sum(d < 0 for d in down)} hands made worse")

    def excess(before: str, after: str, floor: str) -> list[float]:
        return [(r[before][h] - r[after][h]) / (r[before][h] - r[floor][h]) for r in results if before in r
                for h in ROBOT.hands]

    text += (f"; true places missed {sum(r['missed'] for r in results)}; the rigid error's excess over the noise "
             f"floor removed by a median of {100 * np.median(excess('rigid', 'after', 'floor')):.0f} % per hand")
    later = falls("later_rigid", "later_after")
    if later:
        text += (f"; later session: down by a median of {100 * np.median(later):.1f} % per hand, "
                 f"{sum(d < 0 for d in later)} hands made worse, excess over the floor removed by a median of "
                 f"{100 * np.median(excess('later_rigid', 'later_after', 'later_floor')):.0f} %")
    return text


def scores(root: Path, cmd: np.ndarray, rows: np.ndarray, sim) -> tuple[dict, dict, dict, dict]:
    """Per hand, the mean marker error (mm) at ``rows`` of the rigid calibration's prediction, of
    diagnose's, of the true elastic model (the noise floor), and of the rigid true robot."""
    rigid = per_hand(predicted(root / "cal" / "calibration.yaml", cmd[rows], sim.marker_names, root), sim.markers[rows], sim)
    after = per_hand(predicted(root / "diag" / "calibration.yaml", cmd[rows], sim.marker_names, root), sim.markers[rows], sim)
    floor = {h: float(np.mean([np.linalg.norm(1e3 * (sim.exact[rows, m] - sim.markers[rows, m]), axis=1)
                               for m, lk in enumerate(sim.marker_links) if lk == link])) for h, link in ROBOT.hands.items()}
    unmodelled = {h: float(np.mean([np.linalg.norm(1e3 * (sim.rigid[rows, m] - sim.exact[rows, m]), axis=1)
                                    for m, lk in enumerate(sim.marker_links) if lk == link])) for h, link in ROBOT.hands.items()}
    return rigid, after, floor, unmodelled


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[24001])
    ap.add_argument("--poses", type=int, default=300)
    ap.add_argument("--heldout", type=int, default=200)
    ap.add_argument("--bare", action="store_true", help="strip every inertia from the URDF the calibration sees")
    ap.add_argument("--later", type=int, default=0, metavar="N",
                    help="also predict a later session of N new poses of the same robot (its truth, markers and mocap)")
    ap.add_argument("--keep", default=None, help="keep each seed's sessions, calibrations and diagnosis under this folder")
    ap.add_argument("--robot", choices=sorted(ROBOTS_TABLE), default="talos", help="the public humanoid (default talos)")
    ap.add_argument("--compliance-scale", type=float, default=1.0, metavar="F",
                    help="every true compliance times F (below 1: a stiffer robot, a smaller sag)")
    args = ap.parse_args()
    global ROBOT
    ROBOT = ROBOTS_TABLE[args.robot]
    results = []
    for seed in args.seeds:
        if args.keep:
            root = Path(args.keep) / f"{args.robot}_seed{seed}{'_bare' if args.bare else ''}"
            root.mkdir(parents=True, exist_ok=True)
            results.append(run(seed, args.poses, args.heldout, args.bare, root, args.later, args.compliance_scale))
            continue
        with tempfile.TemporaryDirectory(prefix="platkit-trees-") as tmp:
            results.append(run(seed, args.poses, args.heldout, args.bare, Path(tmp), args.later, args.compliance_scale))
    print(summary(results))


if __name__ == "__main__":
    main()
