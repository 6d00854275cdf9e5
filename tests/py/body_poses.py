#!/usr/bin/env python3
"""Body poses in ground computed by OpenSim 4.6 for random coordinate states.

usage: body_poses.py MODEL N_STATES SEED

Every coordinate (locked ones unlocked in the state) gets an independent random value:
rotational uniform in [-1, 1] rad, translational in [-0.05, 0.05] m (ranges
ignored, constraints not enforced: pure forward kinematics X_GB(q)).
Prints JSON: {"states": [{"q": {name: value}, "bodies": {name: {"p": [3],
"R": [[3]x3]}}}]}.
"""
import json
import random
import sys

import opensim as osim

osim.Logger.setLevelString("error")


def main():
    path, n, seed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    rng = random.Random(seed)
    m = osim.Model(path)
    s = m.initSystem()
    cs = m.getCoordinateSet()
    bs = m.getBodySet()
    out = []
    for _ in range(n):
        q = {}
        for i in range(cs.getSize()):
            c = cs.get(i)
            lim = 0.05 if c.getMotionType() == 2 else 1.0
            v = rng.uniform(-lim, lim)
            c.setLocked(s, False)   # locked coordinates ignore setValue otherwise
            c.setValue(s, v, False)
        for i in range(cs.getSize()):
            c = cs.get(i)
            q[c.getName()] = c.getValue(s)
        m.realizePosition(s)
        bodies = {}
        for i in range(bs.getSize()):
            b = bs.get(i)
            X = b.getTransformInGround(s)
            p = X.p()
            R = X.R()
            bodies[b.getName()] = dict(p=[p.get(k) for k in range(3)],
                                       R=[[R.get(r, c) for c in range(3)] for r in range(3)])
        out.append(dict(q=q, bodies=bodies))
    print(json.dumps(dict(states=out)))


if __name__ == "__main__":
    main()
