r"""Features φ(x, E) of one waypoint and their sums Φ(ξ, E) over a trajectory.

Every feature is defined once, as a CasADi expression of the arm configuration q (7,) and the
environment's named parameters (``laptop_x``, ``laptop_y``, ``laptop_yaw``, ``table_x``,
``table_y``; :data:`corrections_sim.scene.environments.ENV_PARAMETERS`). The planner uses the
expressions
symbolically; :func:`feature_counts` evaluates the same compiled function numerically. Each
per-waypoint feature lies in [0, 1] and is smooth (C^∞), so Φ(ξ, E) ∈ [0, T]^k.

With c the cup centre (world, metres) and z_h the hand's approach axis:

* ``laptop``  — how much the coffee is carried *over the laptop*:
  :math:`\exp\!\big(-\|c_{xy} - l_{xy}\|^2 / (2\,σ_l^2)\big)`, σ_l = ``LAPTOP_SCALE``.
* ``table``   — how close the coffee is to the table top while above it:
  :math:`s(c_{xy})\,\exp\!\big(-h^2 / (2\,σ_t^2)\big)`, h = c_z − table top, σ_t =
  ``TABLE_SCALE``, and s a smooth indicator of the table's footprint (product of logistic
  edges of width ``TABLE_EDGE``).
* ``coffee``  — how far the cup is tilted: :math:`(1 + z_h \cdot \hat z)/2`, 0 upright,
  1 upside down.
* ``human``   — how close the coffee comes to a person standing across the table (FERL's
  "human" feature): :math:`\exp(-\|c - p\|^2 / (2 σ_p^2))`, p = ``HUMAN_POSITION``,
  σ_p = ``HUMAN_SCALE``. None of the paper's learners has it.

Positive weights θ_i make the robot seek a feature, negative ones avoid it.

Features are a table, :data:`FEATURES`: a new one is a function of :class:`Waypoint` (the
hand pose, the cup centre and the environment's parameters by name) registered with
``@register_feature(name)``; a parameter it needs beyond the table's and the laptop's is one
:func:`~corrections_sim.scene.environments.register_env_parameter` call.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import casadi as ca
import numpy as np

from corrections_sim.planning.cache import cache_dir
from corrections_sim.planning.compiled import BuildError, Rows
from corrections_sim.registry import Registry
from corrections_sim.scene import geometry as g
from corrections_sim.scene.environments import ENV_PARAMETERS, Environment, env_index, n_env_params
from corrections_sim.scene.robot import N_ARM_JOINTS, symbolic_fk

#: The paper's features (the registry, :data:`FEATURES`, may hold more).
FEATURE_NAMES = ("laptop", "table", "coffee")

LAPTOP_SCALE = 0.15  # m, σ_l
#: Where the person stands (FERL's "human" feature): across the table from the robot, the
#: cup centre's height a chest would be at, world frame, m; and the feature's length scale.
HUMAN_POSITION = (1.15, 0.0, 0.35)
HUMAN_SCALE = 0.35  # m, σ_p
TABLE_SCALE = 0.20  # m, σ_t
TABLE_EDGE = 0.02  # m, width of the logistic footprint edges


@dataclass(frozen=True, eq=False)
class Waypoint:
    """The symbols a feature reads at one waypoint.

    Attributes:
        rot_hand: hand orientation (3, 3), world frame.
        pos_hand: hand position (3,), m.
        cup: cup centre (3,), m.
        env: the environment's parameter vector; read it by name, :meth:`param`.
        learnt: a learnt feature's weights as symbols (:class:`LearntFeature` with no
            weights of its own: the weights are then the NLP's parameters); None otherwise.
    """

    rot_hand: ca.SX
    pos_hand: ca.SX
    cup: ca.SX
    env: ca.SX
    learnt: ca.SX | None = None

    def param(self, name: str) -> ca.SX:
        """The environment parameter ``name`` (see ``environments.ENV_PARAMETERS``)."""
        return self.env[env_index(name)]


Feature = Callable[[Waypoint], ca.SX]
"""A feature: the waypoint's symbols -> a scalar CasADi expression in [0, 1], smooth."""

FEATURES: Registry[Feature] = Registry(
    "feature", check=lambda f: None if callable(f) else "is not callable"
)
"""Every feature by name, in registration order."""


def register_feature(name: str, *, replace: bool = False):
    """Decorator: register a :data:`Feature` function under ``name``."""

    return FEATURES.decorator(name, replace=replace)


class Network(Protocol):
    """A learnt feature's shape (:class:`corrections_sim.learnt.training.Network`)."""

    n_params: int
    slot: str

    def expression(self, w: Waypoint, weights) -> ca.SX: ...

    def source(self) -> str: ...


