#!/usr/bin/env python3
"""Build the offline FR3 MJCF that franka-sim loads through $FR3_MJCF.

Run with the franka-sim venv's python (it needs that venv's mujoco < 3.3):

    .venv-franka-sim/bin/python scripts/build_fr3_mjcf.py .venv-franka-sim/fr3_mjcf/fr3.xml

Recipe (background: docs/history/libfranka-notes.md):
1. take ``franka_sim/models/fr3.urdf`` from the installed franka-sim package;
2. delete every ``<visual>`` and ``<collision>`` element (their meshes are
   ``package://`` URIs that do not resolve offline);
3. load it with ``mujoco.MjModel.from_xml_path`` and save it with
   ``mujoco.mj_saveLastXML``;
4. add ``armature="0.195"`` to every joint of the saved MJCF. Without an
   armature franka-sim's own velocity servo is unstable (the idle arm spins
   joint 7 at tens of rad/s); 0.195 is the value of the Menagerie FR3 model
   franka-sim loads when it is online.

The output is written atomically (temporary file, then rename) and the script
checks the result: it loads, has the 7 hinge joints ``joint1..joint7``, and
every joint carries the armature.
"""

import argparse
import os
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

ARMATURE = 0.195
JOINTS = [f"joint{i}" for i in range(1, 8)]


def strip_urdf(urdf_text: str) -> str:
    """Return the URDF without its <visual> and <collision> elements."""
    root = ET.fromstring(urdf_text)
    removed = 0
    for parent in root.iter():
        for child in list(parent):
            if child.tag in ("visual", "collision"):
                parent.remove(child)
                removed += 1
    if removed == 0:
        raise RuntimeError("the URDF has no <visual>/<collision> elements: unexpected input")
    return ET.tostring(root, encoding="unicode")


def add_armature(mjcf_text: str, armature: float) -> str:
    """Set armature on every <joint> of an MJCF (worldbody joints and defaults alike)."""
    root = ET.fromstring(mjcf_text)
    count = 0
    for joint in root.iter("joint"):
        joint.set("armature", f"{armature:g}")
        count += 1
    if count == 0:
        raise RuntimeError("the saved MJCF has no <joint>: unexpected output of mj_saveLastXML")
    return ET.tostring(root, encoding="unicode")


def build(out: Path, armature: float = ARMATURE) -> None:
    import franka_sim
    import mujoco

    urdf = Path(franka_sim.__file__).resolve().parent / "models" / "fr3.urdf"
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=out.parent) as tmp:
        stripped = Path(tmp) / "fr3_stripped.urdf"
        stripped.write_text(strip_urdf(urdf.read_text(encoding="utf-8")), encoding="utf-8")
        model = mujoco.MjModel.from_xml_path(str(stripped))
        saved = Path(tmp) / "fr3_saved.xml"
        mujoco.mj_saveLastXML(str(saved), model)
        final = add_armature(saved.read_text(encoding="utf-8"), armature)
        candidate = Path(tmp) / "fr3.xml"
        candidate.write_text(final, encoding="utf-8")
        check(candidate, armature)
        os.replace(candidate, out)


def check(path: Path, armature: float) -> None:
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(path))
    names = [model.joint(i).name for i in range(model.njnt)]
    if names != JOINTS:
        raise RuntimeError(f"{path}: joints {names}, expected {JOINTS}")
    if any(abs(a - armature) > 1e-12 for a in model.dof_armature):
        raise RuntimeError(f"{path}: dof_armature {list(model.dof_armature)} != {armature}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="output MJCF path (e.g. .venv-franka-sim/fr3_mjcf/fr3.xml)")
    parser.add_argument("--armature", type=float, default=ARMATURE)
    args = parser.parse_args(argv)
    build(args.out, args.armature)
    print(f"[build_fr3_mjcf] wrote {args.out} (joints {JOINTS[0]}..{JOINTS[-1]}, armature {args.armature:g})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
