"""SymPy derivation of the base-wrench regressor and its code printers.

Only this package imports sympy. ``ineid.generated`` holds what :mod:`.emit` writes and
never imports this package back.
"""

from ineid.symbolic.newton_euler import SymbolicRegressor, derive_base_wrench_regressor

__all__ = ["SymbolicRegressor", "derive_base_wrench_regressor"]