@dataclass(frozen=True, eq=False)
class LearntFeature:
    """A feature learnt from data (:mod:`corrections_sim.learnt.training`), as the registry
    holds it: a network shape and its weights. With ``weights = None`` it is a *slot*: the
    weights are symbols, the compiled NLP's parameters (one build per shape, never one per
    learnt feature); :func:`canonical` maps learnt names to slots and :func:`learnt_values`
    gives the weights the NLP is called with."""

    network: Network
    weights: np.ndarray | None = None

    def __call__(self, w: Waypoint) -> ca.SX:
        weights = w.learnt if self.weights is None else ca.DM(self.weights)
        return self.network.expression(w, weights)

    def source(self) -> str:
        """What shapes its expression: the network's code and shape (and weights' digest)."""
        text = self.network.source()
        if self.weights is not None:
            text += "\n" + hashlib.sha256(np.asarray(self.weights, float).tobytes()).hexdigest()
        return text


def is_slot(name: str) -> bool:
    """Whether ``name`` is a learnt feature whose weights are the NLP's parameters."""
    f = FEATURES.get(name)
    return isinstance(f, LearntFeature) and f.weights is None


def canonical(names: tuple[str, ...]) -> tuple[str, ...]:
    """``names`` with each learnt feature replaced by its shape's slot (registered here on
    first use), so that every learnt feature of one shape shares one compiled NLP."""
    out = []
    for i, name in enumerate(check_feature_names(names)):
        f = FEATURES[name]
        if isinstance(f, LearntFeature) and f.weights is not None:
            name = f"{f.network.slot}-{i}"
            if name not in FEATURES:
                FEATURES.register(name, LearntFeature(f.network))
        out.append(name)
    return tuple(out)


def learnt_values(names: tuple[str, ...]) -> np.ndarray:
    """The weights of the learnt features in ``names``, in order, for the parameters of the
    NLP over :func:`canonical` ``(names)`` (empty when there are none)."""
    parts = [
        np.asarray(FEATURES[n].weights, float)
        for n in names
        if isinstance(FEATURES[n], LearntFeature) and FEATURES[n].weights is not None
    ]
    return np.concatenate(parts) if parts else np.zeros(0)


def n_learnt(names: tuple[str, ...]) -> int:
    """How many NLP parameters the slots in ``names`` take."""
    return sum(FEATURES[n].network.n_params for n in names if is_slot(n))


def check_feature_names(names: tuple[str, ...]) -> tuple[str, ...]:
    """Validate a feature selection; returns it as a tuple."""
    names = tuple(names)
    unknown = [n for n in names if n not in FEATURES]
    if unknown or not names or len(set(names)) != len(names):
        raise ValueError(f"features: {list(names)} must be distinct names from {list(FEATURES)}")
    return names


def fingerprint(names: tuple[str, ...]) -> str:
    """What of the registries shapes a compiled solver over ``names``: each feature's source
    (a plug-in's lives outside this module) and the environment's parameter names, in order."""
    parts = [_source(FEATURES[name]) for name in check_feature_names(names)]
    parts.append(",".join(ENV_PARAMETERS))
    return "\n".join(parts)


def _source(function: Feature) -> str:
    """A feature's source text, or its compiled code where there is no source file
    (``python -c``, ``exec``)."""
    import inspect
    import marshal

    if isinstance(function, LearntFeature):
        return function.source()
    try:
        return inspect.getsource(function)
    except (OSError, TypeError):
        code = getattr(function, "__code__", None)
        return marshal.dumps(code).hex() if code is not None else repr(function)


def _logistic(x: ca.SX) -> ca.SX:
    return 0.5 * (1 + ca.tanh(0.5 * x))


@register_feature("laptop")
def laptop(w: Waypoint) -> ca.SX:
    """exp(−‖c_xy − l_xy‖² / (2 σ_l²)): the coffee carried over the laptop."""
    d2 = (w.cup[0] - w.param("laptop_x")) ** 2 + (w.cup[1] - w.param("laptop_y")) ** 2
    return ca.exp(-d2 / (2 * LAPTOP_SCALE**2))


@register_feature("table")
def table(w: Waypoint) -> ca.SX:
    """s(c_xy) exp(−h² / (2 σ_t²)): the coffee close to the table top while above it."""
    hx, hy = g.TABLE_HALF_SIZE
    dx, dy = w.cup[0] - w.param("table_x"), w.cup[1] - w.param("table_y")
    inside = (
        _logistic((hx + dx) / TABLE_EDGE)
        * _logistic((hx - dx) / TABLE_EDGE)
        * _logistic((hy + dy) / TABLE_EDGE)
        * _logistic((hy - dy) / TABLE_EDGE)
    )
    h = w.cup[2] - g.TABLE_TOP_Z
    return inside * ca.exp(-(h**2) / (2 * TABLE_SCALE**2))


@register_feature("coffee")
def coffee(w: Waypoint) -> ca.SX:
    """(1 + z_h·ẑ)/2: how far the cup is tilted, 0 upright, 1 upside down."""
    return 0.5 * (1 + w.rot_hand[2, 2])


@register_feature("human")
def human(w: Waypoint) -> ca.SX:
    """exp(−‖c − p‖² / (2 σ_p²)): the coffee close to the person standing across the table
    (at ``HUMAN_POSITION``). No learner of the paper has it: a person who minds it corrects
    for something the robot cannot represent."""
    d2 = sum((w.cup[i] - HUMAN_POSITION[i]) ** 2 for i in range(3))
    return ca.exp(-d2 / (2 * HUMAN_SCALE**2))


