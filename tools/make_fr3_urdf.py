#!/usr/bin/env python3
"""Write fabric/robot/urdf/fr3.urdf and its collision meshes from franka_description's FR3 (as franky-sim ships it).

The kinematics (every joint's origin and axis), the links' inertials and the collision meshes of links 0 to 7
are Franka Robotics' (https://github.com/frankarobotics/franka_description, Apache-2.0; franky-sim's
``assets/fr3_clean.urdf`` and ``assets/meshes/link*_coll.stl``). The joint limits are not the URDF's mechanical
ones but those Franka publishes for commanding the arm ("Limits for Franka Research 3",
https://frankarobotics.github.io/docs/control_parameters.html#limits-for-franka-research-3), written into the
cell file (fabric/cells/fr3.toml) with the velocity, acceleration and jerk limits. No hand: the extruder sits on
the flange (``link8``, 107 mm along axis 7), and the accelerometer frames are left out.

Run it where franky-sim is installed (``pip install -e '.[test]'`` brings it):
``python tools/make_fr3_urdf.py`` (it prints what it wrote).
"""
from __future__ import annotations

import shutil
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "fabric" / "robot" / "urdf"
LINKS = [f"link{i}" for i in range(8)]
HEADER = """<?xml version="1.0" ?>
<!-- Franka Research 3 (FR3): kinematics, inertials and collision meshes from Franka Robotics'
     franka_description (Apache-2.0, Copyright 2023 Franka Robotics GmbH), as franky-sim ships it; no hand
     (the extruder sits on the flange, link8). Written by tools/make_fr3_urdf.py: do not edit by hand.
     Joint limits here are the URDF's mechanical ones; the cell (fabric/cells/fr3.toml) commands the arm
     within Franka's published limits for the FR3. -->
"""


def main() -> int:
    try:
        import franky_sim
    except ImportError:
        print("franky-sim is not installed (pip install franky-sim)", file=sys.stderr)
        return 1
    assets = Path(franky_sim.__file__).parent / "assets"
    tree = ET.parse(assets / "fr3_clean.urdf")
    robot = tree.getroot()
    for el in list(robot):                      # the accelerometers' frames: not part of the arm's chain
        name = el.get("name", "")
        if "accelerometer" in name:
            robot.remove(el)
    meshes = OUT / "fr3"
    meshes.mkdir(parents=True, exist_ok=True)
    for link in robot.iter("link"):
        name = link.get("name")
        if name not in LINKS:
            continue
        shutil.copyfile(assets / "meshes" / f"{name}_coll.stl", meshes / f"{name}_coll.stl")
        coll = ET.SubElement(link, "collision", {"name": f"{name}_collision"})
        geom = ET.SubElement(coll, "geometry")
        ET.SubElement(geom, "mesh", {"filename": f"fr3/{name}_coll.stl"})
    ET.indent(tree, space="  ")
    text = HEADER + ET.tostring(robot, encoding="unicode") + "\n"
    (OUT / "fr3.urdf").write_text(text)
    (meshes / "NOTICE").write_text((assets / "NOTICE").read_text())
    print(f"wrote {OUT / 'fr3.urdf'} and {len(LINKS)} collision meshes in {meshes}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
