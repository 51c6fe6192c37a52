"""Code emitted by :mod:`ineid.symbolic.emit`: CasADi and JAX base-wrench regressors.

Files here are generated, checked in, and never edited by hand (``make generate``
rewrites them; a test fails when they drift). This package never imports sympy.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import re
import sys
from pathlib import Path
from types import ModuleType

from ineid.errors import CodegenError, UntrustedCodeError

BUILTIN_DIR = Path(__file__).resolve().parent


SLUG_MAX = 48
"""Longest slug kept whole; a longer one is cut and suffixed with a hash of the name."""


def module_slug(robot_name: str) -> str:
    """Python module stem of a robot name: ``"sweaty-arm"`` -> ``"sweaty_arm"``.

    Safe for any name: only ``[a-z0-9_]`` (path separators, dots and spaces become ``_``),
    never empty, never starting with a digit, at most ``SLUG_MAX + 9`` characters. A
    name that is longer or not ASCII gets ``_`` and 8 hex digits of its SHA-256 appended,
    so such names stay apart.
    """
    slug = re.sub(r"[^a-z0-9_]", "_", robot_name.strip().lower())
    if not slug or slug[0].isdigit():
        slug = "robot_" + slug
    if len(slug) > SLUG_MAX or not robot_name.isascii():
        digest = hashlib.sha256(robot_name.encode("utf-8", "surrogatepass")).hexdigest()[:8]
        slug = f"{slug[:SLUG_MAX]}_{digest}"
    return slug


def file_names(robot_name: str) -> tuple[str, str]:
    """``(jax file, casadi file)`` names of a robot's generated modules."""
    slug = module_slug(robot_name)
    return f"{slug}_jax.py", f"{slug}_casadi.py"


def load_builtin(robot_name: str) -> tuple[ModuleType, ModuleType]:
    """The checked-in ``(jax module, casadi module)`` of a built-in robot."""
    slug = module_slug(robot_name)
    try:
        return (
            importlib.import_module(f"ineid.generated.{slug}_jax"),
            importlib.import_module(f"ineid.generated.{slug}_casadi"),
        )
    except ModuleNotFoundError:
        raise CodegenError(f"no generated code for built-in robot {robot_name!r}; run `make generate`") from None


def load_from_directory(
    directory: str | Path, robot_name: str, *, private: bool = False
) -> tuple[ModuleType, ModuleType] | None:
    """Import ``(jax module, casadi module)`` written by ineid into a folder; None if either is absent.

    Each file's bytes are read once and must match the SHA-256 that ineid recorded in the
    folder's manifest when it wrote them (:mod:`ineid._trust`); the module is compiled from
    those bytes, never from the path again. With ``private`` (a cache folder), each file
    must also be owned by the current user and not writable by others.

    Raises:
        UntrustedCodeError: a file fails a check (``reason`` says which); nothing was run.
        CodegenError: a verified module fails to import.
    """
    from ineid._trust import Untrusted, verified

    directory = Path(directory)
    names = file_names(robot_name)
    try:
        sources = verified(directory, names, private=private)
    except FileNotFoundError:
        return None
    except Untrusted as e:
        raise UntrustedCodeError(
            f"the generated code of {robot_name} in {directory} {e.reason}; regenerate it (ineid generate)",
            e.reason,
        ) from None
    return load_sources(directory, robot_name, sources)


def load_sources(directory: str | Path, robot_name: str, sources: dict[str, bytes]) -> tuple[ModuleType, ModuleType]:
    """``(jax module, casadi module)`` compiled from ``sources`` (``{file name: bytes}``, as
    :func:`file_names` names them), which are the contents of those files in ``directory``."""
    modules = [_module_from_source(Path(directory) / name, sources[name]) for name in file_names(robot_name)]
    return modules[0], modules[1]


_SOURCES: dict[str, bytes] = {}
"""The bytes each module of :func:`load_sources` was compiled from, by module name (:func:`module_reference`)."""


def _module_from_source(path: Path, source: bytes) -> ModuleType:
    """The module of generated code ``source`` (already checked), as if imported from ``path``."""
    key = f"ineid._user_generated.{abs(hash(str(path.resolve())))}_{path.stem}"
    spec = importlib.util.spec_from_loader(key, loader=None, origin=str(path))
    module = importlib.util.module_from_spec(spec)
    module.__file__ = str(path)
    try:
        exec(compile(source, str(path), "exec", dont_inherit=True), module.__dict__)
    except Exception as e:  # e.g. a module ineid generated from an unusable URDF
        raise CodegenError(f"generated module {str(path)!r} fails to import ({e}); regenerate it") from None
    sys.modules[key] = module
    _SOURCES[key] = source
    return module


def module_reference(module: ModuleType) -> tuple:
    """What rebuilds a generated module in another process (:func:`module_from_reference`): a built-in's
    name, or the path and the very bytes (checked when first read) of one loaded by :func:`load_sources`."""
    if module.__name__ in _SOURCES:
        return ("source", module.__file__, _SOURCES[module.__name__])
    if module.__name__.startswith(f"{__name__}."):
        return ("import", module.__name__)
    raise CodegenError(f"module {module.__name__!r} is not generated code ineid loaded; it cannot be sent to a worker")


def module_from_reference(reference: tuple) -> ModuleType:
    """The module :func:`module_reference` describes: imported again, or compiled from the same bytes."""
    if reference[0] == "import":
        return importlib.import_module(reference[1])
    key_path, source = Path(reference[1]), reference[2]
    return _module_from_source(key_path, source)
