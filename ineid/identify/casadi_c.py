"""The CasADi route compiled to C: normal-equation blocks from a generated, compiled C function.

The generated CasADi regressor is an SX graph that CasADi evaluates in its virtual machine.
CasADi can also print a ``Function`` as C (``Function.generate``); compiled with the system's
C compiler and loaded back (``casadi.external``), the same arithmetic runs natively. This
module builds one such function per robot, link split, base structure and frame count:

    blocks(q, qd, qdd, wrench, theta_known) -> (G, h, e)     for a chunk of configurations

with ``G_a = sum_k W_b[k, a]^T W_b[k, a]``, ``h_a = sum_k W_b[k, a]^T y[k, a]`` and
``e_a = sum_k y[k, a]^2`` exactly as :func:`ineid.identify.fused.information_blocks` (the
JAX route) defines them, so the same solver (:func:`ineid.identify.linear.fit_base_blocks`)
finishes both. The compiled library is cached in ``<cache>/casadi-c/`` keyed by a hash of
the function and the compiler command, so only the first run pays the compiler (seconds);
its own SHA-256, recorded when it is compiled, is checked before it is loaded.

This is an option (``SolveSettings(backend="casadi-c")``, ``ineid solve --backend
casadi-c``): the default route needs no compiler.
"""

from __future__ import annotations

import hashlib
import logging
import os
import shlex
import shutil
import subprocess
import tempfile
import threading
from pathlib import Path

import numpy as np

from ineid._temporary import create_temporary
from ineid._trust import Untrusted, opened, read_checked, recorded_hashes, sha256, write_manifest
from ineid.cache import cache_dir, private_folder  # noqa: F401  (cache_dir: tests find the libraries)
from ineid.errors import CodegenError

log = logging.getLogger(__name__)

CONFIGS_PER_CALL = 64
"""Configurations per call of the compiled function (one C loop over them)."""
CFLAGS = ("-O2", "-fPIC", "-shared")


def c_compiler() -> str | None:
    """The C compiler: ``$CC``, else the first of ``cc``, ``gcc``, ``clang`` on ``PATH``."""
    env = os.environ.get("CC")
    if env:
        return env
    for name in ("cc", "gcc", "clang"):
        path = shutil.which(name)
        if path:
            return path
    return None


def compile_function(fn, compiler: str | None = None):
    """``fn`` (a ``casadi.Function``) printed as C, compiled and loaded: the same function, native.

    The shared library is cached in ``<cache>/casadi-c/<name>_<hash>.so``; the hash covers the
    C source and the compiler command, so a changed function or compiler compiles again.
    Beside it, ``<name>_<hash>.json`` records the library's SHA-256 when ineid compiles it;
    a cached library is loaded only when it is owned by you, not writable by others, in a
    private cache folder, and its bytes match that record (see :mod:`ineid._trust`);
    otherwise it is compiled again, with one warning line saying why.

    Raises:
        CodegenError: no C compiler, or the compiler failed.
    """
    import casadi as ca

    cc = compiler or c_compiler()
    if cc is None:
        raise CodegenError(
            "the casadi-c backend needs a C compiler (cc, gcc or clang on PATH, or $CC); "
            "install one or use the default backend"
        )
    name = fn.name()
    with tempfile.TemporaryDirectory(prefix="ineid-casadi-c-") as tmp:
        source = Path(tmp) / f"{name}.c"
        cg = ca.CodeGenerator(source.name, {"with_header": False, "casadi_real": "double"})
        cg.add(fn)
        cg.generate(str(Path(tmp)) + os.sep)
        text = source.read_bytes()
        key = hashlib.sha256(text + " ".join((cc, *CFLAGS)).encode()).hexdigest()[:16]
        folder = private_folder("casadi-c")
        library = folder / f"{name}_{key}.so"
        record = f"{library.stem}.json"
        if library.exists() or library.is_symlink():
            try:
                loaded = _load_checked(name, library, record)
                log.info("compiled CasADi function %s found in %s", name, library)
                return loaded
            except Untrusted as e:
                log.warning(
                    "the cached compiled CasADi function %s in %s %s; compiling it again", name, folder, e.reason
                )
        partial = create_temporary(library)
        cmd = [*shlex.split(cc), *CFLAGS, "-o", str(partial), str(source)]
        log.info("compiling CasADi function %s: %s", name, " ".join(cmd))
        try:
            done = subprocess.run(cmd, capture_output=True, text=True, check=False)
        except OSError as exc:
            raise CodegenError(f"the C compiler {cc!r} cannot run ({exc.strerror}); install one or set $CC") from None
        if done.returncode != 0:
            partial.unlink(missing_ok=True)
            first = (done.stderr.strip().splitlines() or ["no message"])[0]
            raise CodegenError(f"the C compiler {cc!r} failed on {name}.c: {first}")
        try:
            data = read_checked(partial, private=True)
        except Untrusted as e:  # the compiler's output in our private folder: not expected
            partial.unlink(missing_ok=True)
            raise CodegenError(f"the compiled library {partial} {e.reason}; run again") from None
        if library.is_dir() and not library.is_symlink():
            shutil.rmtree(library)
        os.replace(partial, library)
        write_manifest(folder, {library.name: data}, private=True, manifest=record)
    try:
        return _load_checked(name, library, record)
    except Untrusted as e:
        raise CodegenError(f"the compiled library {library} {e.reason} right after compiling; run again") from None


