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
from moment_loading import MomentModel, newton

osim.Logger.setLevelString("error")


def main():
    model_path, cases_path = sys.argv[1], sys.argv[2]
    spec = json.load(open(cases_path))
    mm = MomentModel(model_path, spec["body"], gravity_off=False)
    s, pfs = mm.s, mm.pfs
    out = []
    for case in spec["cases"]:
        m = case["moment"]

        def resid(qv):
            # gravity and bushings, then one moment component at a time
            # (time carries its magnitude)
            mm.set_q(qv)
            for pf in pfs:
                pf.setAppliesForce(s, False)
            s.setTime(0.0)
            base = mm.tau()
            r = base.copy()
            for axis in range(3):
                if m[axis] == 0.0:
                    continue
                for k, p in enumerate(pfs):
                    p.setAppliesForce(s, k == axis)
                s.setTime(float(m[axis]))
                r += mm.tau() - base
            return r

        def jac(q):
            return mm.jacobian(resid, q)

        q0 = np.array([case["q"][n] for n in mm.free])
        r = resid(q0)
        r0 = float(np.abs(r).max())
        J0 = jac(q0)
        # OpenSim's ID residual is M udot - applied = -applied: J0 = -d tau/d q
        # of the tool's convention, so the stiffness is K = J0 here.
        K = 0.5 * (J0 + J0.T)
        asym = float(np.abs(J0 - J0.T).max() / np.abs(J0).max())
        min_eig = float(np.linalg.eigvalsh(K).min())
        q, r, it = newton(resid, jac, q0.copy(), r, J0)
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
    print(json.dumps(dict(n_free=len(mm.free), cases=out)))


if __name__ == "__main__":
    main()
