"""Lowered programs on disk, beside JAX's persistent compilation cache.

JAX's persistent cache (``compile_cache``) skips XLA's compilation of a
program it has seen, but every process still traces the Python code of a
rollout and lowers it to StableHLO before it can look the program up: ~3 s of
the ~3.5 s a cached rollout took to start (``docs/performance.md``, "Compile
from the persistent cache"). ``stored_jit`` also keeps the lowered module:
the first process exports it (``jax.export``) into
``<JAX's cache folder>/drivee2e-lowered/``, later ones deserialize it (a few
ms) and go straight to the compile cache.

A stored program is only reused when everything its trace depended on is
the same, which the key says:

* the code: every ``.py`` file of this package (``package_fingerprint``),
  and for a policy defined outside it, its module file and global values
  and every other module loaded from outside the standard library and
  installed packages (its helpers), the versions of the installed packages
  whose classes it uses;
* the caller's identity (``identity``): for a rollout its class, the
  simulator and its config, the policy object (every attribute, recursively;
  arrays by content), the control timing and the chunk;
* the arguments' tree structure, shapes, dtypes and weak types;
* Python, JAX, jaxlib, NumPy and Flax versions, the backend and the JAX
  options that change a trace (x64, matmul precision, PRNG, promotion).

Anything the key cannot describe (an object without a ``__dict__`` or with
``__slots__``, a class from ``__main__`` of a notebook, a function whose
closure holds such a thing, an array under a trace), arguments placed on
several devices, a call under an outer trace, and any failure to export
(host callbacks: the PyTorch / numpy / remote policies) fall back to a plain
``jax.jit``, which is what runs without the store. A policy whose trace
reads something else (a global changed at run time, a file read while
tracing) must not be cached: run with ``DRIVEE2E_LOWERED_CACHE=off``.

Off when JAX's persistent compilation cache is off (no folder) or with
``DRIVEE2E_LOWERED_CACHE=off``. Files are written to a temporary name and
renamed (concurrent processes cannot leave a torn file); an unreadable or
corrupt file is ignored and written again.
"""

from __future__ import annotations

import collections
import dataclasses
import enum
import functools
import hashlib
import importlib.metadata
import os
import pickle
import sys
import sysconfig
import types
from pathlib import Path
from typing import Any

import jax
import numpy as np
from jax import export as jax_export  # not an attribute of jax before it is imported (JAX 0.5)

from drivee2e_jax.files import atomic_write, sha256_file

ENV = "DRIVEE2E_LOWERED_CACHE"
#: The folder's name inside JAX's compilation cache folder.
FOLDER = "drivee2e-lowered"
#: First bytes of every stored file; a change of layout changes it.
MAGIC = b"drivee2e-lowered/1\n"
#: JAX options that change what a function traces to.
_JAX_OPTIONS = ("jax_enable_x64", "jax_default_matmul_precision", "jax_numpy_rank_promotion",
                "jax_numpy_dtype_promotion", "jax_default_prng_impl", "jax_threefry_partitionable",
                "jax_enable_checks", "jax_debug_nans", "jax_debug_infs", "jax_disable_jit",
                "jax_use_shardy_partitioner")
_PACKAGE = Path(__file__).resolve().parent
#: In-process, the last ``_KEEP`` programs used: key -> (jitted call of the
#: exported module, output tree), or None (not exportable: the plain jit runs).
_PROGRAMS: collections.OrderedDict[str, tuple | None] = collections.OrderedDict()
_KEEP = 64


class Unfingerprintable(Exception):
    """A value the key cannot describe (the caller falls back to a plain jit)."""


def folder() -> Path | None:
    """Where lowered programs are stored, or None when the store is off."""
    if os.environ.get(ENV, "").strip().lower() in ("off", "0", "none", "false"):
        return None
    base = jax.config.jax_compilation_cache_dir
    return Path(base) / FOLDER if base else None


