"""Stiffness of every BushingForce of a model, as OpenSim 4.6 reads it.

Usage: bushing_stiffness.py MODEL

Prints JSON {name: [rx, ry, rz, tx, ty, tz]} after initSystem() (so the
model must be valid for OpenSim, not just parse).
"""
import json
import sys

import opensim as osim

osim.Logger.setLevelString("error")
m = osim.Model(sys.argv[1])
m.initSystem()
out = {}
fs = m.getForceSet()
for i in range(fs.getSize()):
    f = fs.get(i)
    if f.getConcreteClassName() != "BushingForce":
        continue
    b = osim.BushingForce.safeDownCast(f)
    r = b.get_rotational_stiffness()
    t = b.get_translational_stiffness()
    out[b.getName()] = [r.get(k) for k in range(3)] + [t.get(k) for k in range(3)]
print(json.dumps(out))
