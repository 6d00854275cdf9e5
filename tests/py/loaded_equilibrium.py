"""OpenSim 4.6's check of static equilibria under gravity and a pure moment.

Usage: loaded_equilibrium.py MODEL CASES.json

CASES.json: {"body": TOP, "cases": [{"moment": [mx, my, mz], "q":
{coordinate: value}}]}: gravity as in the model (kept on), a pure moment
(N m, ground axes) on body TOP through a PrescribedForce, and a candidate
equilibrium q (the tool's). Every force that is not a bushing (muscles) is
switched off. For each case OpenSim's own forces decide: the generalised
force residual r(q) = InverseDynamicsSolver(q, u=0, udot=0), its Jacobian
J by central differences (h = 1e-7) at the tool's q, and Newton steps from
q (at most 4, stopping when the residual is below 1e-10 or a step no longer
halves it). Prints JSON per case: the largest |residual| at the tool's q,
the largest |q_opensim - q|, the final residual, and, for the stability
test, the asymmetry of J (max |J - J^T| / max |J|) and the smallest
eigenvalue of -(J + J^T) / 2 (positive: a stable equilibrium when J is
symmetric, i.e. the loads are conservative).
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
    fs = model.getForceSet()
    for i in range(fs.getSize()):
        if "Bushing" not in fs.get(i).getConcreteClassName():
            fs.get(i).set_appliesForce(False)  # muscles: not modelled by the tool
    top = model.getBodySet().get(spec["body"])
    pfs = []
    for axis in range(3):
        pf = osim.PrescribedForce(f"load_{axis}", top)
        pf.setForceIsInGlobalFrame(True)
        fns = []
        for k in range(3):
            # torque = t * e_axis, evaluated at time t = the moment component
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
    out = []
    for case in spec["cases"]:
        m = case["moment"]

        def resid(qv):
            r = np.zeros(nu)
            # one moment component at a time (time carries its magnitude)
            for c, v in zip(coords, qv):
                c.setValue(s, float(v), False)
            for axis, pf in enumerate(pfs):
                pf.setAppliesForce(s, False)
            s.setTime(0.0)
            model.realizeDynamics(s)
            tau = ids.solve(s, zero)
            base = np.array([tau.get(i) for i in range(nu)])
            r += base
            for axis, pf in enumerate(pfs):
                if m[axis] == 0.0:
                    continue
                for k, p in enumerate(pfs):
                    p.setAppliesForce(s, k == axis)
                s.setTime(float(m[axis]))
                model.realizeDynamics(s)
                tau = ids.solve(s, zero)
                r += np.array([tau.get(i) for i in range(nu)]) - base
            return r

        def jac(q):
            h = 1e-7
            J = np.empty((nu, len(free)))
            for k in range(len(free)):
                dq = np.zeros(len(free))
                dq[k] = h
                J[:, k] = (resid(q + dq) - resid(q - dq)) / (2 * h)
            return J

        q0 = np.array([case["q"][n] for n in free])
        q = q0.copy()
        r = resid(q)
        r0 = float(np.abs(r).max())
        J0 = jac(q)
        # OpenSim's ID residual is M udot - applied = -applied: J0 = -d tau/d q
        # of the tool's convention, so the stiffness is K = J0 here.
        K = 0.5 * (J0 + J0.T)
        asym = float(np.abs(J0 - J0.T).max() / np.abs(J0).max())
        min_eig = float(np.linalg.eigvalsh(K).min())
        it = 0
        J = J0
        while it == 0 or (np.abs(r).max() > 1e-10 and it < 4):
            if it > 0:
                J = jac(q)
            step = np.linalg.solve(J, -r)
            q_new = q + step
            r_new = resid(q_new)
            it += 1
            stalled = np.abs(r_new).max() > 0.5 * np.abs(r).max()
            if not stalled or it == 1:
                q, r = q_new, r_new
            if stalled:
                break
        out.append(dict(
            moment=m,
            residual_at_tool_q=r0,
            max_abs_dq=float(np.abs(q - q0).max()),
            final_residual=float(np.abs(r).max()),
            newton_iterations=it,
            max_abs_q=float(np.abs(q0).max()),
            jacobian_asymmetry=asym,
            min_stiffness_eigenvalue=min_eig,
        ))
    print(json.dumps(dict(n_free=len(free), cases=out)))


if __name__ == "__main__":
    main()
