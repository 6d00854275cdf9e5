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
from moment_loading import MomentModel, newton

osim.Logger.setLevelString("error")


def main():
    model_path, cases_path = sys.argv[1], sys.argv[2]
    spec = json.load(open(cases_path))
    mm = MomentModel(model_path, spec["body"], gravity_off=True)

    def resid(qv):
        mm.set_q(qv)
        return mm.tau()

    def jac(q):
        return mm.jacobian(resid, q)

    out = []
    for case in spec["cases"]:
        for axis, pf in enumerate(mm.pfs):
            pf.setAppliesForce(mm.s, axis == case["axis"])
        mm.s.setTime(float(case["moment"]))
        q0 = np.array([case["q"][n] for n in mm.free])
        r = resid(q0)
        r0 = float(np.abs(r).max())
        q, r, it = newton(resid, jac, q0.copy(), r)
        out.append(dict(
            axis=case["axis"], moment=case["moment"],
            residual_at_tool_q=r0,
            max_abs_dq=float(np.abs(q - q0).max()),
            final_residual=float(np.abs(r).max()),
            newton_iterations=it,
            max_abs_q=float(np.abs(q0).max()),
        ))
    print(json.dumps(dict(n_free=len(mm.free), cases=out)))


if __name__ == "__main__":
    main()
