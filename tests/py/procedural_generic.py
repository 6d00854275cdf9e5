"""Load a generated procedural model in OpenSim 4.6 and report, at the
default pose: bodies, joints (class, parent, child), coordinates, every
body's ground transform (position + rotation matrix, row-major), and for
every muscle its class, path length, fibre length and optimal fibre length
(after equilibrateMuscles). Prints one JSON object."""
import json
import sys

import opensim as osim

osim.Logger.setLevelString("error")

path = sys.argv[1]
model = osim.Model(path)
state = model.initSystem()
model.equilibrateMuscles(state)
model.realizePosition(state)

out = {"bodies": {}, "joints": [], "muscles": [], "coordinates": []}
bs = model.getBodySet()
for i in range(bs.getSize()):
    b = bs.get(i)
    t = b.getTransformInGround(state)
    p = t.p()
    r = t.R()
    out["bodies"][b.getName()] = {
        "p": [p.get(k) for k in range(3)],
        "R": [[r.get(a, c) for c in range(3)] for a in range(3)],
        "mass": b.getMass(),
    }
js = model.getJointSet()
for i in range(js.getSize()):
    j = js.get(i)
    out["joints"].append({
        "name": j.getName(),
        "class": j.getConcreteClassName(),
        "parent": j.getParentFrame().findBaseFrame().getName(),
        "child": j.getChildFrame().findBaseFrame().getName(),
        "ncoords": j.numCoordinates(),
    })
cs = model.getCoordinateSet()
for i in range(cs.getSize()):
    out["coordinates"].append(cs.get(i).getName())
ms = model.getMuscles()
for i in range(ms.getSize()):
    m = ms.get(i)
    out["muscles"].append({
        "name": m.getName(),
        "class": m.getConcreteClassName(),
        "length": m.getLength(state),
        "fiber_length": m.getFiberLength(state),
        "optimal_fiber_length": m.getOptimalFiberLength(),
        "tendon_slack_length": m.getTendonSlackLength(),
        "max_isometric_force": m.getMaxIsometricForce(),
    })
print(json.dumps(out))
