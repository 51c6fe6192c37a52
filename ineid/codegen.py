"""Deprecated: moved to :mod:`ineid.robots.codegen` (finding or deriving generated code) and
:mod:`ineid.robots.load` (``load_robot``); this module goes in ineid 0.3."""

from __future__ import annotations

import warnings

from ineid.robots.codegen import default_codegen_dir, generate_code, generated_modules_for
from ineid.robots.load import load_robot

warnings.warn(
    "ineid.codegen moved to ineid.robots.codegen and ineid.robots.load (load_robot: ineid.load_robot or "
    "ineid.robots.load_robot); ineid.codegen is removed in ineid 0.3",
    DeprecationWarning,
    stacklevel=2,
)

__all__ = ["default_codegen_dir", "generate_code", "generated_modules_for", "load_robot"]
