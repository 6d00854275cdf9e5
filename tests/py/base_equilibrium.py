"""OpenSim 4.6 static equilibrium of a base model under gravity, started
from the tool's equilibrium, to compare the two.

Usage: base_equilibrium.py BASE.osim REPORT.json

Muscles are switched off (the tool's solver applies no muscle force).
Newton on OpenSim's inverse-dynamics residual tau(q) (generalised forces
needed for zero accelerations at zero speed; equilibrium is tau = 0) with
a central finite-difference Jacobian, starting from the coordinates of
REPORT.json's self_check.equilibrium. Prints JSON: the residual at the
tool's solution, OpenSim's converged coordinates, and the largest
difference between the two (rad or m).
"""
import json
import sys

import numpy as np
import opensim as osim

osim.Logger.setLevelString("error")


def main():
    path, rep = sys.argv[1], sys.argv[2]
    tool = json.load(open(rep))["self_check"]["equilibrium"]["coordinates"]
    m = osim.Model(path)
    fs = m.getForceSet()
    for i in range(fs.getSize()):
        mu = osim.Muscle.safeDownCast(fs.get(i))
        if mu is not None:
            mu.set_appliesForce(False)
    s = m.initSystem()
    cs = m.getCoordinateSet()
    names = [cs.get(i).getName() for i in range(cs.getSize())]
    for n in names:
        cs.get(n).setValue(s, tool[n], False)
    nq = s.getNQ()
    ids = osim.InverseDynamicsSolver(m)
    udot = osim.Vector(s.getNU(), 0.0)

    def tau(q):
        for k in range(nq):
            s.updQ().set(k, float(q[k]))
        s.setU(osim.Vector(s.getNU(), 0.0))
        m.realizeVelocity(s)
        t = ids.solve(s, udot)
        return np.array([t.get(k) for k in range(t.size())])

    q = np.array([s.getQ().get(k) for k in range(nq)])
    r0 = tau(q)
    res0 = float(np.max(np.abs(r0)))
    for _ in range(8):
        r = tau(q)
        if np.max(np.abs(r)) < 1e-9:
            break
        h = 1e-7
        J = np.zeros((len(r), nq))
        for k in range(nq):
            e = np.zeros(nq)
            e[k] = h
            J[:, k] = (tau(q + e) - tau(q - e)) / (2 * h)
        q = q - np.linalg.solve(J, r)
    r = tau(q)
    osim_coords = {n: cs.get(n).getValue(s) for n in names}
    diff = max(abs(osim_coords[n] - tool[n]) for n in names)
    print(json.dumps({
        "residual_at_tool_solution": res0,
        "residual_final": float(np.max(np.abs(r))),
        "max_coordinate_difference": diff,
        "coordinates": osim_coords,
    }))


main()
