"""The Policy protocol and loading a policy from a file path.

A policy is pure and runs inside the jitted rollout, once per control step,
for one scenario (the rollout vmaps it)::

    params = policy.init(key, obs)                 # any pytree (may be None)
    pstate = policy.initial_state(obs)             # recurrent state / history
    action, pstate = policy.act(params, obs, pstate, key)

``action`` is a ``types.Controls`` (throttle, brake, steer) or a
``types.Waypoints`` (future ego-frame points ``Waypoints.dt`` apart), as
``policy.action_type`` declares; a waypoint action goes through the
simulator's PID + pure-pursuit controller, as TCP / Bench2Drive agents do.

A policy file (``--policy path/to/file.py``) defines either a module-level
``policy`` object or a ``make_policy(**kwargs)`` factory returning one.
"""

from __future__ import annotations

import ast
import os
import sys
import traceback
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, Protocol, runtime_checkable

from drivee2e_jax.errors import DriveE2EError, one_line
from drivee2e_jax.files import DuplicateKeyError, loads_json
from drivee2e_jax.hostapi import HostPolicy, load_policy_object, validate_host_policy
from drivee2e_jax.remote import RemotePolicy, is_remote_spec, parse_remote_spec

if TYPE_CHECKING:  # annotations only: this module imports no JAX (host policies use it)
    from drivee2e_jax.types import Observation

ActionType = Literal["controls", "waypoints"]

#: Policies ``drivee2e bench`` runs when none is named.
DEFAULT_POLICIES = ("log_replay", "expert", "stop")
#: Rule-based policies of the zoo (``drivee2e_jax/zoo/``), accepted by name and
#: runnable without a checkpoint. ``reference_policy_names()`` lists every
#: policy the zoo ships (the learned ones load bundled weights or a checkpoint argument).
REFERENCE_POLICIES = (*DEFAULT_POLICIES, "constant_velocity")


@runtime_checkable
class Policy(Protocol):
    """What the simulator needs from a driving policy.

    Attributes:
      name: short name used in result tables.
      action_type: "controls" or "waypoints".
      waypoint_dt: spacing of waypoint actions in seconds (waypoints only).
    """

    name: str
    action_type: ActionType

    def init(self, key, obs: Observation) -> Any: ...

    def initial_state(self, obs: Observation) -> Any: ...

    def act(self, params, obs: Observation, policy_state, key) -> tuple[Any, Any]: ...


class StatelessPolicy:
    """Convenience base: no parameters, no recurrent state."""

    name = "policy"
    action_type: ActionType = "controls"
    waypoint_dt = 0.5

    def init(self, key, obs):
        return None

    def initial_state(self, obs):
        return None

    def act(self, params, obs, policy_state, key):  # pragma: no cover - abstract
        raise NotImplementedError


def load_policy(path: str | Path, **kwargs) -> Policy | HostPolicy:
    """Load a policy from a Python file (a JAX ``Policy`` or a ``HostPolicy``),
    or connect to a remote one (``remote://HOST:PORT``, ``drivee2e serve-policy``).

    ``path`` takes what ``--policy`` takes: a file, a zoo name (``"expert"``),
    ``NAME_OR_FILE:key=value,...`` (``make_policy`` arguments, JSON values;
    ``name=`` renames; ``kwargs`` win over the spec's) or ``remote://HOST:PORT``.

    Raises DriveE2EError (one line) when the file is missing, fails to import,
    or defines neither ``policy`` nor ``make_policy``, or the object lacks the
    protocol's methods.
    """
    if is_remote_spec(path):
        if kwargs:
            raise DriveE2EError(f"{path}: a remote policy takes no make_policy arguments (give them to serve-policy)")
        spec = parse_remote_spec(str(path))
        pol = RemotePolicy(spec.address, **spec.kwargs, name=spec.name or None)
        pol.source = str(path)
        return pol
    rename = ""
    if not Path(path).is_file():  # a zoo name or PATH:key=value,... as on the command line
        path, spec_kwargs, rename = parse_policy_spec(str(path))
        kwargs = {**spec_kwargs, **kwargs}
    pol = load_policy_object(path, **kwargs)
    if rename:
        try:
            pol.name = rename
        except AttributeError as e:
            raise DriveE2EError(f"{path}: cannot rename the policy to {rename!r} ({e})") from e
    if isinstance(pol, HostPolicy):  # runs on the host; the rollout calls it through hostbridge
        validate_host_policy(pol, str(path))
        pol.source = str(path)
        return pol
    missing = [m for m in ("init", "initial_state", "act", "name", "action_type") if not hasattr(pol, m)]
    if missing:
        raise DriveE2EError(f"{path}: policy object lacks {', '.join(missing)} (see drivee2e_jax.policy.Policy)")
    if pol.action_type not in ("controls", "waypoints"):
        raise DriveE2EError(f"{path}: action_type is {pol.action_type!r}, expected 'controls' or 'waypoints'")
    if getattr(pol, "source", None) is None:
        try:  # what error messages name (evaluate's policy check, hostbridge)
            pol.source = str(path)
        except (AttributeError, TypeError):  # a frozen object: messages fall back to its name
            pass
    return pol