@functools.lru_cache(maxsize=1)
def package_fingerprint() -> str:
    """sha256 of every ``.py`` file of the package (relative path and bytes)."""
    h = hashlib.sha256()
    for path in sorted(_PACKAGE.rglob("*.py")):
        h.update(str(path.relative_to(_PACKAGE)).encode() + b"\0" + path.read_bytes() + b"\0")
    return h.hexdigest()


def _version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "?"


@functools.lru_cache(maxsize=1)
def _installed_roots() -> tuple[Path, ...]:
    paths = sysconfig.get_paths()
    roots = {paths[k] for k in ("stdlib", "platstdlib", "purelib", "platlib") if k in paths}
    roots |= {str(Path(p)) for p in sys.path if Path(p).name in ("site-packages", "dist-packages")}
    return tuple(Path(r).resolve() for r in roots)


def _origin(module_name: str) -> tuple[str, Path | None]:
    """("package" | "installed" | "user", the module's file) of a loaded module."""
    module = sys.modules.get(module_name)
    file = getattr(module, "__file__", None)
    if module is None or not file:
        if module_name in sys.builtin_module_names or module_name == "builtins":
            return "installed", None
        raise Unfingerprintable(f"module {module_name!r} has no file")
    path = Path(file).resolve()
    if path.is_relative_to(_PACKAGE):
        return "package", path
    if any(path.is_relative_to(r) for r in _installed_roots()):
        return "installed", path
    return "user", path


def _user_modules() -> list[str]:
    """sha256 of the file of every loaded module from outside the standard
    library, installed packages and this package, sorted."""
    out = []
    for name, module in list(sys.modules.items()):
        file = getattr(module, "__file__", None)
        if not file or not str(file).endswith(".py"):
            continue
        try:
            kind, path = _origin(name)
        except Unfingerprintable:
            continue
        if kind == "user" and path is not None and path.is_file():
            out.append(sha256_file(path))
    return sorted(out)


