"""Compare two .osim files kinematically with OpenSim 4.6.

Usage: compare_models.py REFERENCE CANDIDATE N_STATES SEED

Loads both files (the reference as OpenSim itself reads it, e.g. a legacy
file; the candidate as written by osim-spine), then for the default state and
N_STATES random admissible coordinate states (seeded; each unlocked
coordinate uniform in its range, clipped to +-1 rad / +-0.05 m; coupled
coordinates set from their CoordinateCouplerConstraint) sets the same values
by name in both and compares, in ground: every body's transform, every
marker's position, every muscle's path length (max_length) and every
BushingForce's 12 record values (also in max_length). Prints JSON with the counts,
the names that differ and the largest differences. Also compares every
force's `appliesForce` and every actuator's min/max control (as OpenSim reads
them): `force_flag_mismatch` lists the forces that differ, and
`applies_force` / `controls` give the reference's values.
"""
import json
import math
import random
import sys

import opensim as osim

osim.Logger.setLevelString("error")


def load(path):
    m = osim.Model(path)
    s = m.initSystem()
    return m, s


def coupler_list(m):
    out = []
    cs = m.getConstraintSet()
    for i in range(cs.getSize()):
        c = cs.get(i)
        if c.getConcreteClassName() != "CoordinateCouplerConstraint":
            continue
        cc = osim.CoordinateCouplerConstraint.safeDownCast(c)
        ind = cc.getIndependentCoordinateNames()
        if ind.getSize() != 1:
            continue
        out.append((ind.get(0), cc.getDependentCoordinateName(), cc.getFunction(), osim.PropertyHelper.getValueDouble(cc.getPropertyByName("scale_factor"))))
    return out


def sample(m, rng):
    vals = {}
    cs = m.getCoordinateSet()
    for i in range(cs.getSize()):
        c = cs.get(i)
        if c.getDefaultLocked():
            vals[c.getName()] = c.getDefaultValue()
            continue
        lo, hi = c.getRangeMin(), c.getRangeMax()
        lim = 0.05 if c.getMotionType() == 2 else 1.0  # 2: translational
        lo, hi = max(lo, -lim), min(hi, lim)
        if hi < lo:
            lo = hi = c.getDefaultValue()
        vals[c.getName()] = rng.uniform(lo, hi)
    x = osim.Vector(1, 0.0)
    for ind, dep, f, scale in coupler_list(m):
        x.set(0, vals[ind])
        vals[dep] = f.calcValue(x) * scale
    return vals


def snapshot(m, s, vals):
    cs = m.getCoordinateSet()
    if vals is not None:
        for i in range(cs.getSize()):
            c = cs.get(i)
            c.setValue(s, vals[c.getName()], False)
    m.realizePosition(s)
    bodies = {}
    for b in m.getBodySet():
        t = b.getTransformInGround(s)
        r = t.R()
        p = t.p()
        bodies[b.getName()] = [p.get(k) for k in range(3)] + [r.get(i, j) for i in range(3) for j in range(3)]
    markers = {}
    for mk in m.getMarkerSet():
        p = mk.getLocationInGround(s)
        markers[mk.getName()] = [p.get(k) for k in range(3)]
    lengths = {}
    for mu in m.getMuscles():
        lengths[mu.getName()] = mu.getGeometryPath().getLength(s)
    # Bushing forces (frames and stiffness): their 12 record values.
    m.realizeVelocity(s)
    for f in m.getForceSet():
        if f.getConcreteClassName() == "BushingForce":
            rv = f.getRecordValues(s)
            lengths["bushing:" + f.getName()] = [rv.get(i) for i in range(rv.size())]
    return bodies, markers, lengths


def force_flags(m):
    """Per force: appliesForce, and (actuators) [min_control, max_control]."""
    flags, controls = {}, {}
    for f in m.getForceSet():
        flags[f.getName()] = bool(f.get_appliesForce())
        act = osim.ScalarActuator.safeDownCast(f)
        if act is not None:
            # JSON has no infinity: an unbounded control is null
            controls[f.getName()] = [
                v if math.isfinite(v) else None
                for v in (act.getMinControl(), act.getMaxControl())
            ]
    return flags, controls


def maxdiff(a, b):
    worst = 0.0
    for k in a:
        if k in b:
            x, y = a[k], b[k]
            if isinstance(x, float):
                x, y = [x], [y]
            for u, v in zip(x, y):
                d = abs(u - v)
                if math.isnan(d):
                    d = float("inf")
                worst = max(worst, d)
    return worst


def main():
    ref_path, cand_path, n, seed = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    mr, sr = load(ref_path)
    mc, sc = load(cand_path)
    rng = random.Random(seed)
    res = {"states": 0, "max_body": 0.0, "max_marker": 0.0, "max_length": 0.0}
    (fr, cr), (fc, cc) = force_flags(mr), force_flags(mc)
    res["applies_force"], res["controls"] = fr, cr
    res["force_flag_mismatch"] = sorted(
        k for k in set(fr) | set(fc) if fr.get(k) != fc.get(k) or cr.get(k) != cc.get(k)
    )
    first = True
    for k in range(n + 1):
        vals = None if k == 0 else sample(mr, rng)
        br, kr, lr = snapshot(mr, sr, vals)
        bc, kc, lc = snapshot(mc, sc, vals)
        if first:
            res["bodies"] = len(br)
            res["markers"] = len(kr)
            res["muscles"] = len([k for k in lr if not k.startswith("bushing:")])
            res["bushings"] = len([k for k in lr if k.startswith("bushing:")])
            res["coordinates"] = mr.getCoordinateSet().getSize()
            res["name_mismatch"] = sorted(
                set(br) ^ set(bc) | set(kr) ^ set(kc) | set(lr) ^ set(lc)
            )
            first = False
        res["max_body"] = max(res["max_body"], maxdiff(br, bc))
        res["max_marker"] = max(res["max_marker"], maxdiff(kr, kc))
        res["max_length"] = max(res["max_length"], maxdiff(lr, lc))
        res["states"] += 1
    print(json.dumps(res))


if __name__ == "__main__":
    main()
