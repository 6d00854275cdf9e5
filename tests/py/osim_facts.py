"""Facts OpenSim 4.6 computes, for checking the Rust reader.

Usage: osim_facts.py MODEL

Prints JSON:
- joints: for each joint, the base frame (body or ground) of its parent and
  child frames and each frame's transform in that base frame (p, R row-major);
- markers: base frame of each marker's parent frame and that frame's
  transform in it;
- functions: value, d1, d2 of test functions built in OpenSim (SimmSpline,
  NaturalCubicSpline, PiecewiseLinearFunction, PolynomialFunction,
  MultiplierFunction, LinearFunction) at test abscissae.
"""
import json
import os
import sys

import opensim as osim

osim.Logger.setLevelString("error")


def xf(t):
    return [t.p().get(k) for k in range(3)] + [t.R().get(i, j) for i in range(3) for j in range(3)]


def base_name(frame):
    b = frame.findBaseFrame()
    return b.getName()


def derivs(f, x):
    v = osim.Vector(1, x)
    d1 = osim.StdVectorInt()
    d1.push_back(0)
    d2 = osim.StdVectorInt()
    d2.push_back(0)
    d2.push_back(0)
    return [f.calcValue(v), f.calcDerivative(d1, v), f.calcDerivative(d2, v)]


def main():
    m = osim.Model(sys.argv[1])
    m.initSystem()
    joints = {}
    for j in m.getJointSet():
        pf, cf = j.getParentFrame(), j.getChildFrame()
        joints[j.getName()] = {
            "parent_body": base_name(pf),
            "parent_in_body": xf(pf.findTransformInBaseFrame()),
            "child_body": base_name(cf),
            "child_in_body": xf(cf.findTransformInBaseFrame()),
        }
    markers = {}
    for mk in m.getMarkerSet():
        f = mk.getParentFrame()
        markers[mk.getName()] = {"body": base_name(f), "frame_in_body": xf(f.findTransformInBaseFrame())}

    xs = [-1.7, -1.0, -0.3, 0.0, 0.25, 0.5, 1.1, 2.0, 2.9, 3.0, 3.5, 5.0]
    knots_x = [-1.0, 0.0, 0.5, 1.5, 2.0, 3.0]
    knots_y = [0.3, -0.2, 0.8, 0.1, 1.0, 0.4]
    funcs = {}
    for name, cls in [("SimmSpline", osim.SimmSpline), ("PiecewiseLinearFunction", osim.PiecewiseLinearFunction)]:
        for nk in (2, 3, 4, 6):
            f = cls()
            for a, b in zip(knots_x[:nk], knots_y[:nk]):
                f.addPoint(a, b)
            funcs[f"{name}_{nk}"] = {"x": knots_x[:nk], "y": knots_y[:nk],
                                     "values": [derivs(f, x) for x in xs]}
    poly = osim.PolynomialFunction(osim.Vector([0.5, -1.0, 2.0, 0.25]))
    funcs["Polynomial"] = {"coefficients": [0.5, -1.0, 2.0, 0.25], "values": [derivs(poly, x) for x in xs]}
    # MultiplierFunction is left out: calcValue on one built from Python
    # crashes the 4.6 bindings (it is scale * inner, checked in Rust).
    lin = osim.LinearFunction(0.185, -0.02)
    funcs["Linear"] = {"coefficients": [0.185, -0.02], "values": [derivs(lin, x) for x in xs]}
    print(json.dumps({"joints": joints, "markers": markers, "xs": xs, "functions": funcs}))


if __name__ == "__main__":
    main()
    # Skip interpreter teardown: SWIG-owned OpenSim objects can crash in
    # their destructors at exit (the JSON is already printed).
    sys.stdout.flush()
    os._exit(0)
