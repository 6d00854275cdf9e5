"""Pose a spine model in OpenSim 4.6 and read back its markers and
vertebral centres (ground frame, metres).

Usage: pose_spine.py MODEL.osim POSE.json

POSE.json maps coordinate names to values added to their defaults
(radians or metres). Prints JSON:
{"markers": {name: [x, y, z]}, "centres": {level: [x, y, z]},
 "bodies": {name: [x, y, z]}}
where a level's centre is the centre of the WrapSphere `<LEVEL>_body_sphere`
placed by OpenSim (findStationLocationInGround of the sphere's translation).
"""
import json
import sys

import opensim as osim

osim.Logger.setLevelString("error")


def vec(v):
    return [v.get(0), v.get(1), v.get(2)]


def main():
    model = osim.Model(sys.argv[1])
    with open(sys.argv[2]) as f:
        pose = json.load(f)
    s = model.initSystem()
    cs = model.getCoordinateSet()
    for name, value in pose.items():
        c = cs.get(name)
        c.setValue(s, c.getDefaultValue() + value, False)
    model.realizePosition(s)
    out = {"markers": {}, "centres": {}, "bodies": {}}
    ms = model.getMarkerSet()
    for i in range(ms.getSize()):
        m = ms.get(i)
        out["markers"][m.getName()] = vec(m.getLocationInGround(s))
    bs = model.getBodySet()
    for i in range(bs.getSize()):
        b = bs.get(i)
        out["bodies"][b.getName()] = vec(b.getPositionInGround(s))
        ws = b.getWrapObjectSet()
        for k in range(ws.getSize()):
            w = osim.WrapSphere.safeDownCast(ws.get(k))
            if w is None or not w.getName().endswith("_body_sphere"):
                continue
            level = w.getName()[: -len("_body_sphere")]
            out["centres"][level] = vec(b.findStationLocationInGround(s, w.get_translation()))
    print(json.dumps(out))


main()
