"""What a generated module may contain, checked on its text before anything imports it.

Names from a URDF (robot, links, joints) reach a generated module only as escaped string
literals; this check is the second line of defence: it parses the text (nothing runs)
and refuses any module whose top level is not exactly the emitter's shape, so a name
that escaped its literal (a newline in a comment, a closed docstring) cannot add a
statement that runs on import.
"""

from __future__ import annotations

import ast

from ineid.chain import check_parents
from ineid.errors import CodegenError

_IMPORTS = {"jax": (("jax.numpy", "jnp"), ("jax", None)), "casadi": (("casadi", "ca"),)}
"""Per kind, the imports allowed, each once (``import module as alias``; ``import module`` where the alias is
None). ``import jax`` gives the JAX program its ``jax.lax.optimization_barrier``."""
_CONSTANTS = {
    "ROBOT",
    "N_DOF",
    "JOINT_NAMES",
    "LINK_NAMES",
    "JOINT_TYPES",
    "KINEMATIC_FINGERPRINT",
    "OP_COUNT",
    "SHAPE",
    "NONZERO",
}
_OPTIONAL = {"PARENTS"}
"""Constants a module may lack: without ``PARENTS`` the chain is serial, ``(-1, 0, 1, ...)``."""
_FUNCTIONS = {"program"}


def check_module_source(text: str, kind: str, where: str = "generated module") -> dict[str, object]:
    """Parse a generated module's text (without running it) and check its top level.

    Allowed, each once: the module docstring first; ``import jax.numpy as jnp`` and ``import
    jax`` (``kind "jax"``) or ``import casadi as ca`` (``"casadi"``); the constants (``ROBOT``,
    ``JOINT_NAMES``, ...) assigned literal values of the emitter's shape; the emitter's one
    function, ``program``, without decorators, defaults or annotations (they would run on
    import). Nothing else, so importing the module runs no code of its own.

    Returns:
        ``{constant: value}``, the literal constants (``ROBOT``, ``JOINT_NAMES``, ...).

    Raises:
        CodegenError: the text does not parse or holds anything else.
    """
    constants, functions = _CONSTANTS, _FUNCTIONS
    if kind not in _IMPORTS:
        raise ValueError(f"kind must be one of {', '.join(_IMPORTS)}, got {kind!r}")
    try:
        tree = ast.parse(text)
    except (SyntaxError, ValueError) as e:
        raise CodegenError(f"{where} is not valid Python ({e}); regenerate it") from None
    values: dict[str, object] = {}
    defined: set[str] = set()
    for k, node in enumerate(tree.body):
        problem = _problem(node, k, kind, constants | _OPTIONAL, functions, values)
        name = _defined_name(node)
        if problem is None and name is not None and name in defined:
            problem = f"{name} is defined twice"
        if problem is not None:
            raise CodegenError(
                f"{where} has an unexpected statement at line {node.lineno} ({problem}); "
                "it was not imported; regenerate it"
            )
        if name is not None:
            defined.add(name)
    missing = sorted((constants | functions) - defined)
    if missing:
        raise CodegenError(f"{where} lacks {', '.join(missing)}; regenerate it")
    problem = _constants_problem(values)
    if problem is not None:
        raise CodegenError(f"{where} has {problem}; it was not imported; regenerate it")
    return values


def _constants_problem(values: dict[str, object]) -> str | None:
    """Why the constants do not have the emitter's types and sizes, or None."""
    n = values["N_DOF"]
    if not isinstance(n, int) or isinstance(n, bool) or n < 1:
        return f"N_DOF = {n!r}, not a positive integer"
    for key in ("JOINT_NAMES", "LINK_NAMES", "JOINT_TYPES"):
        v = values[key]
        if not (isinstance(v, tuple) and len(v) == n and all(isinstance(x, str) for x in v)):
            return f"{key} that is not {n} names"
    if not isinstance(values["ROBOT"], str) or not isinstance(values["KINEMATIC_FINGERPRINT"], str):
        return "a ROBOT or KINEMATIC_FINGERPRINT that is not a string"
    if any(t not in ("revolute", "prismatic") for t in values["JOINT_TYPES"]):
        return "a joint type other than revolute and prismatic"
    if values["SHAPE"] != (6, 10 * n):
        return f"SHAPE = {values['SHAPE']!r}, not (6, {10 * n})"
    nz = values["NONZERO"]
    ok = (
        isinstance(nz, tuple)
        and len(nz) == 6
        and all(isinstance(row, tuple) and all(isinstance(c, int) and 0 <= c < 10 * n for c in row) for row in nz)
    )
    if not ok or not isinstance(values["OP_COUNT"], int):
        return "a NONZERO or OP_COUNT of the wrong shape"
    parents = values.get("PARENTS", tuple(range(-1, n - 1)))
    if not isinstance(parents, tuple) or check_parents(parents, n) is not None:
        return "PARENTS that are not a joint before each joint (or -1)"
    return None


def _import_text(module: str, alias: str | None) -> str:
    return f"import {module}" + ("" if alias is None else f" as {alias}")


def _defined_name(node: ast.stmt) -> str | None:
    if isinstance(node, ast.FunctionDef):
        return node.name
    if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
        return node.targets[0].id
    if isinstance(node, ast.Import) and len(node.names) == 1:
        return "import " + node.names[0].name
    return None


def _problem(
    node: ast.stmt, index: int, kind: str, constants: set[str], functions: set[str], values: dict[str, object]
) -> str | None:
    """Why ``node`` may not be at the top level of a ``kind`` module, or None if it may."""
    if isinstance(node, ast.Expr):
        ok = index == 0 and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str)
        return None if ok else "an expression other than the docstring"
    if isinstance(node, ast.Import):
        allowed = _IMPORTS[kind]
        ok = len(node.names) == 1 and (node.names[0].name, node.names[0].asname) in allowed
        return None if ok else "an import other than " + " or ".join(f"`{_import_text(*a)}`" for a in allowed)
    if isinstance(node, ast.FunctionDef):
        args = node.args
        if node.name not in functions:
            return f"a function {node.name!r} the emitter does not write"
        every = [*args.posonlyargs, *args.args, *args.kwonlyargs, args.vararg, args.kwarg]
        annotated = node.returns is not None or any(a is not None and a.annotation is not None for a in every)
        if node.decorator_list or args.defaults or any(d is not None for d in args.kw_defaults) or annotated:
            return f"function {node.name} has decorators, defaults or annotations (they run on import)"
        return None
    if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
        name = node.targets[0].id
        if name in constants:
            try:
                values[name] = ast.literal_eval(node.value)
            except (ValueError, TypeError, SyntaxError, MemoryError, RecursionError):
                return f"{name} is not assigned a literal value"
            return None
        return f"an assignment to {name!r}"
    return f"a {type(node).__name__} statement"