def _load_checked(name: str, library: Path, record: str):
    """``casadi.external`` of ``library`` after :mod:`ineid._trust`'s checks, from the bytes checked.

    Where ``/proc/self/fd`` exists the library is loaded through the open descriptor whose
    bytes were hashed (a link to it, removed right after), so a file swapped between the
    check and the load is never the one loaded.

    Raises:
        Untrusted: ownership, permissions or hash do not pass.
    """
    import casadi as ca

    hashes = recorded_hashes(library.parent, private=True, manifest=record)
    with opened(library, private=True) as (fd, data):
        if hashes.get(library.name) != sha256(data):
            raise Untrusted(f"does not match its record {record} ({library.name} was modified after ineid compiled it)")
        proc = Path(f"/proc/self/fd/{fd}")
        if not proc.exists():
            return ca.external(name, str(library))
        link = library.with_name(f".{library.stem}.{os.getpid()}.{threading.get_ident()}.so")
        link.unlink(missing_ok=True)
        os.symlink(proc, link)
        try:
            return ca.external(name, str(link))
        finally:
            link.unlink(missing_ok=True)


def _frame_blocks(model, base):
    """Per-frame ``(G (r x 6r), h (r x 6), e (1 x 6))`` of one frame as a CasADi ``Function``."""
    import casadi as ca

    n = model.n_dof
    q, qd, qdd = (ca.SX.sym(s, n) for s in ("q", "qd", "qdd"))
    wrench = ca.SX.sym("wrench", 6)
    known = np.asarray(model.known_index)
    theta_known = ca.SX.sym("theta_known", len(known))
    psi = model.casadi_regressor(q, qd, qdd)  # 6 x 10 n_links
    columns = [int(c) for c in np.asarray(model.unknown_index)[base.base_index]]
    w_b = psi[:, columns]  # 6 x r
    y = wrench - (ca.mtimes(psi[:, [int(k) for k in known]], theta_known) if len(known) else 0)
    g = ca.horzcat(*[ca.mtimes(w_b[a, :].T, w_b[a, :]) for a in range(6)])  # r x 6r
    h = ca.horzcat(*[w_b[a, :].T * y[a] for a in range(6)])  # r x 6
    e = (y * y).T  # 1 x 6
    return ca.Function("ineid_frame_blocks", [q, qd, qdd, wrench, theta_known], [g, h, e])


_LOADED: dict[tuple, object] = {}


def _chunk_function(model, base, n_frames: int):
    """Compiled ``(q, qd, qdd, wrench)`` of CONFIGS_PER_CALL x n_frames frames -> summed blocks."""
    base_key = (tuple(base.base_index.tolist()), base.rank)
    key = (id(model), base_key, n_frames)
    if key not in _LOADED:
        _LOADED[key] = (model, _build_chunk_function(model, base, base_key, n_frames))
    return _LOADED[key][1]


def _build_chunk_function(model, base, base_key: tuple, n_frames: int):
    frame = _frame_blocks(model, base)
    # sum over the frames of a configuration (theta_known shared), then one column block per configuration
    per_config = frame.map(n_frames, [False, False, False, False, True], [True, True, True])
    per_chunk = per_config.map(CONFIGS_PER_CALL, [False, False, False, False, True], [False, False, False])
    tag = hashlib.sha256(f"{model.name}:{model.unknown_links}:{base_key}:{n_frames}".encode()).hexdigest()[:10]
    import casadi as ca

    args = [ca.MX.sym(s, *per_chunk.size_in(i)) for i, s in enumerate(("q", "qd", "qdd", "wrench", "theta_known"))]
    named = ca.Function(f"ineid_blocks_{tag}", args, per_chunk(*args))
    return compile_function(named)


def information_blocks_c(model, base, q, qd, qdd, wrench, theta_known, progress=None):
    """:func:`ineid.identify.fused.information_blocks` through compiled C (same numbers, round-off).

    Args and result as there: (C, F, n_dof) frames, (C, F, 6) wrench -> ``InformationBlocks``.
    """
    from ineid.identify.fused import InformationBlocks

    q, qd, qdd, wrench = (np.asarray(a, dtype=np.float64) for a in (q, qd, qdd, wrench))
    c, f, n = q.shape
    r = base.rank
    fn = _chunk_function(model, base, f)
    theta_known = np.asarray(theta_known, dtype=np.float64)
    g_out, h_out, e_out = np.empty((c, 6, r, r)), np.empty((c, 6, r)), np.empty((c, 6))
    k = CONFIGS_PER_CALL
    for start in range(0, c, k):
        stop = min(start + k, c)
        parts = [a[start:stop] for a in (q, qd, qdd, wrench)]
        if stop - start < k:  # pad with copies of the last configuration (one compiled shape)
            parts = [np.concatenate([p, np.repeat(p[-1:], k - len(p), axis=0)]) for p in parts]
        # columns: configuration-major, frame-minor (the map's order)
        cols = [p.reshape(k * f, -1).T for p in parts]
        g, h, e = fn(*cols, theta_known)
        m = stop - start
        g = np.asarray(g).reshape(r, k, 6, r)  # (r, configs, axis, r): column blocks per configuration
        g_out[start:stop] = g.transpose(1, 2, 0, 3)[:m]
        h_out[start:stop] = np.asarray(h).reshape(r, k, 6).transpose(1, 2, 0)[:m]
        e_out[start:stop] = np.asarray(e).reshape(k, 6)[:m]
        if progress is not None:
            progress(stop, c)
    return InformationBlocks(g_out, h_out, e_out, f)
