"""Writes the test URDFs beside this file: ur5e.urdf, iiwa14.urdf, panda_gripper.urdf.

Rigid bodies only (no geometry), built from the parameter tables below; each table names
its source. What a manufacturer does not publish is said where it is used, in the table's
comment and in the URDF's header. All numbers in SI units (m, rad, kg, kg m^2, s, N, N m).
Inertia tensors are (Ixx, Iyy, Izz, Ixy, Ixz, Iyz) about the centre of mass.

panda_gripper.urdf is the shipped Panda plus the Franka Hand's fingers, written by
engine/assets/generate_panda_urdf.py (its tables, its URDF helpers).

Run: python engine/tests/assets/generate_arm_urdfs.py
Check: .venv/bin/python engine/tests/assets/check_arm_urdfs.py (Pinocchio; MuJoCo if present)
"""

import sys
from math import cos, isclose, pi, radians, sin
from pathlib import Path

sys.dont_write_bytecode = True  # no __pycache__ in engine/assets
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "assets"))
from generate_panda_urdf import joint, link, panda_urdf, write_if_changed  # noqa: E402

HERE = Path(__file__).resolve().parent

# ---------------------------------------------------------------------------- UR5e
# Universal Robots, "DH Parameters for calculations of kinematics and dynamics" (support
# article, universal-robots.com), table "UR5e". Standard DH, one row per joint: (a, d, alpha);
# the frame of link i sits on joint i+1's axis and joint i turns about the previous z.
UR5E_DH = [
    (0.0, 0.1625, pi / 2),
    (-0.425, 0.0, 0.0),
    (-0.3922, 0.0, 0.0),
    (0.0, 0.1333, pi / 2),
    (0.0, 0.0997, -pi / 2),
    (0.0, 0.0996, 0.0),
]
# Same table, "Dynamics": mass and centre of mass of links 1..6, in their DH frames.
UR5E_MASS = [3.761, 8.058, 2.846, 1.37, 1.3, 0.365]
UR5E_COM = [
    (0.0, -0.02561, 0.00193),
    (0.2125, 0.0, 0.11336),
    (0.15, 0.0, 0.0265),
    (0.0, -0.0018, 0.01634),
    (0.0, 0.0018, 0.01634),
    (0.0, 0.0, -0.001159),
]
# NOT on UR's DH page, which publishes no UR5e inertia tensors ("negligible due to their
# smaller size"). These are the tensors Universal Robots ships in its ROS 2 description:
# Universal_Robots_ROS2_Description, config/ur5e/physical_parameters.yaml, inertia_parameters
# / tensor. They are about the CoM in the same DH frames (that file's `rotation` entries turn
# its ROS link frames into the DH frames); UR does not say how they were obtained.
UR5E_INERTIA = [
    (0.00700210, 0.00648091, 0.00657286, 0.00000073, -0.00001053, 0.00049994),
    (0.01505885, 0.33388086, 0.33247207, -0.00005400, 0.00000563, -0.00000181),
    (0.00399632, 0.07879254, 0.07848510, -0.00001365, 0.00137272, -0.00000660),
    (0.00165491, 0.00135962, 0.00126279, -0.00000282, -0.00000438, 0.00010157),
    (0.00135617, 0.00127827, 0.00096614, -0.00000274, 0.00000444, -0.00005048),
    (0.00018694, 0.00018908, 0.00025756, 0.00000006, -0.00000017, -0.00000092),
]
# Universal Robots, UR5e User Manual (e-Series, v5.8), technical specifications: every joint
# +-360 deg at 180 deg/s. Torques: UR support article "Max. joint torques" (size-3 joints
# 150 N m, size-1 wrists 28 N m). Both as cited by Universal_Robots_ROS2_Description,
# config/ur5e/joint_limits.yaml (which halves the elbow's range for planning; not here).
UR5E_Q_MAX = [2 * pi] * 6
UR5E_QD_MAX = [pi] * 6
UR5E_TAU_MAX = [150.0, 150.0, 150.0, 28.0, 28.0, 28.0]
UR5E_LINKS = ["shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link", "wrist_3_link"]
UR5E_JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]