class _Digest:
    """A stable description of a Python value, fed into sha256."""

    def __init__(self):
        self.h = hashlib.sha256()
        self.user_code = False
        self._stack: list[int] = []
        self._modules: set[str] = set()  # user modules whose globals are in

    def put(self, *parts: Any) -> None:
        for p in parts:
            self.h.update(repr(p).encode() + b"\x1f")

    def module(self, name: str) -> None:
        """A module by what its code is, not by its name (a policy file is
        loaded under a name that changes from process to process)."""
        kind, path = _origin(name)
        if kind == "installed":
            self.put("installed", name, _version(name.partition(".")[0]))
        elif kind == "user":
            self.user_code = True
            self.put("user", sha256_file(path))
            if name not in self._modules:
                self._modules.add(name)
                self.module_data(sys.modules[name])
        else:  # covered by package_fingerprint
            self.put("package", path.relative_to(_PACKAGE).as_posix())

    def module_data(self, module: types.ModuleType) -> None:
        """A user module's global values (its file says what its code is,
        not what ``X = os.environ[...]`` or a file read at import gave):
        every global but the functions, classes and modules it defines or
        imports; one the key cannot describe counts by its name only."""
        for name, v in sorted(vars(module).items()):
            if name.startswith("__") or isinstance(v, (type, types.ModuleType, types.FunctionType,
                                                       types.BuiltinFunctionType)):
                continue
            self.put("global", name)
            try:
                self.value(v)
            except Unfingerprintable:
                self.put("opaque")

    def cls(self, c: type) -> None:
        if c.__module__ == "__main__":
            raise Unfingerprintable(f"class {c.__qualname__} is defined in __main__")
        self.put("class", c.__qualname__)
        self.module(c.__module__)

    def function(self, f: types.FunctionType) -> None:
        self.put("function", f.__qualname__)
        if f.__module__ is not None:
            self.module(f.__module__)
        self.code(f.__code__)
        self.value(f.__defaults__)
        self.value(f.__kwdefaults__)
        self.value(tuple(c.cell_contents for c in f.__closure__ or ()))

    def code(self, c: types.CodeType) -> None:
        self.put("code", c.co_code, c.co_names, c.co_varnames, c.co_freevars, c.co_cellvars)
        for k in c.co_consts:
            self.code(k) if isinstance(k, types.CodeType) else self.put(type(k).__name__, k)

    def value(self, v: Any) -> None:
        if id(v) in self._stack:
            self.put("cycle", self._stack.index(id(v)))
            return
        if len(self._stack) > 64:
            raise Unfingerprintable("nested too deeply")
        self._stack.append(id(v))
        try:
            self._value(v)
        finally:
            self._stack.pop()

    def _value(self, v: Any) -> None:
        t = type(v)
        if v is None or t in (bool, int, float, complex, str, bytes):
            self.put(t.__name__, v)
        elif isinstance(v, enum.Enum):
            self.cls(t)
            self.put(v.name)
        elif t in (tuple, list):
            self.put(t.__name__, len(v))
            for x in v:
                self.value(x)
        elif t is dict:
            self.put("dict", len(v))
            for k in sorted(v, key=repr):
                self.value(k)
                self.value(v[k])
        elif t in (set, frozenset):
            self.put(t.__name__, sorted(repr(x) for x in v))
        elif isinstance(v, jax.core.Tracer):
            raise Unfingerprintable("a traced value")
        elif isinstance(v, (np.ndarray, np.generic, jax.Array)):
            a = np.asarray(v)
            self.put("array", a.dtype.str, a.shape)
            self.h.update(np.ascontiguousarray(a).tobytes())
        elif isinstance(v, type):
            self.cls(v)
        elif isinstance(v, functools.partial):
            self.put("partial")
            self.value((v.func, v.args, v.keywords))
        elif isinstance(v, types.FunctionType):
            self.function(v)
        elif isinstance(v, types.MethodType):
            self.put("method")
            self.value((v.__func__, v.__self__))
        elif isinstance(v, types.ModuleType):
            self.put("module")
            self.module(v.__name__)
        elif isinstance(v, (types.BuiltinFunctionType, np.ufunc)):
            self.put("builtin", getattr(v, "__module__", None), getattr(v, "__qualname__", v.__name__))
        elif dataclasses.is_dataclass(v):
            self.cls(t)
            for f in dataclasses.fields(v):
                self.put(f.name)
                self.value(getattr(v, f.name, None))
        elif hasattr(v, "__dict__") and not hasattr(t, "__slots__"):
            self.cls(t)
            self.value(dict(vars(v)))
        else:
            raise Unfingerprintable(f"a {t.__module__}.{t.__qualname__} object")

    def hexdigest(self) -> str:
        if self.user_code:  # a policy's helpers: every module loaded from the user's files
            self.put("user modules", _user_modules())
        return self.h.hexdigest()


def fingerprint(value: Any) -> str:
    """sha256 (hex) of ``value``'s description; raises ``Unfingerprintable``."""
    d = _Digest()
    d.value(value)
    return d.hexdigest()


def _environment() -> tuple:
    return (sys.version_info[:2], jax.__version__, _version("jaxlib"), np.__version__, _version("flax"),
            jax.default_backend(), tuple((o, str(getattr(jax.config, o, None))) for o in _JAX_OPTIONS),
            package_fingerprint())


def stored_jit(fn, identity: Any):
    """``jax.jit(fn)`` whose lowered program is stored on disk (module doc).

    ``identity``: everything ``fn``'s trace depends on beyond its arguments
    (fingerprinted; see the module doc), or a function of no arguments that
    returns it on first use; None never stores. The result is
    called like ``jax.jit(fn)`` with positional arguments and has ``lower``.
    """
    jitted = jax.jit(fn)
    if identity is None or folder() is None or jax.config.jax_disable_jit:
        return jitted
    return StoredJit(jitted, identity)


