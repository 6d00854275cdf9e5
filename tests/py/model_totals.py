"""Totals OpenSim 4.6 computes for a model.

Usage: model_totals.py MODEL

Prints JSON: total_mass (kg, Model.getTotalMass), and for each coordinate
its range [min, max] and whether it is locked by default.
"""
import json
import sys

import opensim as osim

osim.Logger.setLevelString("error")
m = osim.Model(sys.argv[1])
s = m.initSystem()
coords = {}
cs = m.getCoordinateSet()
for i in range(cs.getSize()):
    c = cs.get(i)
    coords[c.getName()] = {
        "range": [c.getRangeMin(), c.getRangeMax()],
        "locked": bool(c.getDefaultLocked()),
    }
print(json.dumps({"total_mass": m.getTotalMass(s), "coordinates": coords}))
