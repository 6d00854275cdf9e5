#!/usr/bin/env python3
"""Random chains of FreeJoint, BallJoint, GimbalJoint and 6-DoF CustomJoint
joints built with the OpenSim 4.6 API (for tests/solver_free_ball.rs).

usage: free_ball_chains.py OUT_DIR SEED N_MODELS

Each model: a base body welded to ground, then 3-8 bodies, each on a joint
of a random class with random joint-frame orientations, and a BushingForce
per joint with random stiffness and damping (on the joint's own frames, or
on offset frames); random gravity. Stiffness is moderate (natural
frequencies up to ~50 rad/s) so that a short forward simulation can be
compared with a tight-accuracy OpenSim integration.

Writes OUT_DIR/fb_chain_K.osim and prints JSON, per model:
- states: random (q, u) by coordinate name, and OpenSim's udot
  (Coordinate::getAccelerationValue), qdot (State::getQDot, mapped to the
  coordinates through their q slots), Coordinate::getSpeedValue, and per
  body the ground angular velocity, centre-of-mass velocity, mass, centre of
  mass, inertia about it and rotation R_GB, and per bushing its record
  values (forces and moments with damping at that state);
- simulation: a random start (q, u) and the state after `duration` seconds
  of OpenSim's RungeKuttaMerson integrator at accuracy 1e-12;
- statics: the equilibrium under 1/20 of the gravity (Newton on
  InverseDynamicsSolver, central-difference Jacobian, as random_chains.py
  does).
"""
import json
import os
import sys

import numpy as np
import opensim as osim

osim.Logger.setLevelString("error")
AX = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
SUFFIX = ["r0", "r1", "r2", "t0", "t1", "t2"]
KINDS = ["free", "ball", "gimbal", "custom"]


def v3(a):
    return osim.Vec3(float(a[0]), float(a[1]), float(a[2]))


def custom_joint(rng, jn, parent, p_loc, p_ori, body, c_loc, c_ori):
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
    return osim.CustomJoint(jn, parent, v3(p_loc), v3(p_ori), body, v3(c_loc), v3(c_ori), st)


def build(rng, n, path, kinds):
    model = osim.Model()
    model.setName(os.path.basename(path)[:-5])
    g = rng.uniform(-1, 1, 3)
    g = g / np.linalg.norm(g) * 9.80665 * rng.uniform(0.0, 1.0)
    model.setGravity(v3(g))
    base = osim.Body("base", 2.0, osim.Vec3(0), osim.Inertia(0.01, 0.01, 0.01))
    model.addBody(base)
    model.addJoint(osim.WeldJoint("base_weld", model.getGround(), osim.Vec3(0), osim.Vec3(0), base, osim.Vec3(0), osim.Vec3(0)))
    prev = base
    for i in range(n):
        kind = kinds[i]
        m = rng.uniform(0.5, 2.0)
        a, b, c = rng.uniform(0.05, 0.15, 3)
        # a full inertia (products too) about the centre of mass
        R = osim.Rotation(osim.BodyRotationSequence, *[x for k, ang in enumerate(rng.uniform(-1, 1, 3)) for x in (float(ang), osim.CoordinateAxis(k))])
        Rn = np.array([[R.get(r, k) for k in range(3)] for r in range(3)])
        Id = np.diag([m * (b * b + c * c) / 5, m * (a * a + c * c) / 5, m * (a * a + b * b) / 5])
        Ic = Rn @ Id @ Rn.T
        inertia = osim.Inertia(Ic[0, 0], Ic[1, 1], Ic[2, 2], Ic[0, 1], Ic[0, 2], Ic[1, 2])
        body = osim.Body(f"b{i}", m, v3(rng.uniform(-0.03, 0.03, 3)), inertia)
        model.addBody(body)
        jn = f"j{i}"
        p_loc = (rng.uniform(-0.01, 0.01), 0.05, rng.uniform(-0.01, 0.01))
        p_ori = rng.uniform(-0.5, 0.5, 3)
        c_loc = (0.0, -0.02, 0.0)
        c_ori = rng.uniform(-0.5, 0.5, 3)
        if kind == "custom":
            j = custom_joint(rng, jn, prev, p_loc, p_ori, body, c_loc, c_ori)
        else:
            cls = {"free": osim.FreeJoint, "ball": osim.BallJoint, "gimbal": osim.GimbalJoint}[kind]
            j = cls(jn, prev, v3(p_loc), v3(p_ori), body, v3(c_loc), v3(c_ori))
        model.addJoint(j)
        rk = rng.uniform(2.0, 10.0, 3)
        tk = rng.uniform(500.0, 2000.0, 3)
        rc = rng.uniform(0.0, 0.05, 3)
        tc = rng.uniform(0.0, 5.0, 3)
        if rng.uniform() < 0.3:
            # bushing on its own frames, offset from the joint frames
            X1 = osim.Transform(osim.Rotation(osim.BodyRotationSequence, p_ori[0] + 0.05, osim.CoordinateAxis(0), p_ori[1], osim.CoordinateAxis(1), p_ori[2] - 0.05, osim.CoordinateAxis(2)), v3(p_loc))
            X2 = osim.Transform(osim.Rotation(osim.BodyRotationSequence, c_ori[0], osim.CoordinateAxis(0), c_ori[1] + 0.04, osim.CoordinateAxis(1), c_ori[2], osim.CoordinateAxis(2)), v3((0.001, -0.02, 0.0)))
            bf = osim.BushingForce(f"{jn}_bushing", prev, X1, body, X2, v3(tk), v3(rk), v3(tc), v3(rc))
        else:
            # on the joint's own frames (the solver's fast path for FreeJoint and 6-DoF CustomJoint)
            bf = osim.BushingForce()
            bf.setName(f"{jn}_bushing")
            bf.set_rotational_stiffness(v3(rk))
            bf.set_translational_stiffness(v3(tk))
            bf.set_rotational_damping(v3(rc))
            bf.set_translational_damping(v3(tc))
            bf.connectSocket_frame1(j.getParentFrame())
            bf.connectSocket_frame2(j.getChildFrame())
        model.addForce(bf)
        prev = body
    model.finalizeConnections()
    model.printToXML(path)