# ------------------------------------------------------------------- LBR iiwa 14 R820
# KUKA, "LBR iiwa 7 R800, LBR iiwa 14 R820 Specification" (Spez LBR iiwa), dimensions of the
# iiwa 14: mounting face to A2 0.36 m, A2 to A4 0.42 m, A4 to A6 0.40 m, A6 to the flange
# 0.126 m; at q = 0 the arm stands straight up. KUKA gives no link frames: the joint origins
# (xyz, rpy from the parent link) split those lengths at the housings as Drake's iiwa14 model
# does (RobotLocomotion/drake, manipulation/models/iiwa_description/urdf/iiwa14.xacro), whose
# link frames the inertias below are written in. The assert below ties them to KUKA's lengths.
IIWA_LENGTHS = (0.36, 0.42, 0.40, 0.126)
IIWA_ORIGINS = [
    ((0.0, 0.0, 0.1575), (0.0, 0.0, 0.0)),
    ((0.0, 0.0, 0.2025), (pi / 2, 0.0, pi)),
    ((0.0, 0.2045, 0.0), (pi / 2, 0.0, pi)),
    ((0.0, 0.0, 0.2155), (pi / 2, 0.0, 0.0)),
    ((0.0, 0.1845, 0.0), (-pi / 2, pi, 0.0)),
    ((0.0, 0.0, 0.2155), (pi / 2, 0.0, 0.0)),
    ((0.0, 0.081, 0.0), (-pi / 2, pi, 0.0)),
]
IIWA_FLANGE = (0.0, 0.0, 0.045)  # link 7 to the media flange
# NOT published by KUKA (its specification gives the total mass only). Mass, CoM and diagonal
# inertia of links 1..7 are Drake's (iiwa14.xacro above, inherited from IFL-CAMP iiwa_stack):
# a widely used but NOT identified set; Drake's own comments note its masses of links 2-7 were
# raised above KUKA's CAD values. (Stuerz, Affolter & Smith, IFAC 2017 identify a set, but the
# public transcriptions of it disagree with each other, so it is not used.)
IIWA_MASS = [5.76, 6.35, 3.5, 3.5, 3.5, 1.8, 1.2]
IIWA_COM = [
    (0.0, -0.03, 0.12),
    (0.0003, 0.059, 0.042),
    (0.0, 0.03, 0.13),
    (0.0, 0.067, 0.034),
    (0.0001, 0.021, 0.076),
    (0.0, 0.0006, 0.0004),
    (0.0, 0.0, 0.02),
]
IIWA_INERTIA = [
    (0.033, 0.0333, 0.0123, 0.0, 0.0, 0.0),
    (0.0305, 0.0304, 0.011, 0.0, 0.0, 0.0),
    (0.025, 0.0238, 0.0076, 0.0, 0.0, 0.0),
    (0.017, 0.0164, 0.006, 0.0, 0.0, 0.0),
    (0.01, 0.0087, 0.00449, 0.0, 0.0, 0.0),
    (0.0049, 0.0047, 0.0036, 0.0, 0.0, 0.0),
    (0.001, 0.001, 0.001, 0.0, 0.0, 0.0),
]
# KUKA, same specification, axis data of the LBR iiwa 14 R820 (also KUKA's brochure "Sensitive
# robotics LBR iiwa", p. 30; as quoted in Drake's iiwa_description/README.md): range, speed,
# maximum torque of A1..A7.
IIWA_Q_MAX = [radians(d) for d in (170, 120, 170, 120, 170, 120, 175)]
IIWA_QD_MAX = [radians(d) for d in (85, 85, 100, 75, 130, 135, 135)]
IIWA_TAU_MAX = [320.0, 320.0, 176.0, 176.0, 110.0, 40.0, 40.0]


def header(name, notes):
    lines = [
        '<?xml version="1.0"?>\n',
        "<!-- Generated by engine/tests/assets/generate_arm_urdfs.py; do not edit. -->\n",
    ]
    lines += [f"<!-- {note} -->\n" for note in notes]
    return lines + [f'<robot name="{name}">\n']


def dh_fixed_part(a, d, alpha):
    """TransZ(d) TransX(a) RotX(alpha), the part of a standard-DH row after the joint's
    rotation, as URDF xyz / rpy."""
    return (a, 0.0, d), (alpha, 0.0, 0.0)