def user_frame(exc: BaseException, source: str | Path | None = None) -> str:
    """``"file:line"`` where ``exc`` left the policy's code: the last frame of
    its traceback in the policy file ``source``, else the last frame outside
    installed packages, the standard library and drivee2e_jax's own machinery
    (its ``zoo/`` and ``models/`` count as policy code); "" when none."""
    frames = traceback.extract_tb(exc.__traceback__)
    want = _resolved(source) if source else None
    mine = [f for f in frames if want is not None and _resolved(f.filename) == want]
    mine = mine or [f for f in frames if not _is_library(f.filename)]
    return f"{mine[-1].filename}:{mine[-1].lineno}" if mine else ""


def raised_text(exc: BaseException, source: str | Path | None = None, limit: int = 200) -> str:
    """``raised Type: message at file:line`` on one line: the message cut at
    ``limit`` characters, the place from :func:`user_frame` (when found)."""
    frame = user_frame(exc, source)
    if isinstance(exc, SystemExit):  # a policy must not end the benchmark's process
        return f"called sys.exit({exc.code!r})" + (f" at {frame}" if frame else "")
    text = one_line(exc, limit)
    return f"raised {type(exc).__name__}" + (f": {text}" if text else "") + (f" at {frame}" if frame else "")


def _resolved(path: str | Path) -> Path | None:
    try:
        return Path(path).resolve()
    except (OSError, ValueError):
        return None


def _is_library(filename: str) -> bool:
    """Whether a traceback frame's file is library code rather than a policy's."""
    path = _resolved(filename)
    if path is None or filename.startswith("<"):
        return True
    if {"site-packages", "dist-packages"} & set(path.parts):
        return True
    for prefix in {sys.base_prefix, sys.prefix, sys.exec_prefix}:
        stdlib = Path(prefix).resolve() / "lib"
        if path.is_relative_to(stdlib):
            return True
    package = Path(__file__).resolve().parent
    return path.is_relative_to(package) and not any(path.is_relative_to(package / d) for d in ("zoo", "models"))


def parse_policy_spec(spec: str) -> tuple[Path | str, dict, str]:
    """``PATH_OR_NAME[:key=value,...]`` -> (policy file, ``make_policy`` kwargs,
    result name; a ``remote://`` spec stays text). Values are JSON when they parse (numbers, true, lists), else
    text; the key ``name`` renames the policy in the results instead.

    Example: ``drivee2e_jax/zoo/ad_mlp.py:checkpoint=runs/ad_mlp/checkpoints/3,name=ad_mlp_e3``.
    """
    if is_remote_spec(spec):  # remote://HOST:PORT[:timeout_s=S,name=N]: kept as text, read by load_policy
        return spec, {}, parse_remote_spec(spec).name or ""
    head, sep, tail = spec.partition(":")
    kwargs: dict = {}
    if sep:
        for item in filter(None, tail.split(",")):
            key, eq, value = item.partition("=")
            if not eq or not key.strip().isidentifier():
                raise DriveE2EError(f"--policy {spec}: expected PATH:key=value[,key=value...], got {item!r}")
            try:
                kwargs[key.strip()] = loads_json(value)
            except DuplicateKeyError as e:
                raise DriveE2EError(f"--policy {spec}: {key.strip()}={value}: {e}") from None
            except ValueError:
                kwargs[key.strip()] = value
    name = kwargs.pop("name", "")
    return resolve_policy_path(head), kwargs, str(name)


def resolve_policy_path(spec: str) -> Path:
    """A policy argument: an existing file, or a reference policy name."""
    path = Path(spec)
    if path.suffix == ".py" or path.exists():
        if not path.is_file():
            raise DriveE2EError(f"{spec}: policy file not found (expected a .py file or one of "
                                f"{', '.join(reference_policy_names())})")
        return path
    ref = reference_policy_dir() / f"{spec}.py"
    if ref.is_file():
        return ref
    raise DriveE2EError(f"--policy {spec}: not a file and not a policy of the zoo (expected a .py path or one of "
                        f"{', '.join(reference_policy_names())})")