def coords(model):
    cs = model.getCoordinateSet()
    return [cs.get(i) for i in range(cs.getSize())]


def random_qu(rng, cs, u_scale):
    q = [rng.uniform(-0.6, 0.6) if c.getMotionType() == 1 else rng.uniform(-0.01, 0.01) for c in cs]
    u = [u_scale * rng.uniform(-2.0, 2.0) if c.getMotionType() == 1 else u_scale * rng.uniform(-0.1, 0.1) for c in cs]
    return q, u


def set_state(model, s, q, u=None):
    for i, c in enumerate(coords(model)):
        c.setValue(s, float(q[i]), False)
        c.setSpeedValue(s, 0.0 if u is None else float(u[i]))


def q_slots(model, s):
    """Index in State::getQ of each coordinate (found by distinct values;
    Coordinate has no public q index and MobilizedBody is not wrapped)."""
    cs = coords(model)
    marks = [0.001 * (i + 1) + 0.1 for i in range(len(cs))]
    set_state(model, s, marks)
    Q = s.getQ()
    qv = [Q.get(i) for i in range(Q.size())]
    slots = []
    for mk in marks:
        hits = [i for i, v in enumerate(qv) if v == mk]
        assert len(hits) == 1, "coordinate q slot not unique"
        slots.append(hits[0])
    return slots


def vec(v):
    return [v.get(i) for i in range(3)]


def state_record(model, s, q, u):
    cs = coords(model)
    slots = q_slots(model, s)
    set_state(model, s, q, u)
    model.realizeAcceleration(s)
    QD = s.getQDot()
    bodies = {}
    for b in model.getBodySet():
        com = b.getMassCenter()
        R = b.getTransformInGround(s).R()
        I = b.getInertia()
        mom = I.getMoments()
        prod = I.getProducts()
        bodies[b.getName()] = dict(
            w=vec(b.getAngularVelocityInGround(s)),
            v_com=vec(b.findStationVelocityInGround(s, com)),
            mass=b.getMass(),
            com=vec(com),
            inertia=[mom.get(0), mom.get(1), mom.get(2), prod.get(0), prod.get(1), prod.get(2)],
            R=[[R.get(r, k) for k in range(3)] for r in range(3)],
        )
    bushings = {}
    for f in model.getForceSet():
        rv = f.getRecordValues(s)
        bushings[f.getName()] = [rv.get(i) for i in range(rv.size())]
    return dict(
        q={c.getName(): q[i] for i, c in enumerate(cs)},
        u={c.getName(): u[i] for i, c in enumerate(cs)},
        bushing_records=bushings,
        speed_value={c.getName(): c.getSpeedValue(s) for c in cs},
        qdot={c.getName(): QD.get(slots[i]) for i, c in enumerate(cs)},
        udot={c.getName(): c.getAccelerationValue(s) for c in cs},
        bodies=bodies,
    )


def simulate(model, s, q, u, duration):
    cs = coords(model)
    set_state(model, s, q, u)
    s.setTime(0.0)
    manager = osim.Manager(model)
    manager.setIntegratorMethod(osim.Manager.IntegratorMethod_RungeKuttaMerson)
    manager.setIntegratorAccuracy(1e-12)
    manager.initialize(s)
    s1 = manager.integrate(duration)
    return dict(
        duration=duration,
        q0={c.getName(): q[i] for i, c in enumerate(cs)},
        u0={c.getName(): u[i] for i, c in enumerate(cs)},
        q={c.getName(): c.getValue(s1) for c in cs},
        u={c.getName(): c.getSpeedValue(s1) for c in cs},
    )


def statics(model, s):
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
    # ID's forces are in mobility order and vanish together with the
    # coordinate-rate forces; q was set by coordinate name.
    return dict(iterations=it, residual=float(np.abs(r).max()),
                q={c.getName(): float(q[i]) for i, c in enumerate(cs)})


def main():
    out_dir, seed, n_models = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    rng = np.random.default_rng(seed)
    models = []
    for k in range(n_models):
        n = int(rng.integers(3, 9))
        # every class appears in every model, then random ones
        kinds = list(rng.permutation(KINDS))[: min(n, 4)] + [KINDS[int(x)] for x in rng.integers(0, 4, max(0, n - 4))]
        path = os.path.join(out_dir, f"fb_chain_{k}.osim")
        build(rng, n, path, kinds)
        model = osim.Model(path)
        s = model.initSystem()
        cs = coords(model)
        states = []
        for _ in range(3):
            q, u = random_qu(rng, cs, 1.0)
            states.append(state_record(model, s, q, u))
        q, u = random_qu(rng, cs, 0.5)
        sim = simulate(model, s, q, u, 0.05)
        # statics under a twentieth of the gravity: small deflections, one
        # equilibrium near the default pose (soft bushings under full gravity
        # have several)
        g = model.getGravity()
        g = [0.05 * g.get(i) for i in range(3)]
        model.setGravity(v3(g))
        s = model.initSystem()
        st = statics(model, s)
        st["gravity"] = g
        models.append(dict(file=path, kinds=kinds, n_dofs=s.getNU(), states=states,
                           simulation=sim, statics=st))
    print(json.dumps(dict(opensim=osim.GetVersionAndDate(), models=models)))


if __name__ == "__main__":
    main()
