"""Write tests/data/published/specimen.osim: the project's own base model
(base_model/base.osim, built by `osim-spine base --procedural`) cut to the
passive thoracolumbar specimen a published in-vitro table describes: pelvis,
sacrum, lumbar5 .. lumbar1 and thoracic12, their joints and intervertebral
BushingForces; no muscles, markers, wrap objects or meshes.

Every intervertebral joint frame is turned onto the ground axes (the
lordosis is taken out): a published table gives each level's rotation about
its own anatomical axes under the applied moment, while the experiment
format's rotations are components on the ground axes; the two agree only
when every level's anatomical axes are the load axes.

Usage (from the repository root): python3 tests/data/published/make_specimen.py
"""
import xml.etree.ElementTree as ET
from pathlib import Path

KEEP_BODIES = ["pelvis", "sacrum", "lumbar5", "lumbar4", "lumbar3", "lumbar2",
               "lumbar1", "thoracic12"]
KEEP_JOINTS = ["ground_pelvis", "sacral", "L5_S1_IVDjnt", "L4_L5_IVDjnt",
               "L3_L4_IVDjnt", "L2_L3_IVDjnt", "L1_L2_IVDjnt", "T12_L1_IVDjnt"]
KEEP_FORCES = [j.replace("_IVDjnt", "_bushing") for j in KEEP_JOINTS[2:]]

root_dir = Path(__file__).resolve().parents[3]
tree = ET.parse(root_dir / "base_model" / "base.osim")
model = tree.getroot().find("Model")
model.set("name", "published_table_specimen_T12_S1")


def keep_only(set_tag, names):
    objects = model.find(set_tag).find("objects")
    for child in list(objects):
        if child.get("name") not in names:
            objects.remove(child)


keep_only("BodySet", KEEP_BODIES)
keep_only("JointSet", KEEP_JOINTS)
keep_only("ForceSet", KEEP_FORCES)
keep_only("MarkerSet", [])
for body in model.find("BodySet").find("objects"):
    for tag in ("attached_geometry", "WrapObjectSet"):
        for e in body.findall(tag):
            body.remove(e)
for joint in model.find("JointSet").find("objects"):
    if joint.get("name").endswith("_IVDjnt"):
        for frame in joint.iter("PhysicalOffsetFrame"):
            frame.find("orientation").text = "0 0 0"
for e in model.iter():
    for tag in ("attached_geometry",):
        for g in e.findall(tag):
            e.remove(g)
ET.indent(tree, space="\t")
out = Path(__file__).resolve().parent / "specimen.osim"
tree.write(out, encoding="UTF-8", xml_declaration=True)
print(f"wrote {out}")
