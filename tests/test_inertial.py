"""Mass distribution online (issue 22 part 3): inertial NLP parameters against pinocchio on an edited model,
and the online estimator recovering a known base CoM offset / payload."""

import casadi as ca
import numpy as np
import pinocchio as pin

from wbmpc.bench.dynamics import random_samples, world_forces_to_pinocchio
from wbmpc.symbolic import InertialParameters, Motion, SymbolicDynamics


def _symbolic(robot):
    dyn = SymbolicDynamics(robot)
    q, v, a = ca.SX.sym("q", robot.nq), ca.SX.sym("v", robot.nv), ca.SX.sym("a", robot.nv)
    f, dc, m_p = ca.SX.sym("f", dyn.n_forces), ca.SX.sym("dc", 3), ca.SX.sym("m_p")
    cfg = dyn.configuration(q)
    nominal = ca.Function("nominal", [q, v, a, f], [dyn.rnea(cfg, Motion(cfg, v), a, f), dyn.mass_matrix(cfg)])
    cfg = dyn.configuration(q)
    cfg.inertial = InertialParameters(dc, m_p)
    edited = ca.Function("edited", [q, v, a, f, dc, m_p], [dyn.rnea(cfg, Motion(cfg, v), a, f), dyn.mass_matrix(cfg)])
    return dyn, nominal, edited


def test_inertial_parameters_match_pinocchio_on_an_edited_model(b1z1):
    """RNEA and CRBA with a base CoM offset and a hand payload change exactly as pinocchio's on the edited
    model; zero parameters give today's functions."""
    dyn, nominal, edited = _symbolic(b1z1)
    offset, payload = np.array([-0.05, 0.02, 0.01]), 5.0
    model = InertialParameters.apply_to(b1z1, offset, payload)
    data_nominal, data_edited = b1z1.model.createData(), model.createData()
    for s in random_samples(b1z1, dyn.n_forces, 5, seed=11):
        q, v, a, f = s["q"], s["v"], s["a"], s["f"]
        tau0, mass0 = (np.array(x) for x in nominal(q, v, a, f))
        tau_zero, mass_zero = (np.array(x) for x in edited(q, v, a, f, np.zeros(3), 0.0))
        np.testing.assert_allclose(tau_zero, tau0, atol=1e-9)
        np.testing.assert_allclose(mass_zero, mass0, atol=1e-9)
        tau1, mass1 = (np.array(x) for x in edited(q, v, a, f, offset, payload))
        pin.framesForwardKinematics(b1z1.model, data_nominal, q)
        fext = world_forces_to_pinocchio(b1z1, data_nominal, f)
        reference = pin.rnea(model, data_edited, q, v, a, fext) - pin.rnea(b1z1.model, data_nominal, q, v, a, fext)
        np.testing.assert_allclose((tau1 - tau0).ravel(), reference, atol=1e-9 * max(1.0, np.abs(reference).max()))
        mass_ref = pin.crba(model, data_edited, q) - pin.crba(b1z1.model, data_nominal, q)
        np.testing.assert_allclose(np.triu(mass1 - mass0), np.triu(mass_ref), atol=1e-9)