def ur5e_urdf():
    # URDF turns a joint after its origin, standard DH before its offsets: so link i's URDF
    # frame is DH frame i-1 turned by q_i, and each joint's origin is the previous row's
    # fixed part. The CoM and tensor of link i (given in DH frame i) are placed with that row's
    # fixed part: CoM at (a, 0, d) + RotX(alpha) c, tensor axes rotated by alpha about x.
    parts = header("ur5e", [
        "UR5e. Kinematics, masses, CoMs: Universal Robots' DH parameter page (table UR5e).",
        "Inertia tensors: not on that page; from Universal Robots' ROS 2 description",
        "(config/ur5e/physical_parameters.yaml), origin undocumented by UR.",
        "Limits: UR5e user manual (+-360 deg, 180 deg/s) and UR 'Max. joint torques'.",
        "base = UR's base frame (DH frame 0), turned by pi about z from base_link as in ROS.",
        "flange = DH frame 6, carrying wrist 3's mass (lumped onto wrist_3_link); tool0 = flange.",
        "The UR base's own mass is not published and is left out (it is fixed to the world).",
    ])
    parts.append(link("base_link"))
    parts.append(link("base"))
    parts.append(joint("base_link-base_fixed_joint", "fixed", "base_link", "base", (0.0, 0.0, 0.0), (0.0, 0.0, pi)))
    parent, origin = "base", ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    for i, (a, d, alpha) in enumerate(UR5E_DH):
        inertial = None
        if i < 5:  # wrist 3's inertia sits on the flange, i.e. in its own DH frame
            c = UR5E_COM[i]
            com = (a + c[0], cos(alpha) * c[1] - sin(alpha) * c[2], d + sin(alpha) * c[1] + cos(alpha) * c[2])
            inertial = (UR5E_MASS[i], com, UR5E_INERTIA[i], (alpha, 0.0, 0.0))
        limit = (-UR5E_Q_MAX[i], UR5E_Q_MAX[i], UR5E_QD_MAX[i], UR5E_TAU_MAX[i])
        parts.append(link(UR5E_LINKS[i], inertial))
        parts.append(joint(UR5E_JOINTS[i], "revolute", parent, UR5E_LINKS[i], *origin, limit))
        parent, origin = UR5E_LINKS[i], dh_fixed_part(a, d, alpha)
    parts.append(link("flange", (UR5E_MASS[5], UR5E_COM[5], UR5E_INERTIA[5])))
    parts.append(joint("wrist_3-flange", "fixed", "wrist_3_link", "flange", *origin))
    parts.append(link("tool0"))
    parts.append(joint("flange-tool0", "fixed", "flange", "tool0", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0)))
    return "".join(parts) + "</robot>\n"


def iiwa14_urdf():
    segments = [(0, 1), (2, 3), (4, 5)]  # joint origins spanning KUKA's 0.36 / 0.42 / 0.40 m
    for length, (j, k) in zip(IIWA_LENGTHS, segments):
        assert isclose(sum(IIWA_ORIGINS[j][0]) + sum(IIWA_ORIGINS[k][0]), length)
    assert isclose(sum(IIWA_ORIGINS[6][0]) + IIWA_FLANGE[2], IIWA_LENGTHS[3])
    parts = header("iiwa14", [
        "KUKA LBR iiwa 14 R820. Lengths (0.36/0.42/0.40/0.126 m), ranges, speeds, torques:",
        "KUKA's LBR iiwa specification. Link frames: Drake's iiwa14 model (same lengths).",
        "Masses, CoMs, inertias: NOT published by KUKA; Drake's iiwa14 values (diagonal",
        "tensors, masses raised above KUKA CAD values by Drake): plausible, not identified.",
        "iiwa_link_ee = the media flange, 0.126 m beyond A6.",
    ])
    parts.append(link("iiwa_link_0"))
    for i, (xyz, rpy) in enumerate(IIWA_ORIGINS):
        limit = (-IIWA_Q_MAX[i], IIWA_Q_MAX[i], IIWA_QD_MAX[i], IIWA_TAU_MAX[i])
        parts.append(link(f"iiwa_link_{i + 1}", (IIWA_MASS[i], IIWA_COM[i], IIWA_INERTIA[i])))
        parts.append(joint(f"iiwa_joint_{i + 1}", "revolute", f"iiwa_link_{i}", f"iiwa_link_{i + 1}", xyz, rpy, limit))
    parts.append(link("iiwa_link_ee"))
    parts.append(joint("iiwa_joint_ee", "fixed", "iiwa_link_7", "iiwa_link_ee", IIWA_FLANGE, (0.0, 0.0, 0.0)))
    return "".join(parts) + "</robot>\n"


def main():
    write_if_changed(HERE / "ur5e.urdf", ur5e_urdf())
    write_if_changed(HERE / "iiwa14.urdf", iiwa14_urdf())
    write_if_changed(HERE / "panda_gripper.urdf", panda_urdf(fingers=True))


if __name__ == "__main__":
    main()
