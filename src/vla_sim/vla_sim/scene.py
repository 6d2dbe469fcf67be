"""Construction of the MuJoCo scene: example-robot-data's Panda URDF (the file Pinocchio loads) with
its two fingers (coupled by the URDF's mimic joint, driven by one force-limited servo on their gap:
hand.py), a table whose top is z = 0, lights, a fixed webcam-like camera and the five
objects on free joints, plus the joint servos that turn velocity commands into position targets.

Pure model building (MjSpec); the simulator itself lives in `sim.py`.
"""
from __future__ import annotations

import math
import os
import re

import mujoco
import numpy as np
from vla_common.camera_model import SIM_WEBCAM
from vla_common.catalogue import Catalogue, ObjectSpec, default_catalogue
from vla_common.kinematics import FINGER_JOINTS, panda_description_dir, panda_urdf_path
from vla_common.layout import TABLE_X, TABLE_Y
from vla_common.robot import HAND, JOINT_NAMES, TAU_MAX

# Table: the robot is mounted on the table top (z = 0) at the origin, x away from the robot.
TABLE_THICKNESS = 0.04
FLOOR_Z = -0.75

# The fixed camera (vla_common.camera_model.SIM_WEBCAM gives its pose and field of view).
CAMERA_NAME = "webcam"
MAX_OFFSCREEN = (1920, 1440)

TCP_SITE = "tcp"
OBJECT_BODY_PREFIX = "obj_"
# Where objects that are not in the current layout wait: far behind the camera, out of view,
# floating (gravity compensated, no contacts) so they cost nothing and never move.
PARK_X = 4.0

# Joint drives: one torque motor per joint, set every physics step by the joint servo in sim.py (a
# computed-torque position servo on the integrated command, its acceleration limited to the Panda's
# table); total joint torque clipped to TAU_MAX; gravity compensated through the actuators.
JOINT_ARMATURE = np.array([0.3, 0.3, 0.3, 0.3, 0.1, 0.1, 0.1])
ROBOT_FRICTION = 0.3
MOTOR_PREFIX = "motor_"
TABLE_FRICTION = 0.3

# The hand: a tendon whose length is the gap between the fingers, and a position servo on it whose
# force (on each finger) the simulator limits to the commanded grasp force (vla_sim.hand.SimHand).
HAND_TENDON = "hand_width"
HAND_ACTUATOR = "hand"
HAND_KP = 3000.0                 # N/m: 1 cm short of the target pushes with 30 N (then force-limited)
FINGER_ARMATURE = 0.05
FINGER_DAMPING = 20.0            # N s/m: the finger servo critically damped (no ringing)
# Contacts: elliptic friction cones with a high impedance ratio, so that a squeezed object does not
# creep out of the grasp (pyramidal cones let a held can slide 1.4 cm in 2 s; these 0.7 mm).
CONTACT_IMPRATIO = 10.0
FINGER_BODIES = ("panda_leftfinger", "panda_rightfinger")
FINGER_MASS = 1e-6               # kg: see _add_hand
FINGER_LIMIT_TIMECONST = 0.004   # s: stiff finger stops (MuJoCo keeps it >= 2 physics steps)

# Collision bits: robot (1) hits table and objects but not itself; objects (2) hit everything.
_ROBOT_CT, _ROBOT_CA = 1, 0
_TABLE_CT, _TABLE_CA = 2, 1
_OBJ_CT, _OBJ_CA = 2, 3

_LINK_RGBA = {
    "panda_link0": (0.92, 0.92, 0.92, 1.0),
    "panda_link7": (0.25, 0.25, 0.27, 1.0),
    "panda_hand": (0.92, 0.92, 0.92, 1.0),
    "panda_leftfinger": (0.20, 0.20, 0.22, 1.0),
    "panda_rightfinger": (0.20, 0.20, 0.22, 1.0),
}
_DEFAULT_LINK_RGBA = (0.95, 0.95, 0.95, 1.0)


def mujoco_urdf_text() -> str:
    """The Panda URDF rewritten for MuJoCo's importer: STL collision meshes by absolute path (the
    .dae visuals are unreadable), static bodies kept (the TCP frame). The finger joints stay
    prismatic; the importer turns their mimic into an equality constraint (they move together)."""
    with open(panda_urdf_path()) as f:
        text = f.read()
    mesh_dir = os.path.join(panda_description_dir(), "meshes", "collision")
    text = re.sub(r'filename="[^"]*/meshes/(?:visual|collision)/(\w+)\.(?:dae|stl)"',
                  lambda m: f'filename="{os.path.join(mesh_dir, m.group(1) + ".stl")}"', text)
    for joint in FINGER_JOINTS:
        if not re.search(rf'<joint\s+name="{joint}"\s+type="prismatic"', text):
            raise ValueError(f"no prismatic finger joint {joint} in the Panda URDF")
    compiler = ('<mujoco><compiler fusestatic="false" discardvisual="true" strippath="false" '
                'balanceinertia="true"/></mujoco>')
    text, n = re.subn(r"(<robot\b[^>]*>)", r"\1" + compiler, text, count=1)
    if n != 1:
        raise ValueError("no <robot> element in the Panda URDF")
    return text


