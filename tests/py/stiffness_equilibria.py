"""OpenSim 4.6's static equilibria of a model near given states.

Usage: stiffness_equilibria.py MODEL CASES.json

CASES.json: {"body": TOP, "cases": [{"axis": 0|1|2, "moment": M,
"q": {coordinate: value}}]}: a pure moment M (N m) about ground axis `axis`
on body TOP, and a candidate equilibrium q (the tool's). Gravity is switched
off, and so is every force that is not a bushing (muscles). For each case OpenSim's own forces decide: the generalised force
residual r(q) = InverseDynamicsSolver(q, u=0, udot=0) with the load applied
(through a PrescribedForce whose torque is t * axis, evaluated at time t = M),
its Jacobian by central differences (h = 1e-7), and Newton steps from q (at
least one, then until the residual is below 1e-10, at most 4, stopping early
when a step no longer halves the residual: OpenSim's own rounding floor, e.g.
~1e-10 N with 1.9e6 N/m translational stiffness, has been reached; the
iterate with the smaller residual is kept). Prints JSON: per case the
largest |residual| at the given q, the largest |q_opensim - q| and the
final residual.

Speed (the Jacobian takes 2 x n residuals per Newton step, n = 102 on a base
model): coordinates are looked up once, speeds are set to zero once, and
linear algebra runs single-threaded (a threaded BLAS on a loaded 2-core
machine made one 102 x 102 least-squares solve take up to 0.5 s).
"""
import json
import os
import sys

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np
import opensim as osim

osim.Logger.setLevelString("error")


def main():
    model_path, cases_path = sys.argv[1], sys.argv[2]
    spec = json.load(open(cases_path))
    model = osim.Model(model_path)
    model.setGravity(osim.Vec3(0, 0, 0))
    fs = model.getForceSet()
    for i in range(fs.getSize()):
        if "Bushing" not in fs.get(i).getConcreteClassName():
            fs.get(i).set_appliesForce(False)  # e.g. muscles: not modelled by the tool
    top = model.getBodySet().get(spec["body"])
    pfs = []
    for axis in range(3):
        pf = osim.PrescribedForce(f"load_{axis}", top)
        pf.setForceIsInGlobalFrame(True)
        fns = []
        for k in range(3):
            f = osim.LinearFunction(1.0, 0.0) if k == axis else osim.Constant(0.0)
            f.thisown = False
            fns.append(f)
        pf.setTorqueFunctions(*fns)
        model.addForce(pf)
        pfs.append(pf)
    s = model.initSystem()
    cs = model.getCoordinateSet()
    names = [cs.get(i).getName() for i in range(cs.getSize())]
    free = [n for n in names if not cs.get(n).getDefaultLocked()]
    ids = osim.InverseDynamicsSolver(model)
    nu = s.getNU()
    zero = osim.Vector(nu, 0.0)
    s.setU(zero)
    coords = [cs.get(n) for n in free]

    def resid(qv):
        for c, v in zip(coords, qv):
            c.setValue(s, float(v), False)
        model.realizeDynamics(s)
        tau = ids.solve(s, zero)
        return np.array([tau.get(i) for i in range(nu)])

    out = []
    for case in spec["cases"]:
        for axis, pf in enumerate(pfs):
            pf.setAppliesForce(s, axis == case["axis"])
        s.setTime(float(case["moment"]))
        q0 = np.array([case["q"][n] for n in free])
        q = q0.copy()
        r = resid(q)
        r0 = float(np.abs(r).max())
        it = 0
        while it == 0 or (np.abs(r).max() > 1e-10 and it < 4):
            h = 1e-7
            J = np.empty((nu, len(free)))
            for k in range(len(free)):
                dq = np.zeros(len(free))
                dq[k] = h
                J[:, k] = (resid(q + dq) - resid(q - dq)) / (2 * h)
            if J.shape[0] == J.shape[1]:
                step = np.linalg.solve(J, -r)
            else:
                step = np.linalg.lstsq(J, -r, rcond=None)[0]
            q_new = q + step
            r_new = resid(q_new)
            it += 1
            stalled = np.abs(r_new).max() > 0.5 * np.abs(r).max()
            if not stalled or it == 1:
                q, r = q_new, r_new
            if stalled:
                break
        out.append(dict(
            axis=case["axis"], moment=case["moment"],
            residual_at_tool_q=r0,
            max_abs_dq=float(np.abs(q - q0).max()),
            final_residual=float(np.abs(r).max()),
            newton_iterations=it,
            max_abs_q=float(np.abs(q0).max()),
        ))
    print(json.dumps(dict(n_free=len(free), cases=out)))


if __name__ == "__main__":
    main()
