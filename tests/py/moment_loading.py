"""Shared OpenSim set-up and Newton check for the equilibrium scripts
(stiffness_equilibria.py, loaded_equilibrium.py): a model with every
non-bushing force (muscles) switched off, three PrescribedForces on body TOP
whose torque about ground axis k is the time t (so setting the time sets the
moment magnitude), the free coordinates looked up once, and the generalised
force residual r(q) = InverseDynamicsSolver(q, u=0, udot=0).
"""
import numpy as np
import opensim as osim


class MomentModel:
    def __init__(self, model_path, body, gravity_off):
        self.model = osim.Model(model_path)
        if gravity_off:
            self.model.setGravity(osim.Vec3(0, 0, 0))
        fs = self.model.getForceSet()
        for i in range(fs.getSize()):
            if "Bushing" not in fs.get(i).getConcreteClassName():
                fs.get(i).set_appliesForce(False)  # muscles: not modelled by the tool
        top = self.model.getBodySet().get(body)
        self.pfs = []
        for axis in range(3):
            pf = osim.PrescribedForce(f"load_{axis}", top)
            pf.setForceIsInGlobalFrame(True)
            fns = []
            for k in range(3):
                f = osim.LinearFunction(1.0, 0.0) if k == axis else osim.Constant(0.0)
                f.thisown = False
                fns.append(f)
            pf.setTorqueFunctions(*fns)
            self.model.addForce(pf)
            self.pfs.append(pf)
        self.s = self.model.initSystem()
        cs = self.model.getCoordinateSet()
        names = [cs.get(i).getName() for i in range(cs.getSize())]
        self.free = [n for n in names if not cs.get(n).getDefaultLocked()]
        self.coords = [cs.get(n) for n in self.free]
        self.ids = osim.InverseDynamicsSolver(self.model)
        self.nu = self.s.getNU()
        self.zero = osim.Vector(self.nu, 0.0)
        self.s.setU(self.zero)

    def set_q(self, qv):
        for c, v in zip(self.coords, qv):
            c.setValue(self.s, float(v), False)

    def tau(self):
        """Generalised force residual with the forces applied now."""
        self.model.realizeDynamics(self.s)
        t = self.ids.solve(self.s, self.zero)
        return np.array([t.get(i) for i in range(self.nu)])

    def jacobian(self, resid, q, h=1e-7):
        J = np.empty((self.nu, len(q)))
        for k in range(len(q)):
            dq = np.zeros(len(q))
            dq[k] = h
            J[:, k] = (resid(q + dq) - resid(q - dq)) / (2 * h)
        return J


def newton(resid, jac, q, r, J=None):
    """Newton steps from q (residual r): at least one, then until the
    residual is below 1e-10, at most 4, stopping when a step no longer
    halves the residual (OpenSim's rounding floor); the first step is always
    taken, later ones only when they improve. `J` is the Jacobian at q when
    already known. Returns (q, r, iterations)."""
    it = 0
    while it == 0 or (np.abs(r).max() > 1e-10 and it < 4):
        if J is None or it > 0:
            J = jac(q)
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
    return q, r, it
