#!/usr/bin/env python3
"""Random serial chains built with the OpenSim 4.6 API (for
tests/solver_random_chains.rs).

usage: random_chains.py OUT_DIR SEED N_MODELS

Each model: a base body welded to ground, then 3-20 bodies on 6-DoF
CustomJoints whose three rotation axes (and three translation axes) are a
random permutation of X, Y, Z, with random joint-frame orientations, a
BushingForce per joint with random stiffness and damping (on the joint's own
frames, or on its own offset frames), random gravity. Writes OUT_DIR/chain_K.osim
and prints JSON: per model, generalised accelerations (udot) at random states,
and static equilibria under random loads (Newton on InverseDynamicsSolver,
central-difference Jacobian, as ../shared/oracle/make_cases.py does).
"""
import json
import math
import os
import sys

import numpy as np
import opensim as osim

osim.Logger.setLevelString("error")
AX = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
SUFFIX = ["r0", "r1", "r2", "t0", "t1", "t2"]


def v3(a):
    return osim.Vec3(float(a[0]), float(a[1]), float(a[2]))


def build(rng, n, path):
    model = osim.Model()
    model.setName(os.path.basename(path)[:-5])
    g = rng.uniform(-1, 1, 3)
    g = g / np.linalg.norm(g) * 9.80665 * rng.uniform(0.0, 1.0)
    model.setGravity(v3(g))
    base = osim.Body("base", 2.0, osim.Vec3(0), osim.Inertia(0.01, 0.01, 0.01))
    model.addBody(base)
    model.addJoint(osim.WeldJoint("base_weld", model.getGround(), osim.Vec3(0), osim.Vec3(0), base, osim.Vec3(0), osim.Vec3(0)))
    prev = base
    names = []
    for i in range(n):
        m = rng.uniform(0.1, 0.6)
        a, b, c = rng.uniform(0.01, 0.05, 3)
        inertia = osim.Inertia(m * (b * b + c * c) / 5, m * (a * a + c * c) / 5, m * (a * a + b * b) / 5)
        body = osim.Body(f"b{i}", m, v3(rng.uniform(-0.01, 0.01, 3)), inertia)
        model.addBody(body)
        jn = f"j{i}"
        st = osim.SpatialTransform()
        rot_order = rng.permutation(3)
        tr_order = rng.permutation(3)
        for k in range(6):
            ta = st.updTransformAxis(k)
            axis = AX[rot_order[k]] if k < 3 else AX[tr_order[k - 3]]
            ta.setAxis(v3(axis))
            arr = osim.ArrayStr()
            arr.append(f"{jn}_{SUFFIX[k]}")
            ta.setCoordinateNames(arr)
            f = osim.LinearFunction(1.0, 0.0)
            f.thisown = False
            ta.setFunction(f)
        p_loc = (rng.uniform(-0.005, 0.005), 0.025, rng.uniform(-0.005, 0.005))
        p_ori = rng.uniform(-0.5, 0.5, 3)
        c_loc = (0.0, -0.01, 0.0)
        c_ori = rng.uniform(-0.5, 0.5, 3)
        j = osim.CustomJoint(jn, prev, v3(p_loc), v3(p_ori), body, v3(c_loc), v3(c_ori), st)
        model.addJoint(j)
        rk = rng.uniform(100.0, 1000.0, 3)
        tk = rng.uniform(1e5, 2e6, 3)
        rc = rng.uniform(0.0, 3.0, 3)
        tc = rng.uniform(0.0, 1000.0, 3)
        if rng.uniform() < 0.3:
            # bushing on its own frames, offset from the joint frames
            X1 = osim.Transform(osim.Rotation(osim.BodyRotationSequence, p_ori[0] + 0.05, osim.CoordinateAxis(0), p_ori[1], osim.CoordinateAxis(1), p_ori[2] - 0.05, osim.CoordinateAxis(2)), v3(p_loc))
            X2 = osim.Transform(osim.Rotation(osim.BodyRotationSequence, c_ori[0], osim.CoordinateAxis(0), c_ori[1] + 0.04, osim.CoordinateAxis(1), c_ori[2], osim.CoordinateAxis(2)), v3((0.001, -0.01, 0.0)))
            bf = osim.BushingForce(f"{jn}_bushing", prev, X1, body, X2, v3(tk), v3(rk), v3(tc), v3(rc))
        else:
            bf = osim.BushingForce()
            bf.setName(f"{jn}_bushing")
            bf.set_rotational_stiffness(v3(rk))
            bf.set_translational_stiffness(v3(tk))
            bf.set_rotational_damping(v3(rc))
            bf.set_translational_damping(v3(tc))
            bf.connectSocket_frame1(j.getParentFrame())
            bf.connectSocket_frame2(j.getChildFrame())
        model.addForce(bf)
        names.append(f"b{i}")
        prev = body
    model.finalizeConnections()
    model.printToXML(path)
    return names


