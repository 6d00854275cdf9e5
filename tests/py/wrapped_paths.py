"""The muscle paths OpenSim 4.6 actually uses, wrapping included.

Usage: wrapped_paths.py MODEL.osim [POSE.json]

POSE.json (optional) maps coordinate names to values added to their
defaults (radians or metres); without it the default pose is used.

Prints JSON:
{"bodies": {name: {"p": [x, y, z], "R": [[3x3 row-major]]}},
 "muscles": {name: {"length": L, "straight": S,
                    "path": [{"kind": "point"|"wrap", "body": b,
                              "ground": [x, y, z]}...],
                    "polyline": [{"ground": [x, y, z], "body": b|null, "name": n}...],
                    "wraps": [...]}}}
`path` is GeometryPath.getCurrentPath (the muscle's own active points and
the wrap tangent points); `polyline` is the path OpenSim's length is the
length of: own points, and between the two tangent points of a wrap the
great-circle arc of the wrap sphere whose length OpenSim added
(PathWrapPoint.getWrapLength; the arc is sampled every 1 mm here: the
display points of PathWrapPoint.getWrapPath are not on the arc in 4.6).
`wraps` lists each active wrap: sphere name, body, centre (ground),
radius, arc length. `straight` is the straight polyline through the
own points only.
"""
import json
import math
import sys

import opensim as osim

osim.Logger.setLevelString("error")


def vec(v):
    return [v.get(0), v.get(1), v.get(2)]


def sphere_arc(c, r, a, b, length):
    """Interior points of the great-circle arc of length `length` from the
    tangent point `a` to the tangent point `b` on the sphere (c, r): the
    short arc, or the long one when `length` is longer (a far-side wrap)."""
    ua = [(a[i] - c[i]) / r for i in range(3)]
    ub = [(b[i] - c[i]) / r for i in range(3)]
    n = [ua[1] * ub[2] - ua[2] * ub[1], ua[2] * ub[0] - ua[0] * ub[2], ua[0] * ub[1] - ua[1] * ub[0]]
    nn = math.sqrt(sum(x * x for x in n))
    if nn < 1e-12:
        return []
    n = [x / nn for x in n]
    short = math.acos(max(-1.0, min(1.0, sum(ua[i] * ub[i] for i in range(3)))))
    total = length / r
    sign = 1.0 if abs(total - short) <= abs(total - (2 * math.pi - short)) else -1.0
    steps = max(1, int(math.ceil(length / 0.001)))
    w = [n[1] * ua[2] - n[2] * ua[1], n[2] * ua[0] - n[0] * ua[2], n[0] * ua[1] - n[1] * ua[0]]
    out = []
    for k in range(1, steps):
        t = sign * total * k / steps
        out.append([c[i] + r * (ua[i] * math.cos(t) + w[i] * math.sin(t)) for i in range(3)])
    return out


def main():
    model = osim.Model(sys.argv[1])
    s = model.initSystem()
    if len(sys.argv) > 2:
        with open(sys.argv[2]) as f:
            pose = json.load(f)
        cs = model.getCoordinateSet()
        for name, value in pose.items():
            c = cs.get(name)
            c.setValue(s, c.getDefaultValue() + value, False)
    model.realizePosition(s)
    out = {"bodies": {}, "muscles": {}}
    bs = model.getBodySet()
    for i in range(bs.getSize()):
        b = bs.get(i)
        x = b.getTransformInGround(s)
        r = x.R()
        out["bodies"][b.getName()] = {
            "p": vec(x.p()),
            "R": [[r.get(i, j) for j in range(3)] for i in range(3)],
        }
    fs = model.getForceSet()
    for i in range(fs.getSize()):
        mus = osim.Muscle.safeDownCast(fs.get(i))
        if mus is None:
            continue
        gp = osim.GeometryPath.safeDownCast(mus.getPath())
        cur = gp.getCurrentPath(s)
        path, poly, own, wraps = [], [], [], []
        for k in range(cur.getSize()):
            p = cur.get(k)
            g = vec(p.getLocationInGround(s))
            wp = osim.PathWrapPoint.safeDownCast(p)
            kind = "point" if wp is None else "wrap"
            path.append({"kind": kind, "body": p.getParentFrame().findBaseFrame().getName(), "ground": g})
            if wp is None:
                own.append(g)
                poly.append({"ground": g, "body": path[-1]["body"], "name": p.getName()})
                continue
            arc_len = wp.getWrapLength(s)
            if arc_len > 0.0 and poly:
                # Second tangent point of a wrap: the arc from the first.
                wo = wp.getWrapObject()
                sph = osim.WrapSphere.safeDownCast(wo)
                if sph is None:
                    raise SystemExit("only WrapSphere arcs are handled")
                c = vec(wo.getFrame().findStationLocationInGround(s, wo.get_translation()))
                r = sph.get_radius()
                arc = sphere_arc(c, r, poly[-1]["ground"], g, arc_len)
                poly.extend({"ground": x, "body": None} for x in arc)
                wraps.append({"sphere": wo.getName(), "body": wo.getFrame().getName(),
                              "centre": c, "radius": r, "arc_length": arc_len})
            poly.append({"ground": g, "body": None})
        straight = sum(math.dist(own[k], own[k + 1]) for k in range(len(own) - 1))
        out["muscles"][mus.getName()] = {
            "length": gp.getLength(s),
            "straight": straight,
            "path": path,
            "polyline": poly,
            "wraps": wraps,
        }
    print(json.dumps(out))


main()