def look_at_quat(pos, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(w, x, y, z) quaternion of a MuJoCo camera at `pos` looking at `target` (camera -z forward)."""
    f = np.asarray(target, float) - np.asarray(pos, float)
    f /= np.linalg.norm(f)
    x = np.cross(f, np.asarray(up, float))
    x /= np.linalg.norm(x)
    y = np.cross(x, f)
    mat = np.column_stack([x, y, -f])
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, mat.reshape(-1))
    return quat


def _box_inertia(mass: float, sx: float, sy: float, sz: float) -> list[float]:
    return [mass / 12.0 * (sy * sy + sz * sz), mass / 12.0 * (sx * sx + sz * sz),
            mass / 12.0 * (sx * sx + sy * sy)]


def _cyl_inertia(mass: float, r: float, h: float) -> list[float]:
    i = mass / 12.0 * (3 * r * r + h * h)
    return [i, i, 0.5 * mass * r * r]


def _add_geom(body, name, gtype, size, rgba, pos=(0, 0, 0), collide=True, friction=0.5):
    g = body.add_geom()
    g.name = name
    g.type = gtype
    g.size = list(size) + [0.0] * (3 - len(size))
    g.pos = list(pos)
    g.rgba = list(rgba)
    if collide:
        g.contype, g.conaffinity = _OBJ_CT, _OBJ_CA
        g.friction = [friction, 0.005, 0.0001]
    else:
        g.contype, g.conaffinity = 0, 0
        g.group = 1
    return g


def _add_object(world, class_id: str, spec: ObjectSpec, park_pos) -> None:
    """One object: a body on a free joint with the bounding shape's inertia, a collision geom of
    that shape and visual-only accents (the catalogue's `style`) that make classes easy to tell apart."""
    body = world.add_body()
    body.name = OBJECT_BODY_PREFIX + class_id
    body.pos = list(park_pos)
    body.explicitinertial = True
    body.ipos = [0.0, 0.0, 0.0]
    body.iquat = [1.0, 0.0, 0.0, 0.0]
    body.mass = spec.mass
    sx, sy, sz = spec.size
    body.inertia = (_box_inertia(spec.mass, sx, sy, sz) if spec.shape == "box"
                    else _cyl_inertia(spec.mass, sx, sz))
    fj = body.add_freejoint()
    fj.name = body.name + "_joint"
    style = spec.style if spec.style in _STYLES else ("band" if spec.shape == "box" else "rims")
    _STYLES[style](body, body.name, spec)


_BOX, _CYL = mujoco.mjtGeom.mjGEOM_BOX, mujoco.mjtGeom.mjGEOM_CYLINDER


def _loaf(body, n: str, spec: ObjectSpec) -> None:
    sx, sy, sz = spec.size
    _add_geom(body, n, _BOX, (sx / 2, sy / 2, sz / 2), spec.rgba, friction=spec.friction)
    _add_geom(body, n + "_crust", _BOX, (sx / 2 - 0.008, sy / 2 - 0.008, 0.006), _accent(spec),
              pos=(0, 0, sz / 2), collide=False)


def _rims(body, n: str, spec: ObjectSpec) -> None:
    sx, _, sz = spec.size
    _add_geom(body, n, _CYL, (sx, sz / 2), spec.rgba, friction=spec.friction)
    for k, zz in enumerate((sz / 2, -sz / 2)):
        _add_geom(body, f"{n}_rim{k}", _CYL, (sx - 0.004, 0.004), _accent(spec), pos=(0, 0, zz),
                  collide=False)


def _band(body, n: str, spec: ObjectSpec) -> None:
    sx, sy, sz = spec.size
    _add_geom(body, n, _BOX, (sx / 2, sy / 2, sz / 2), spec.rgba, friction=spec.friction)
    _add_geom(body, n + "_band", _BOX, (sx / 2 + 0.001, sy / 2 + 0.001, min(0.035, sz / 4)), _accent(spec),
              pos=(0, 0, 0.01 if sz > 0.1 else 0.0), collide=False)


def _carton(body, n: str, spec: ObjectSpec) -> None:
    _band(body, n, spec)
    _add_geom(body, n + "_cap", _CYL, (0.012, 0.008), _accent(spec),
              pos=(0.0, 0.0, spec.size[2] / 2 + 0.006),
              collide=False)


def _bottle(body, n: str, spec: ObjectSpec) -> None:
    sx, _, sz = spec.size
    body_h = 0.65 * sz
    _add_geom(body, n, _CYL, (sx, body_h / 2), spec.rgba, pos=(0, 0, -sz / 2 + body_h / 2),
              friction=spec.friction)
    neck_h = sz - body_h
    _add_geom(body, n + "_neck", _CYL, (0.013, neck_h / 2), _accent(spec),
              pos=(0, 0, sz / 2 - neck_h / 2), friction=spec.friction)
    _add_geom(body, n + "_shoulder", mujoco.mjtGeom.mjGEOM_ELLIPSOID, (sx, sx, 0.03), spec.rgba,
              pos=(0, 0, -sz / 2 + body_h), collide=False)


def _labels(body, n: str, spec: ObjectSpec) -> None:
    sx, sy, sz = spec.size
    _add_geom(body, n, _BOX, (sx / 2, sy / 2, sz / 2), spec.rgba, friction=spec.friction)
    for k, yy in enumerate((sy / 2, -sy / 2)):
        _add_geom(body, f"{n}_label{k}", _BOX, (sx / 2 - 0.02, 0.001, sz / 4), _accent(spec),
                  pos=(0, yy, 0.02), collide=False)


def _accent(spec: ObjectSpec):
    return spec.accent_rgba or spec.rgba


# Visual styles a catalogue entry may name (`style:`); boxes default to a band, cylinders to rims.
_STYLES = {"loaf": _loaf, "rims": _rims, "band": _band, "carton": _carton, "bottle": _bottle,
           "labels": _labels}
STYLES = tuple(_STYLES)


def park_position(index: int) -> tuple[float, float, float]:
    """Out-of-view resting place of the catalogue's `index`-th object when it is not in the layout."""
    return (PARK_X, -1.0 + 0.5 * index, 0.5)


def _add_hand(spec: mujoco.MjSpec) -> None:
    """The fingers' drive: a tendon (joint1 + joint2 = the gap) and a force-limited position servo.
    The fingers' mass moves to the hand: light fingers on their own joints would couple into the
    arm's computed-torque servo (M's arm-finger terms), 1e-4 of ddq_max past the table; the drive's
    reflected inertia (armature) is what their joints feel."""
    hand = spec.body("panda_hand")
    hand.explicitinertial = True
    for body_name in FINGER_BODIES:
        finger = spec.body(body_name)
        hand.mass += finger.mass
        finger.explicitinertial = True
        finger.mass = FINGER_MASS
        finger.fullinertia = [FINGER_MASS * 1e-4] * 3 + [0.0] * 3
    for name in FINGER_JOINTS:
        j = spec.joint(name)
        j.armature = FINGER_ARMATURE
        j.damping = [FINGER_DAMPING, 0.0, 0.0]
        j.range = [0.0, HAND.max_width / 2]
        j.solref_limit = [FINGER_LIMIT_TIMECONST, 1.0]   # closed fingers stop at 0, not 6 mm past it
        j.solimp_limit = [0.95, 0.99, 0.001, 0.5, 2.0]
    tendon = spec.add_tendon()
    tendon.name = HAND_TENDON
    for name in FINGER_JOINTS:
        tendon.wrap_joint(name, 1.0)
    a = spec.add_actuator()
    a.name = HAND_ACTUATOR
    a.target = HAND_TENDON
    a.trntype = mujoco.mjtTrn.mjTRN_TENDON
    a.set_to_position(kp=HAND_KP, kv=0.0)
    a.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
    a.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    a.forcerange = [-HAND.max_force, HAND.max_force]


def build_spec(physics_dt: float = 0.002, catalogue: Catalogue | None = None) -> mujoco.MjSpec:
    """The whole scene as an MjSpec (compile with `.compile()`), with every object of the catalogue."""
    spec = mujoco.MjSpec.from_string(mujoco_urdf_text())
    spec.modelname = "vla_panda_scene"
    spec.compiler.discardvisual = False  # the URDF's visuals were dropped at parse time; keep ours
    spec.option.timestep = physics_dt
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = CONTACT_IMPRATIO
    spec.visual.global_.offwidth, spec.visual.global_.offheight = MAX_OFFSCREEN
    spec.visual.quality.shadowsize = 0
    spec.visual.quality.offsamples = 0  # no multisampling: 4x MSAA costs ~4x per frame on Mesa (CPU)
    spec.visual.headlight.ambient = [0.25, 0.25, 0.25]
    spec.visual.headlight.diffuse = [0.30, 0.30, 0.30]
    spec.visual.headlight.specular = [0.05, 0.05, 0.05]

    # Robot: colours, collision bits, friction, gravity compensation, servo-friendly armature.
    for body in spec.bodies:
        if body.name.startswith("panda_"):
            body.gravcomp = 1.0
    for geom in spec.geoms:
        parent = geom.parent.name
        geom.rgba = list(_LINK_RGBA.get(parent, _DEFAULT_LINK_RGBA))
        geom.contype, geom.conaffinity = _ROBOT_CT, _ROBOT_CA
        geom.friction = [ROBOT_FRICTION, 0.005, 0.0001]
    for i, name in enumerate(JOINT_NAMES):
        j = spec.joint(name)
        j.armature = float(JOINT_ARMATURE[i])
        j.damping = [0.0, 0.0, 0.0]  # the servo models the drive (not the URDF's 0.003); see teaching
        j.actgravcomp = True
        j.actfrclimited = mujoco.mjtLimited.mjLIMITED_TRUE
        j.actfrcrange = [-float(TAU_MAX[i]), float(TAU_MAX[i])]
    _add_hand(spec)
    tcp_body = spec.body("panda_hand_tcp")
    site = tcp_body.add_site()
    site.name = TCP_SITE
    site.size = [0.005, 0.005, 0.005]
    site.rgba = [1.0, 0.2, 0.2, 0.0]

    for name in JOINT_NAMES:
        a = spec.add_actuator()
        a.name = MOTOR_PREFIX + name
        a.target = name
        a.trntype = mujoco.mjtTrn.mjTRN_JOINT
        a.set_to_motor()  # torque = ctrl; the joint's actfrcrange clips it with the gravity compensation

    world = spec.worldbody
    floor = world.add_geom()
    floor.name = "floor"
    floor.type = mujoco.mjtGeom.mjGEOM_PLANE
    floor.size = [6.0, 6.0, 3.0]  # 3rd value: rendering grid spacing; a fine grid costs ~5 ms a frame
    floor.pos = [0.0, 0.0, FLOOR_Z]
    floor.rgba = [0.42, 0.44, 0.47, 1.0]
    floor.contype, floor.conaffinity = _TABLE_CT, _TABLE_CA
    table = world.add_body()
    table.name = "table"
    top = table.add_geom()
    top.name = "table_top"
    top.type = mujoco.mjtGeom.mjGEOM_BOX
    top.size = [(TABLE_X[1] - TABLE_X[0]) / 2, (TABLE_Y[1] - TABLE_Y[0]) / 2, TABLE_THICKNESS / 2]
    top.pos = [(TABLE_X[0] + TABLE_X[1]) / 2, (TABLE_Y[0] + TABLE_Y[1]) / 2, -TABLE_THICKNESS / 2]
    top.rgba = [0.62, 0.50, 0.36, 1.0]
    top.contype, top.conaffinity = _TABLE_CT, _TABLE_CA
    top.friction = [TABLE_FRICTION, 0.005, 0.0001]
    leg_h = -FLOOR_Z - TABLE_THICKNESS
    corners = [(x, y) for x in (TABLE_X[0] + 0.05, TABLE_X[1] - 0.05)
               for y in (TABLE_Y[0] + 0.05, TABLE_Y[1] - 0.05)]
    for k, (lx, ly) in enumerate(corners):
        leg = table.add_geom()
        leg.name = f"table_leg{k}"
        leg.type = mujoco.mjtGeom.mjGEOM_BOX
        leg.size = [0.03, 0.03, leg_h / 2]
        leg.pos = [lx, ly, -TABLE_THICKNESS - leg_h / 2]
        leg.rgba = [0.55, 0.45, 0.33, 1.0]
        leg.contype, leg.conaffinity = 0, 0

    for pos, diffuse in (((0.4, 0.0, 2.5), 0.45), ((1.5, 1.0, 2.0), 0.2)):
        light = world.add_light()
        light.pos = list(pos)
        to_table = np.array([0.4, 0.0, 0.0]) - np.array(pos)
        light.dir = list(to_table / np.linalg.norm(to_table))
        light.diffuse = [diffuse] * 3
        light.specular = [0.1] * 3
        light.castshadow = False
        light.type = mujoco.mjtLightType.mjLIGHT_DIRECTIONAL

    cam = world.add_camera()
    cam.name = CAMERA_NAME
    cam.pos = list(SIM_WEBCAM.position)
    cam.quat = list(look_at_quat(SIM_WEBCAM.position, SIM_WEBCAM.look_at))
    cam.fovy = SIM_WEBCAM.fovy_deg

    cat = catalogue or default_catalogue()
    for i, (class_id, obj) in enumerate(cat.objects.items()):
        _add_object(world, class_id, obj, park_position(i))
    return spec


def build_model(physics_dt: float = 0.002, catalogue: Catalogue | None = None) -> mujoco.MjModel:
    """Compiled scene model."""
    if not (math.isfinite(physics_dt) and 1e-4 <= physics_dt <= 0.01):
        raise ValueError(f"physics_dt must be in [0.0001, 0.01] s, got {physics_dt}")
    return build_spec(physics_dt, catalogue).compile()
