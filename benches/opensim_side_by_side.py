#!/usr/bin/env python3
"""Side-by-side timing on ../shared/oracle/chain17.osim (17 six-DoF joints),
gravity off, a ground-fixed 7.5 N m moment on T1 (flexion, -Z):

1. OpenSim forward integration (Manager, RungeKuttaMerson, accuracy 1e-9,
   from rest at the default pose) until every coordinate is within 1e-8 of
   the equilibrium (checked every 0.25 s of simulated time, up to T_MAX);
2. OpenSim Newton on InverseDynamicsSolver's residual (central-difference
   Jacobian, as ../shared/oracle/make_cases.py does), median of N runs;
3. the tool (target/release/examples/solve_timing), median of many solves.

usage: python benches/opensim_side_by_side.py [--tool PATH] [--t-max 6] [--newton-runs 3]
Build the tool first: cargo build --release --example solve_timing
"""
import argparse
import json
import os
import statistics
import subprocess
import time

import numpy as np
import opensim as osim

HERE = os.path.dirname(os.path.abspath(__file__))
CHAIN17 = os.path.join(HERE, "..", "..", "shared", "oracle", "chain17.osim")
TORQUE = (0.0, 0.0, -7.5)


def loaded_model():
    model = osim.Model(CHAIN17)
    model.setGravity(osim.Vec3(0, 0, 0))
    fs = model.getForceSet()
    for i in range(fs.getSize()):
        if osim.Muscle.safeDownCast(fs.get(i)) is not None:
            fs.get(i).set_appliesForce(False)
    pf = osim.PrescribedForce("applied_load", model.getBodySet().get("T1"))
    pf.setForceIsInGlobalFrame(True)
    fns = [osim.Constant(v) for v in TORQUE]
    for f in fns:
        f.thisown = False
    pf.setTorqueFunctions(*fns)
    model.addForce(pf)
    s = model.initSystem()
    return model, s


def coords(model, s):
    cs = model.getCoordinateSet()
    return {cs.get(i).getName(): cs.get(i).getValue(s) for i in range(cs.getSize())}


def newton(model, s0):
    s = osim.State(s0)
    ids = osim.InverseDynamicsSolver(model)
    n = s.getNU()
    zero = osim.Vector(n, 0.0)
    cs = model.getCoordinateSet()

    def resid(q):
        for i in range(n):
            cs.get(i).setValue(s, float(q[i]), False)
        tau = ids.solve(s, zero)
        return np.array([tau.get(i) for i in range(n)])

    q = np.zeros(n)
    r = resid(q)
    it = 0
    while np.abs(r).max() > 1e-10 and it < 50:
        J = np.empty((n, n))
        for k in range(n):
            dq = np.zeros(n)
            dq[k] = 1e-7
            J[:, k] = (resid(q + dq) - resid(q - dq)) / 2e-7
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
    return {cs.get(i).getName(): q[i] for i in range(n)}, it


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--tool", default=os.path.join(os.environ.get("CARGO_TARGET_DIR", os.path.join(HERE, "..", "target")), "release", "examples", "solve_timing"))
    ap.add_argument("--t-max", type=float, default=6.0)
    ap.add_argument("--newton-runs", type=int, default=3)
    ap.add_argument("--tool-repeats", type=int, default=2000)
    a = ap.parse_args()
    osim.Logger.setLevelString("error")

    model, s0 = loaded_model()
    newton_t = []
    for _ in range(a.newton_runs):
        t0 = time.perf_counter()
        q_newton, iters = newton(model, s0)
        newton_t.append(time.perf_counter() - t0)
    names = sorted(q_newton)

    tool = json.loads(subprocess.run([a.tool, CHAIN17, "T1", *map(str, TORQUE), str(a.tool_repeats)],
                                     check=True, capture_output=True, text=True).stdout)
    d_tool = max(abs(tool["coordinates"][k] - q_newton[k]) for k in names)

    s = osim.State(s0)
    s.setTime(0.0)
    man = osim.Manager(model)
    man.setIntegratorMethod(osim.Manager.IntegratorMethod_RungeKuttaMerson)
    man.setIntegratorAccuracy(1e-9)
    man.setWriteToStorage(False)
    man.setPerformAnalyses(False)
    man.initialize(s)
    t_int = 0.0
    t = 0.0
    d_int = float("inf")
    while t < a.t_max - 1e-12:
        t += 0.25
        t0 = time.perf_counter()
        sf = man.integrate(t)
        t_int += time.perf_counter() - t0
        q = coords(model, sf)
        d_int = max(abs(q[k] - q_newton[k]) for k in names)
        if d_int < 1e-8:
            break

    rows = [
        ("OpenSim forward integration (RK-Merson 1e-9)", t_int, f"simulated {t:.2f} s, max|q - q_newton| = {d_int:.1e}"),
        ("OpenSim Newton on InverseDynamicsSolver", statistics.median(newton_t), f"{iters} iterations"),
        ("osim-spine static solve (median)", tool["median_s"], f"{tool['iterations']} iterations, max|q - q_newton| = {d_tool:.1e}"),
    ]
    print(f"chain17.osim, {tool['dofs']} dofs, gravity off, {TORQUE} N m on T1 (ground axes)")
    print(f"{'route':48s} {'time [s]':>12s} {'tool speed-up':>14s}  notes")
    for name, sec, note in rows:
        print(f"{name:48s} {sec:12.3e} {sec / tool['median_s']:14.0f}x  {note}")
    print(json.dumps(dict(rows=[dict(route=r[0], seconds=r[1], note=r[2]) for r in rows])))


if __name__ == "__main__":
    main()