def coords(model):
    cs = model.getCoordinateSet()
    return [cs.get(i) for i in range(cs.getSize())]


def set_state(model, s, q, u=None):
    for i, c in enumerate(coords(model)):
        c.setValue(s, float(q[i]), False)
        c.setSpeedValue(s, 0.0 if u is None else float(u[i]))


def udot_states(path, rng, n_states):
    model = osim.Model(path)
    s = model.initSystem()
    cs = coords(model)
    out = []
    for _ in range(n_states):
        q = [rng.uniform(-0.3, 0.3) if c.getMotionType() == 1 else rng.uniform(-0.004, 0.004) for c in cs]
        u = [rng.uniform(-2.0, 2.0) if c.getMotionType() == 1 else rng.uniform(-0.05, 0.05) for c in cs]
        set_state(model, s, q, u)
        model.realizeAcceleration(s)
        out.append(dict(q={c.getName(): q[i] for i, c in enumerate(cs)},
                        u={c.getName(): u[i] for i, c in enumerate(cs)},
                        udot={c.getName(): c.getAccelerationValue(s) for c in cs}))
    return out


def add_pf(model, body, vec, point, ground):
    pf = osim.PrescribedForce(f"pf_{body}_{len(str(vec))}_{ground}_{point is None}", model.getBodySet().get(body))
    pf.setForceIsInGlobalFrame(bool(ground))
    pf.setPointIsInGlobalFrame(False)
    fns = [osim.Constant(float(v)) for v in vec]
    for f in fns:
        f.thisown = False
    if point is None:
        pf.setTorqueFunctions(*fns)
    else:
        pts = [osim.Constant(float(v)) for v in point]
        for f in pts:
            f.thisown = False
        pf.setForceFunctions(*fns)
        pf.setPointFunctions(*pts)
    model.addForce(pf)


def static_case(path, rng, names):
    model = osim.Model(path)
    top = names[-1]
    mid = names[len(names) // 2]
    loads = [
        dict(kind="moment", body=top, vec=list(rng.uniform(-3, 3, 3)), frame=("ground" if rng.uniform() < 0.5 else "body")),
        dict(kind="force", body=mid, vec=list(rng.uniform(-20, 20, 3)), point=list(rng.uniform(-0.02, 0.02, 3)),
             frame=("ground" if rng.uniform() < 0.5 else "body")),
    ]
    for l in loads:
        add_pf(model, l["body"], l["vec"], l.get("point"), l["frame"] == "ground")
    s = model.initSystem()
    ids = osim.InverseDynamicsSolver(model)
    n = s.getNU()
    zero = osim.Vector(n, 0.0)
    cs = coords(model)

    def resid(q):
        set_state(model, s, q)
        tau = ids.solve(s, zero)
        return np.array([tau.get(i) for i in range(n)])

    q = np.zeros(n)
    r = resid(q)
    it = 0
    h = 1e-7
    while np.abs(r).max() > 1e-10 and it < 40:
        J = np.empty((n, n))
        for k in range(n):
            dq = np.zeros(n)
            dq[k] = h
            J[:, k] = (resid(q + dq) - resid(q - dq)) / (2 * h)
        step = np.linalg.solve(J, -r)
        lam = 1.0
        while True:
            r_new = resid(q + lam * step)
            if np.abs(r_new).max() < np.abs(r).max() or lam < 1e-4:
                break
            lam *= 0.5
        q = q + lam * step
        r = r_new
        it += 1
    # InverseDynamicsSolver's generalised forces are in mobility order; the
    # coordinate values were set by name, so q (coordinate order) is exact.
    return dict(loads=loads, iterations=it, residual=float(np.abs(r).max()),
                q={c.getName(): float(q[i]) for i, c in enumerate(cs)})


def main():
    out_dir, seed, n_models = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    rng = np.random.default_rng(seed)
    models = []
    for k in range(n_models):
        n = int(rng.integers(3, 21)) if k > 1 else (3 if k == 0 else 20)
        path = os.path.join(out_dir, f"chain_{k}.osim")
        names = build(rng, n, path)
        models.append(dict(file=path, joints=n, states=udot_states(path, rng, 3),
                           statics=[static_case(path, rng, names)]))
    print(json.dumps(dict(opensim=osim.GetVersionAndDate(), models=models)))


if __name__ == "__main__":
    main()
