"""Check a base model written by `osim-spine base` with OpenSim 4.6.

Usage: base_check.py BASE.osim LB_DEG AR_DEG

Prints JSON:
- counts: IVD CustomJoints with 6 coordinates, BushingForces, markers;
- default pose: the largest |record value| of every bushing (force and
  torque, should be 0), every marker's position in ground;
- scoliotic pose (every *_LB coordinate at LB_DEG and *_AR at AR_DEG on top
  of its default): for every muscle with PathWraps, path length vs the
  straight polyline through its own points, the smallest clearance
  (distance - radius) of its own points to the spheres it wraps over, and
  whether its straight path crosses one of those spheres and whether
  wrapping is active (wrap points in the current path).
"""
import json
import math
import sys

import opensim as osim

osim.Logger.setLevelString("error")


def vec(v):
    return [v.get(0), v.get(1), v.get(2)]


def seg_dist(c, a, b):
    ab = [b[i] - a[i] for i in range(3)]
    l2 = sum(x * x for x in ab)
    t = 0.0 if l2 == 0 else max(0.0, min(1.0, sum((c[i] - a[i]) * ab[i] for i in range(3)) / l2))
    p = [a[i] + ab[i] * t for i in range(3)]
    return math.dist(p, c)


def main():
    path, lb, ar = sys.argv[1], math.radians(float(sys.argv[2])), math.radians(float(sys.argv[3]))
    m = osim.Model(path)
    s = m.initSystem()
    out = {}
    js = m.getJointSet()
    six = 0
    for i in range(js.getSize()):
        j = js.get(i)
        if j.getConcreteClassName() == "CustomJoint" and j.numCoordinates() == 6 and j.getName().endswith("_IVDjnt"):
            six += 1
    out["ivd_6dof_joints"] = six
    fs = m.getForceSet()
    m.realizeVelocity(s)
    bushing_max = 0.0
    nb = 0
    for i in range(fs.getSize()):
        f = fs.get(i)
        if f.getConcreteClassName() == "BushingForce":
            nb += 1
            rv = f.getRecordValues(s)
            for k in range(rv.getSize()):
                bushing_max = max(bushing_max, abs(rv.get(k)))
    out["bushings"] = nb
    out["bushing_max_record_at_default"] = bushing_max
    m.realizePosition(s)
    ms = m.getMarkerSet()
    out["markers"] = {ms.get(i).getName(): vec(ms.get(i).getLocationInGround(s)) for i in range(ms.getSize())}
    bodies = {}
    bs = m.getBodySet()
    for i in range(bs.getSize()):
        b = bs.get(i)
        bodies[b.getName()] = vec(b.getPositionInGround(s))
    out["body_origins"] = bodies
    # Spheres.
    spheres = {}
    for i in range(bs.getSize()):
        b = bs.get(i)
        ws = b.getWrapObjectSet()
        for k in range(ws.getSize()):
            w = osim.WrapSphere.safeDownCast(ws.get(k))
            if w is None:
                continue
            spheres[w.getName()] = (b, w.get_translation(), w.get_radius())
    # Scoliotic pose.
    cs = m.getCoordinateSet()
    for i in range(cs.getSize()):
        c = cs.get(i)
        n = c.getName()
        if n.endswith("_LB"):
            c.setValue(s, c.getDefaultValue() + lb, False)
        elif n.endswith("_AR"):
            c.setValue(s, c.getDefaultValue() + ar, False)
    m.assemble(s)
    m.realizePosition(s)
    centres = {n: (vec(b.findStationLocationInGround(s, t)), r) for n, (b, t, r) in spheres.items()}
    rows = []
    for i in range(fs.getSize()):
        f = fs.get(i)
        mus = osim.Muscle.safeDownCast(f)
        if mus is None:
            continue
        gp = osim.GeometryPath.safeDownCast(mus.getPath())
        pws = gp.getWrapSet()
        if pws.getSize() == 0:
            continue
        wrapped = [pws.get(k).get_wrap_object() for k in range(pws.getSize())]
        cur = gp.getCurrentPath(s)
        own, nwrap = [], 0
        for k in range(cur.getSize()):
            p = cur.get(k)
            if p.getConcreteClassName() == "PathWrapPoint":
                nwrap += 1
            else:
                own.append(vec(p.getLocationInGround(s)))
        straight = sum(math.dist(own[k], own[k + 1]) for k in range(len(own) - 1))
        clearance = min(math.dist(p, centres[w][0]) - centres[w][1] for w in wrapped for p in own)
        crosses = any(
            seg_dist(centres[w][0], own[k], own[k + 1]) < centres[w][1]
            for w in wrapped
            for k in range(len(own) - 1)
        )
        crosses_any = any(
            seg_dist(c, own[k], own[k + 1]) < r
            for (c, r) in centres.values()
            for k in range(len(own) - 1)
        )
        rows.append({
            "muscle": mus.getName(),
            "length": gp.getLength(s),
            "straight": straight,
            "min_clearance": clearance,
            "crosses_wrapped_sphere": crosses,
            "crosses_any_sphere": crosses_any,
            "wrap_points": nwrap,
        })
    out["scoliotic"] = rows
    print(json.dumps(out))


main()
