"""A Python function of IPOPT's variables as a CasADi function, with its exact Jacobian.

The excitation criterion (:class:`ineid.excite.trajectory.DesignProblem`) and the floor, box and
self-collision constraints (:class:`ineid.excite.safety.SafetyConstraints`) are NumPy and JAX code
that CasADi cannot trace: :func:`numpy_function` wraps each as a :class:`casadi.Callback` whose
Jacobian is a second callback (CasADi's finite differences off), so IPOPT sees the exact derivative.
Neither callback caches: the functions wrapped keep their own last evaluation (the value and the
Jacobian of one iterate share the forward kinematics or the regressor).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np


def numpy_function(
    name: str,
    n_in: int,
    n_out: int,
    value: Callable[[np.ndarray], np.ndarray | float],
    jacobian: Callable[[np.ndarray], np.ndarray],
):
    """``x -> value(x)`` as a CasADi function whose Jacobian is ``jacobian(x)``.

    Args:
        name: the CasADi function's name.
        n_in: the length of ``x`` (a dense column).
        n_out: the length of ``value(x)`` (a dense column; 1: a scalar).
        value: ``x`` (n_in,) float64 -> (n_out,) or a float.
        jacobian: ``x`` (n_in,) -> the derivative of ``value``, ``n_out * n_in`` numbers in row order
            ((n_out, n_in), or (n_in,) when ``n_out`` is 1).

    Returns:
        A :class:`casadi.Callback` (it keeps its Jacobian's alive); CasADi does not own Python callbacks, so the
        caller keeps it alive as long as any function built on it (``keep`` of :func:`ineid.identify.ipopt.nlpsol`).
    """
    import casadi as ca

    def column(n: int):
        return ca.Sparsity.dense(n, 1)

    class Jacobian(ca.Callback):
        """``(x, value) -> d value / d x`` (n_out, n_in); the nominal output is CasADi's convention."""

        def __init__(self, name, opts):
            ca.Callback.__init__(self)
            self.construct(name, opts)

        def get_n_in(self):
            return 2

        def get_n_out(self):
            return 1

        def get_sparsity_in(self, i):
            return column(n_in) if i == 0 else column(n_out)

        def get_sparsity_out(self, i):
            return ca.Sparsity.dense(n_out, n_in)

        def eval(self, arg):
            jac = np.asarray(jacobian(np.asarray(arg[0]).ravel()))
            return [ca.DM(jac.reshape(n_out, n_in))]

    class Value(ca.Callback):
        """``x -> value(x)``, with :class:`Jacobian` as its exact derivative."""

        def __init__(self, name, opts):
            ca.Callback.__init__(self)
            self._jac = None
            self.construct(name, opts)

        def get_n_in(self):
            return 1

        def get_n_out(self):
            return 1

        def get_sparsity_in(self, i):
            return column(n_in)

        def get_sparsity_out(self, i):
            return column(n_out)

        def eval(self, arg):
            return [ca.DM(value(np.asarray(arg[0]).ravel()))]

        def has_jacobian(self):
            return True

        def get_jacobian(self, name, inames, onames, opts):
            self._jac = Jacobian(name, opts)
            return self._jac

    return Value(name, {"enable_fd": False})
