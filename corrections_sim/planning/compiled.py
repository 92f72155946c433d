"""CasADi functions compiled to C by gcc, cached on disk, and called through ctypes.

A call of a CasADi ``Function`` from Python costs ≈ 0.1 ms plus ≈ 0.25 ms to convert its
outputs, more than a small compiled evaluation itself; :class:`Compiled` calls the generated
C entry point with preallocated buffers instead (≈ 5 µs of overhead).
"""

from __future__ import annotations

import ctypes
import fcntl
import hashlib
import os
import subprocess
import tempfile
import threading
from collections.abc import Callable
from pathlib import Path

import casadi as ca
import numpy as np

from corrections_sim.planning.cache import mark_used

#: How gcc builds every library here.
GCC_FLAGS = ("-O1", "-fPIC", "-shared")


class Compiled:
    """A CasADi function compiled to C and called through ctypes (one set of buffers per
    thread); ``jit = False`` calls the CasADi function instead."""

    def __init__(self, fn: ca.Function, library: Path | None) -> None:
        self._fn = fn
        self._sizes_in = [fn.nnz_in(i) for i in range(fn.n_in())]
        self._sizes_out = [fn.nnz_out(i) for i in range(fn.n_out())]
        self._local = threading.local()
        self._call = None
        if library is not None:
            lib = ctypes.CDLL(str(library))
            call = getattr(lib, fn.name())
            call.restype = ctypes.c_int
            call.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p]
            call.argtypes.append(ctypes.c_int)
            sizes = [ctypes.c_longlong() for _ in range(4)]
            work = getattr(lib, f"{fn.name()}_work")
            if work(*(ctypes.byref(s) for s in sizes)) != 0:
                raise RuntimeError(f"{library}: the compiled function refused its work sizes")
            self._work = [s.value for s in sizes]
            self._lib, self._call = lib, call

    def _buffers(self):
        b = getattr(self._local, "buffers", None)
        if b is None:
            n_arg, n_res, n_iw, n_w = self._work
            ins = [np.zeros(n) for n in self._sizes_in]
            outs = [np.zeros(n) for n in self._sizes_out]
            arg = (ctypes.c_void_p * max(n_arg, len(ins)))(*(a.ctypes.data for a in ins))
            res = (ctypes.c_void_p * max(n_res, len(outs)))(*(o.ctypes.data for o in outs))
            iw = np.zeros(max(n_iw, 1), dtype=np.int64)
            w = np.zeros(max(n_w, 1))
            b = self._local.buffers = (ins, outs, arg, res, iw, w)
        return b

    def __call__(self, *inputs: np.ndarray) -> list[np.ndarray]:
        """The outputs' nonzeros (copies), in CasADi's column-major order."""
        if self._call is None:
            out = self._fn(*inputs)  # one output comes back alone, not in a list
            return [np.array(o.nonzeros()) for o in ([out] if self._fn.n_out() == 1 else out)]
        ins, outs, arg, res, iw, w = self._buffers()
        for buffer, value in zip(ins, inputs, strict=True):
            buffer[:] = value
        if self._call(arg, res, iw.ctypes.data, w.ctypes.data, 0) != 0:
            raise RuntimeError(f"{self._fn.name()}: the compiled evaluation failed")
        return [o.copy() for o in outs]


def build_once(path: Path, build: Callable[[Path], None]) -> None:
    """``build(path)`` unless ``path`` exists, by one process of the machine at a time: the
    others wait on a lock beside it (``path.lock``) and then find the file made. ``build``
    writes atomically, so a reader that takes no lock never sees half a file; the lock spares
    two processes (two test workers on a fresh machine) the same minutes of gcc."""
    if path.is_file():
        mark_used(path)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_name(path.name + ".lock"), "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not path.is_file():
                build(path)
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def compile_library(
    functions: list[ca.Function], library: Path, with_source: tuple[str, bytes] | None = None
) -> None:
    """C code of ``functions`` compiled by gcc into ``library`` (atomically), with one more C
    source ``with_source`` = (file name, text) that may call them."""
    library.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=library.parent) as scratch:
        source = Path(scratch) / "generated.c"
        generator = ca.CodeGenerator(source.name, {"with_header": False})
        for fn in functions:
            generator.add(fn)
        generator.generate(f"{scratch}{os.sep}")
        sources = [source]
        if with_source is not None:
            sources.append(Path(scratch) / with_source[0])
            sources[-1].write_bytes(with_source[1])
        build_shared_library(sources, library)


class BuildError(RuntimeError):
    """gcc could not build a library: one line naming it and gcc's first error (a command
    prints it as its one-line error, exit status 1)."""


def build_shared_library(sources: Path | list[Path], library: Path) -> None:
    """gcc ``sources`` (C) into ``library``: built beside the first and moved into place at
    once, so a process that finds the library never loads half a file.

    Raises:
        BuildError: no gcc on the PATH, or gcc refused the sources (the library's name and
            gcc's first error line; nothing is left at ``library``).
    """
    sources = [sources] if isinstance(sources, Path) else sources
    tmp = sources[0].parent / library.name
    try:
        subprocess.run(
            ["gcc", *GCC_FLAGS, *map(str, sources), "-o", str(tmp), "-lm"],
            check=True,
            capture_output=True,
        )
    except FileNotFoundError:
        raise BuildError(
            f"{library.name}: no gcc on the PATH to build it (the planner's compiled code "
            "needs a C compiler: install gcc)"
        ) from None
    except subprocess.CalledProcessError as exc:
        raise BuildError(f"{library.name}: gcc could not build it: {_first_error(exc)}") from None
    os.replace(tmp, library)