def symbolic_features(
    rot_hand: ca.SX,
    pos_hand: ca.SX,
    env: ca.SX,
    names: tuple[str, ...],
    learnt: ca.SX | None = None,
) -> ca.SX:
    """Per-waypoint features (k,) from the hand pose and the environment parameters (n,);
    ``learnt`` holds the weights of the slots in ``names`` (:func:`n_learnt` of them)."""
    cup = pos_hand + rot_hand @ ca.DM(g.CUP_CENTER_IN_HAND)
    w = Waypoint(rot_hand=rot_hand, pos_hand=pos_hand, cup=cup, env=env)
    values, at = [], 0
    for name in names:
        f = FEATURES[name]
        if is_slot(name):
            n = f.network.n_params
            if learnt is None or learnt.shape[0] < at + n:
                raise ValueError(f"feature {name!r}: its weights are parameters; none given")
            values.append(f(dataclasses.replace(w, learnt=learnt[at : at + n])))
            at += n
        else:
            values.append(f(w))
    return ca.vertcat(*values)


def waypoint_feature_function(names: tuple[str, ...]) -> ca.Function:
    """CasADi Function (q (7,), e (n,)) -> φ (k,) for one waypoint."""
    return _waypoint_feature_function(check_feature_names(names), n_env_params())


@functools.cache
def _waypoint_feature_function(names: tuple[str, ...], n_params: int) -> ca.Function:
    q = ca.SX.sym("q", N_ARM_JOINTS)
    e = ca.SX.sym("e", n_params)
    rot, pos = symbolic_fk(q, ("panda_hand",))["panda_hand"]
    return ca.Function("phi", [q, e], [symbolic_features(rot, pos, e, names)], ["q", "e"], ["phi"])


def slot_feature_function(names: tuple[str, ...]) -> ca.Function:
    """CasADi Function (q (7,), e (n,), l) -> φ (k,) for one waypoint, l the weights of the
    slots in ``names`` (see :func:`canonical`)."""
    names = check_feature_names(names)
    q = ca.SX.sym("q", N_ARM_JOINTS)
    e = ca.SX.sym("e", n_env_params())
    lw = ca.SX.sym("l", n_learnt(names))
    rot, pos = symbolic_fk(q, ("panda_hand",))["panda_hand"]
    phi = symbolic_features(rot, pos, e, names, lw)
    return ca.Function("phi_slots", [q, e, lw], [phi])


@functools.cache
def _rows(names: tuple[str, ...], n_params: int) -> Rows | None:
    """The features of one waypoint compiled with a loop over many (:class:`Rows`: the same
    bits as CasADi's evaluation, ten times faster), in the machine's cache; None, with a
    warning, where it cannot be built (the cache not writable, no gcc): CasADi then
    evaluates them, to the same numbers."""
    try:
        return Rows(_waypoint_feature_function(names, n_params), cache_dir())
    except (OSError, BuildError) as error:
        warnings.warn(
            f"waypoint features {names}: not compiled ({error}); CasADi evaluates them",
            RuntimeWarning,
            stacklevel=3,
        )
        return None


@functools.cache
def _mapped(names: tuple[str, ...], n_params: int, n_waypoints: int) -> ca.Function:
    return _waypoint_feature_function(names, n_params).map(n_waypoints)


def waypoint_features(
    trajectory: np.ndarray, env: Environment | np.ndarray, names: tuple[str, ...]
) -> np.ndarray:
    """Features of each waypoint, shape (T, k), for a trajectory (T, 7) in ``env`` (an
    :class:`Environment` or its parameter vector, :meth:`Environment.params`)."""
    traj = np.asarray(trajectory, dtype=float)
    if traj.ndim != 2 or traj.shape[1] != N_ARM_JOINTS:
        raise ValueError(f"trajectory: expected shape (T, {N_ARM_JOINTS}), got {traj.shape}")
    params = env.params() if isinstance(env, Environment) else np.asarray(env, float)
    names = check_feature_names(names)
    rows = _rows(names, params.shape[0])
    if rows is not None:
        return rows(traj, params).T
    f = _mapped(names, params.shape[0], traj.shape[0])
    return np.asarray(f(traj.T, params)).T


def feature_counts(
    trajectory: np.ndarray, env: Environment | np.ndarray, names: tuple[str, ...]
) -> np.ndarray:
    """Φ(ξ, E) = Σ_i φ(x^i, E), shape (k,), for a trajectory (T, 7)."""
    return waypoint_features(trajectory, env, names).sum(axis=0)


@functools.cache
def pose_feature_function(names: tuple[str, ...]) -> ca.Function:
    """CasADi Function (R (3, 3), p (3,), e (n,)) -> φ (k,): the features with the hand at
    rotation R and position p (no arm: a map of the features over places, e.g. the page's
    heat map over the table)."""
    names = check_feature_names(names)
    rot = ca.SX.sym("R", 3, 3)
    pos = ca.SX.sym("p", 3)
    e = ca.SX.sym("e", n_env_params())
    return ca.Function("phi_pose", [rot, pos, e], [symbolic_features(rot, pos, e, names)])
