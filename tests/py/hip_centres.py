#!/usr/bin/env python3
"""Hip joint centres of a model in ground at its default pose, by OpenSim 4.6.

usage: hip_centres.py MODEL JOINT...

Prints JSON: {joint: [x, y, z]} (the joint's parent frame origin in ground, m).
"""
import json
import sys

import opensim as osim

osim.Logger.setLevelString("error")


def main():
    m = osim.Model(sys.argv[1])
    s = m.initSystem()
    out = {}
    for name in sys.argv[2:]:
        p = m.getJointSet().get(name).getParentFrame().getPositionInGround(s)
        out[name] = [p.get(0), p.get(1), p.get(2)]
    print(json.dumps(out))


if __name__ == "__main__":
    main()