def _first_error(exc: subprocess.CalledProcessError) -> str:
    """gcc's first line that says "error" (else its last line, else its exit status)."""
    text = exc.stderr.decode(errors="replace") if isinstance(exc.stderr, bytes) else exc.stderr
    lines = [line.strip() for line in (text or "").splitlines() if line.strip()]
    errors = [line for line in lines if "error" in line.lower()]
    return (errors or lines or [f"exit status {exc.returncode}"])[0]


#: The C loop of :class:`Rows`: the function ``%(name)s`` at each of ``n`` rows of ``x``
#: (``%(m)d`` doubles each), the parameters ``p`` the same for every row, each row's ``%(k)d``
#: outputs written column by column (output j of row i at ``out[j * n + i]``).
_ROWS_SOURCE = """\
typedef long long int casadi_int;
int %(name)s(const double** arg, double** res, casadi_int* iw, double* w, int mem);
int %(name)s_rows(const double* x, const double* p, double* out, casadi_int n,
              const double** arg, double** res, casadi_int* iw, double* w) {
  double row[%(k)d];
  for (casadi_int i = 0; i < n; ++i) {
    arg[0] = x + %(m)d * i;
    arg[1] = p;
    res[0] = row;
    if (%(name)s(arg, res, iw, w, 0)) return 1;
    for (int j = 0; j < %(k)d; ++j) out[j * n + i] = row[j];
  }
  return 0;
}
"""


class Rows:
    """A CasADi function ``fn`` (x (m,), p (q,)) -> y (k,), all dense, compiled by gcc with a
    C loop over many x: ``rows(xs (n, m), p)`` -> (k, n), column i ``fn``'s output at row i.
    The generated C performs ``fn``'s operations in the order CasADi's own evaluation does,
    so the answers are the same bits (tested); about ten times faster than ``fn.map(n)``.
    The library is ``<root>/rows-<name>-<hash of its C source>.so``, built once per machine.
    Each call has its own work arrays, so threads may share one."""

    def __init__(self, fn: ca.Function, root: Path) -> None:
        if fn.n_in() != 2 or fn.n_out() != 1:
            raise ValueError(f"{fn.name()}: Rows compiles a function (x, p) -> y")
        dense = [fn.sparsity_in(0), fn.sparsity_in(1), fn.sparsity_out(0)]
        if not all(s.is_dense() and s.is_column() for s in dense):
            raise ValueError(f"{fn.name()}: Rows compiles dense column inputs and output only")
        self.name = fn.name()
        self._m, self._q, self._k = fn.nnz_in(0), fn.nnz_in(1), fn.nnz_out(0)
        with tempfile.TemporaryDirectory() as scratch:
            generator = ca.CodeGenerator("generated.c", {"with_header": False})
            generator.add(fn)
            generator.generate(f"{scratch}{os.sep}")
            generated = (Path(scratch) / "generated.c").read_bytes()
        fields = {"name": self.name, "m": self._m, "k": self._k}
        loop = (_ROWS_SOURCE % fields).encode()
        key = hashlib.sha256(generated + b"\0" + loop + b"\0" + " ".join(GCC_FLAGS).encode())
        library = Path(root) / f"rows-{self.name}-{key.hexdigest()[:20]}.so"

        def build(path: Path) -> None:
            path.parent.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryDirectory(dir=path.parent) as scratch:
                sources = [Path(scratch) / "generated.c", Path(scratch) / "rows.c"]
                sources[0].write_bytes(generated)
                sources[1].write_bytes(loop)
                build_shared_library(sources, path)

        build_once(library, build)
        lib = ctypes.CDLL(str(library))
        sizes = [ctypes.c_longlong() for _ in range(4)]
        if getattr(lib, f"{self.name}_work")(*(ctypes.byref(s) for s in sizes)) != 0:
            raise RuntimeError(f"{library}: the compiled function refused its work sizes")
        self._work = [max(s.value, 2) for s in sizes]
        call = getattr(lib, f"{self.name}_rows")
        call.restype = ctypes.c_int
        call.argtypes = [ctypes.c_void_p] * 3 + [ctypes.c_longlong] + [ctypes.c_void_p] * 4
        self._lib, self._call, self.library = lib, call, library

    def __call__(self, xs: np.ndarray, p: np.ndarray) -> np.ndarray:
        xs = np.ascontiguousarray(xs, dtype=float)
        p = np.ascontiguousarray(p, dtype=float)
        if xs.ndim != 2 or xs.shape[1] != self._m or p.shape != (self._q,):
            raise ValueError(
                f"{self.name}: expected rows (n, {self._m}) and parameters ({self._q},), got "
                f"{xs.shape} and {p.shape}"
            )
        n = len(xs)
        out = np.empty((self._k, n))
        n_arg, n_res, n_iw, n_w = self._work
        arg, res = (ctypes.c_void_p * n_arg)(), (ctypes.c_void_p * n_res)()
        iw, w = np.zeros(n_iw, dtype=np.int64), np.zeros(n_w)
        data = (xs.ctypes.data, p.ctypes.data, out.ctypes.data)
        if self._call(*data, n, arg, res, iw.ctypes.data, w.ctypes.data) != 0:
            raise RuntimeError(f"{self.name}: the compiled evaluation failed")
        return out