def reference_policy_dir() -> Path:
    """The policy zoo's folder, ``drivee2e_jax/zoo/`` (inside the installed
    package, so names resolve from any directory and from a wheel)."""
    return Path(__file__).resolve().parent / "zoo"


#: Environment variable naming another folder of bundled zoo weights (tests, your own exports).
ZOO_WEIGHTS_ENV = "DRIVEE2E_ZOO_WEIGHTS"


def zoo_weights_dir() -> Path:
    """The folder of the zoo's bundled weights (``models.bundled``):
    ``$DRIVEE2E_ZOO_WEIGHTS`` when set, else ``drivee2e_jax/zoo/weights/``."""
    env = os.environ.get(ZOO_WEIGHTS_ENV, "").strip()
    return Path(env).expanduser() if env else reference_policy_dir() / "weights"


def zoo_weight_files(policy_path: str | Path) -> list[Path]:
    """The bundled weight files a zoo policy file may load (``<stem>.*`` and,
    for a variant such as ``tcp_traj``, its family's ``tcp.*``): what a
    results folder fingerprints besides the policy file. [] for a file
    outside the zoo."""
    p = Path(policy_path)
    if p.suffix != ".py" or p.resolve().parent != reference_policy_dir():
        return []
    stems = {p.stem, p.stem.split("_")[0]}
    wdir = zoo_weights_dir()
    return sorted(f for f in wdir.glob("*.*") if f.stem in stems) if wdir.is_dir() else []


def reference_policy_names() -> tuple[str, ...]:
    """Every policy name the zoo ships (file stems of ``reference_policy_dir()``)."""
    return tuple(sorted(f.stem for f in reference_policy_dir().glob("*.py") if not f.name.startswith("_")))


#: ``local_modules`` follows at most this many modules from one policy file.
MAX_LOCAL_MODULES = 1000


def local_modules(path: str | Path) -> list[Path]:
    """The user's own modules a policy file imports, directly or through each
    other: the files below the policy file's folder that its ``import`` /
    ``from ... import`` statements (anywhere in the file, found with ``ast``,
    nothing executed) name, resolved as Python would with that folder on the
    import path (``a.b`` -> ``a/__init__.py`` and ``a/b.py`` or
    ``a/b/__init__.py``; ``from . import x`` relative to the importing file;
    ``from a import b``: ``a/b.py`` too when it is a submodule). Modules
    elsewhere (the standard library, site-packages, drivee2e itself unless it
    lives in that folder) are not followed. Recursive, each file once (cycles
    end), at most ``MAX_LOCAL_MODULES``; a file that does not parse is listed
    but not followed. Sorted absolute paths, the policy file itself excluded."""
    policy = Path(path).resolve()
    root = policy.parent
    seen, todo = {policy}, [policy]
    while todo and len(seen) <= MAX_LOCAL_MODULES:
        for f in _imported_files(todo.pop(), root):
            if f not in seen:
                seen.add(f)
                todo.append(f)
    return sorted(seen - {policy})


def _imported_files(module: Path, root: Path) -> list[Path]:
    """The files under ``root`` that the imports of ``module`` name."""
    try:
        tree = ast.parse(module.read_bytes(), filename=str(module))
    except (OSError, SyntaxError, ValueError, RecursionError):
        return []
    out: list[Path] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                out += _module_files(root, alias.name.split("."))
        elif isinstance(node, ast.ImportFrom):
            base = root
            if node.level:
                base = module.parent
                for _ in range(node.level - 1):
                    base = base.parent
            if not base.is_relative_to(root):
                continue
            parts = node.module.split(".") if node.module else []
            out += _module_files(base, parts)
            for alias in node.names:
                if alias.name != "*":
                    out += _module_files(base, [*parts, alias.name])
    return [f.resolve() for f in out if f.resolve().is_relative_to(root)]


def _module_files(base: Path, parts: list[str]) -> list[Path]:
    """The files importing ``.``-joined ``parts`` from folder ``base`` runs:
    each package's ``__init__.py`` on the way and the module itself."""
    out, folder = [], base
    for i, name in enumerate(parts):
        if (folder / name / "__init__.py").is_file():
            out.append(folder / name / "__init__.py")
            folder = folder / name
        elif (folder / f"{name}.py").is_file():
            if i == len(parts) - 1:
                out.append(folder / f"{name}.py")
            break
        elif (folder / name).is_dir():  # a namespace package
            folder = folder / name
        else:
            break
    return out