class StoredJit:
    """A jitted function with a lowered-program store (``stored_jit``)."""

    def __init__(self, jitted, identity):
        self._jitted = jitted
        self._identity = identity
        self._ident: str | None = None  # fingerprint of identity + environment, on first use
        self._keys: dict = {}  # (tree, avals) -> stored-program key, or None (not stored)

    def __call__(self, *args):
        program, leaves = self._program(args)
        if program is None:
            return self._jitted(*args)
        call, out_tree = program
        return jax.tree_util.tree_unflatten(out_tree, call(*leaves))

    def lower(self, *args):
        """Lowered program (``.compile()``, ``.out_info`` as the output tree)."""
        program, leaves = self._program(args)
        if program is None:
            return self._jitted.lower(*args)
        call, out_tree = program
        return _Lowered(call.lower(*leaves), out_tree)

    # -------------------------------------------------------------------------
    def _key(self, leaves, tree) -> str | None:
        avals = []
        for x in leaves:
            if isinstance(x, jax.core.Tracer):
                return None  # under an outer trace: the outer program is what gets lowered
            sharding = getattr(x, "sharding", None)
            if sharding is not None and len(sharding.device_set) > 1:
                return None
            if not (hasattr(x, "shape") and hasattr(x, "dtype")):
                return None  # a Python scalar argument: left to the plain jit
            avals.append((tuple(x.shape), x.dtype, bool(getattr(x, "weak_type", False))))
        signature = (tree, tuple(avals))
        if signature not in self._keys:  # hashing the tree's text costs ~1 ms: once per signature
            if self._ident is None:
                try:
                    identity = self._identity() if callable(self._identity) else self._identity
                    self._ident = fingerprint((identity, _environment()))
                except Unfingerprintable:
                    self._ident = ""
            self._keys[signature] = (hashlib.sha256(f"{self._ident}|{tree}|{avals}".encode()).hexdigest()
                                     if self._ident else None)
        return self._keys[signature]

    def _program(self, args):
        """(the stored program or None, the flat arguments)."""
        leaves, tree = jax.tree_util.tree_flatten(args)
        key = self._key(leaves, tree)
        if key is None:
            return None, leaves
        if key in _PROGRAMS:
            _PROGRAMS.move_to_end(key)
        else:
            _PROGRAMS[key] = _load(key) or self._export(key, leaves, tree)
            while len(_PROGRAMS) > _KEEP:
                _PROGRAMS.popitem(last=False)
        return _PROGRAMS[key], leaves

    def _export(self, key: str, leaves, in_tree):
        out = {}

        def flat(*xs):
            result = self._jitted(*jax.tree_util.tree_unflatten(in_tree, xs))
            ys, out["tree"] = jax.tree_util.tree_flatten(result)
            return ys

        try:
            exported = jax_export.export(jax.jit(flat))(*leaves)
            skeleton = pickle.dumps(jax.tree_util.tree_unflatten(out["tree"], list(range(out["tree"].num_leaves))))
            module = exported.serialize()
        except Exception:  # noqa: BLE001 - not exportable (host callbacks, ...) or a bug the plain jit will raise
            return None
        _store(key, skeleton, module)
        return jax.jit(exported.call), out["tree"]


class _Lowered:
    def __init__(self, lowered, out_tree):
        self._lowered = lowered
        self.out_info = jax.tree_util.tree_unflatten(out_tree, lowered.out_info)

    def compile(self):
        return self._lowered.compile()


def _path(key: str) -> Path | None:
    base = folder()
    return None if base is None else base / f"{key}.bin"


def _load(key: str):
    path = _path(key)
    try:
        blob = path.read_bytes()
        if not blob.startswith(MAGIC):
            return None
        n = int.from_bytes(blob[len(MAGIC):len(MAGIC) + 8], "little")
        start = len(MAGIC) + 8
        skeleton = pickle.loads(blob[start:start + n])
        exported = jax_export.deserialize(bytearray(blob[start + n:]))
    except Exception:  # noqa: BLE001 - missing, unreadable or corrupt: lowered again and rewritten
        return None
    return jax.jit(exported.call), jax.tree_util.tree_structure(skeleton)


def _store(key: str, skeleton: bytes, module: bytes) -> None:
    path = _path(key)
    if path is None:
        return
    try:
        atomic_write(path, lambda f: f.write(MAGIC + len(skeleton).to_bytes(8, "little") + skeleton + module),
                     binary=True)
    except OSError:  # a read-only or full cache folder: the program still runs, unstored
        pass
