r"""Features learnt from a person's feature traces (FERL: Bobu, Wiggert, Tomlin & Dragan,
HRI 2021; IJRR 2022), planned with like any hand-written feature.

A *feature trace* is a sequence of arm configurations a person moves the arm through, from
where the feature is high to where it is low. From N traces a small network f_ψ over the
waypoint's state learns the ranking they imply (FERL's loss): on each trace a later state
scores lower than an earlier one, the starts of different traces alike, and their ends alike.
The network's output is normalised to [0, 1] over random reachable configurations (the
workspace) and registered as a feature (:class:`~corrections_sim.planning.features.LearntFeature`):
a study file, the planner, every learner and the page use it by name.

What is exact and what is learnt: the ranking loss, its gradient and the network are the same
CasADi expression the planner differentiates (no second implementation); the optimum is a
local one (L-BFGS from a seeded start), and the network can only rank what the traces show.

The network: tanh hidden layers (smooth, as the Newton re-solve needs second derivatives),
linear output; its inputs (:data:`INPUTS`) are the cup's position, the hand's approach axis
and the cup relative to the scene's objects. The planner builds one NLP per network *shape*
(its slot) with the weights as parameters, so a newly learnt feature costs no compile.

Training is CasADi's algorithmic differentiation of the full-batch loss and our own L-BFGS
(:mod:`corrections_sim.learnt.lbfgs`, whose path is the same bits on every CPU: SciPy's took
its inner products from the machine's BLAS kernel and ended in another local optimum on
another processor); measured against torch in the docs: no CUDA wheels, one definition of the
network.
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import casadi as ca
import numpy as np

from corrections_sim.learnt import lbfgs
from corrections_sim.planning import features as feats
from corrections_sim.scene import geometry as g
from corrections_sim.scene.environments import Environment, n_env_params
from corrections_sim.scene.robot import N_ARM_JOINTS, joint_limits, symbolic_fk
from corrections_sim.scene.world import CollisionChecker

#: What a network may read at a waypoint, and how many numbers each is.
INPUTS = {
    "cup": 3,  # the cup centre, world frame (m)
    "axis": 3,  # the hand's approach axis (the cup's tilt)
    "laptop": 2,  # the cup centre relative to the laptop, horizontal (m)
    "table": 3,  # the cup centre relative to the table top's centre (m)
}


def _inputs(w: feats.Waypoint, names: tuple[str, ...]) -> ca.SX:
    parts = []
    for name in names:
        if name == "cup":
            parts.append(w.cup)
        elif name == "axis":
            parts.append(w.rot_hand[:, 2])
        elif name == "laptop":
            parts.append(ca.vertcat(w.cup[0] - w.param("laptop_x"), w.cup[1] - w.param("laptop_y")))
        elif name == "table":
            parts.append(
                ca.vertcat(
                    w.cup[0] - w.param("table_x"),
                    w.cup[1] - w.param("table_y"),
                    w.cup[2] - g.TABLE_TOP_Z,
                )
            )
    return ca.vertcat(*parts)


@dataclass(frozen=True)
class Network:
    """A learnt feature's shape: which inputs, which hidden layers (tanh), one linear output.

    Attributes:
        inputs: names from :data:`INPUTS`, distinct, in order.
        hidden: the hidden layers' widths.
    """

    inputs: tuple[str, ...] = ("cup", "axis", "laptop", "table")
    hidden: tuple[int, ...] = (16, 16)

    def __post_init__(self) -> None:
        inputs, hidden = tuple(self.inputs), tuple(self.hidden)
        if not inputs or len(set(inputs)) != len(inputs) or any(i not in INPUTS for i in inputs):
            raise ValueError(f"inputs: {list(inputs)} must be distinct names from {list(INPUTS)}")
        if not hidden or any(
            isinstance(h, bool) or not isinstance(h, int | np.integer) or not 1 <= h <= 256
            for h in hidden
        ):
            raise ValueError(f"hidden: {list(hidden)} must be one or more widths in [1, 256]")
        object.__setattr__(self, "inputs", inputs)
        object.__setattr__(self, "hidden", tuple(int(h) for h in hidden))

    @property
    def n_in(self) -> int:
        return sum(INPUTS[i] for i in self.inputs)

    @property
    def layers(self) -> tuple[tuple[int, int], ...]:
        """(fan-in, fan-out) per layer, the output's last."""
        sizes = (self.n_in, *self.hidden, 1)
        return tuple(zip(sizes[:-1], sizes[1:], strict=True))

    @property
    def n_params(self) -> int:
        return sum(o * (i + 1) for i, o in self.layers)

    @property
    def slot(self) -> str:
        """The name its NLP slot is registered under (one per shape)."""
        return f"slot_{'_'.join(self.inputs)}_{'x'.join(map(str, self.hidden))}"

    def source(self) -> str:
        return inspect.getsource(Network) + inspect.getsource(_inputs) + self.slot

    def forward(self, x, weights):
        """f_ψ(x) for inputs x (n_in, N) of any CasADi type (N states at once)."""
        at, h = 0, x
        n = x.shape[1]
        for layer, (i, o) in enumerate(self.layers):
            w = ca.reshape(weights[at : at + o * i], o, i)
            b = weights[at + o * i : at + o * (i + 1)]
            at += o * (i + 1)
            h = ca.mtimes(w, h) + ca.repmat(b, 1, n)
            if layer < len(self.layers) - 1:
                h = ca.tanh(h)
        return h

    def expression(self, w: feats.Waypoint, weights) -> ca.SX:
        return self.forward(_inputs(w, self.inputs), weights)

    def initial(self, rng: np.random.Generator) -> np.ndarray:
        """Glorot-uniform weights, zero biases, drawn from ``rng``."""
        parts = []
        for i, o in self.layers:
            bound = math.sqrt(6.0 / (i + o))
            parts += [rng.uniform(-bound, bound, o * i), np.zeros(o)]
        return np.concatenate(parts)

    def normalised(self, weights: np.ndarray, low: float, high: float) -> np.ndarray:
        """The weights of (f_ψ − low) / (high − low): the output layer rescaled."""
        out = np.array(weights, float)
        i, _ = self.layers[-1]
        out[-(i + 1) :] /= high - low
        out[-1] -= low / (high - low)
        return out


@functools.cache
def _input_function(inputs: tuple[str, ...]) -> ca.Function:
    q = ca.SX.sym("q", N_ARM_JOINTS)
    e = ca.SX.sym("e", n_env_params())
    rot, pos = symbolic_fk(q, ("panda_hand",))["panda_hand"]
    cup = pos + rot @ ca.DM(g.CUP_CENTER_IN_HAND)
    w = feats.Waypoint(rot_hand=rot, pos_hand=pos, cup=cup, env=e)
    return ca.Function("learnt_inputs", [q, e], [_inputs(w, inputs)])


def state_inputs(configs: np.ndarray, env: Environment, network: Network) -> np.ndarray:
    """The network's inputs (n_in, n) at arm configurations (n, 7) in ``env``."""
    configs = np.atleast_2d(np.asarray(configs, float))
    f = _input_function(network.inputs).map(configs.shape[0])
    return np.asarray(f(configs.T, env.params()))


def evaluate(network: Network, weights: np.ndarray, x: np.ndarray) -> np.ndarray:
    """f_ψ at inputs x (n_in, n) -> (n,)."""
    return np.asarray(network.forward(ca.DM(x), ca.DM(weights))).ravel()


# --- the workspace -----------------------------------------------------------------------


def reachable(
    env: Environment, n: int, rng: np.random.Generator, *, batch: int = 256
) -> np.ndarray:
    """``n`` random reachable configurations (n, 7): uniform within the joint limits, the cup
    above the table's plane, no contact with the scene of ``env`` (MuJoCo)."""
    lo, hi = joint_limits()
    out: list[np.ndarray] = []
    have = 0
    while have < n:
        q = rng.uniform(lo, hi, size=(batch, N_ARM_JOINTS))
        q = q[reachable_mask(q, env)]
        out.append(q)
        have += q.shape[0]
    return np.concatenate(out)[:n]


def reachable_mask(q: np.ndarray, env: Environment) -> np.ndarray:
    """Which configurations (n, 7) within the joint limits are reachable: the cup above the
    table's plane, no contact with the scene of ``env`` (MuJoCo)."""
    cup = np.asarray(_input_function(("cup",)).map(q.shape[0])(q.T, env.params()))
    above = np.flatnonzero(cup[2] > g.TABLE_TOP_Z + 0.02)
    report = _checker().check_configurations(q[above], env)
    hit = {c.sample for c in report.contacts}
    mask = np.zeros(q.shape[0], bool)
    mask[[i for k, i in enumerate(above) if k not in hit]] = True
    return mask


@functools.cache
def _checker() -> CollisionChecker:
    return CollisionChecker()


@functools.lru_cache(maxsize=8)
def _workspace(env_key: bytes, env: Environment, n: int, seed: int) -> np.ndarray:
    return reachable(env, n, np.random.default_rng(seed))


def workspace(env: Environment, n: int = 2000, seed: int = 0) -> np.ndarray:
    """A fixed sample of ``n`` reachable configurations of ``env`` (the same for a seed)."""
    q = _workspace(env.key(), env, n, seed)
    q.setflags(write=False)
    return q


# --- traces and training -----------------------------------------------------------------


def check_traces(traces: Sequence[np.ndarray]) -> tuple[np.ndarray, ...]:
    """Traces as float arrays (n_i, 7), refused in one line when one has fewer than two
    states, a value that is not finite, or when every trace ends where it starts."""
    if len(traces) == 0:
        raise ValueError("traces: none given; a learnt feature needs at least one trace")
    out = []
    for i, trace in enumerate(traces):
        arr = np.asarray(trace, float)
        if arr.ndim != 2 or arr.shape[1] != N_ARM_JOINTS:
            raise ValueError(f"trace {i}: expected shape (n, {N_ARM_JOINTS}), got {arr.shape}")
        if arr.shape[0] < 2:
            raise ValueError(f"trace {i}: {arr.shape[0]} state(s); a trace needs at least 2")
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"trace {i}: a state is not finite (NaN or inf)")
        out.append(arr)
    if all(np.max(np.abs(t[0] - t[-1])) < 1e-6 for t in out):
        raise ValueError(
            "traces: every trace ends where it starts; a trace must go from where the feature "
            "is high to where it is low"
        )
    return tuple(out)


@dataclass(frozen=True)
class Training:
    """FERL's loss and our optimizer's settings.

    Attributes:
        equal_weight: weight of the "starts alike, ends alike" terms (FERL: 10).
        decay: L2 weight decay on the weights (not the biases).
        max_iter: iterations of :func:`corrections_sim.learnt.lbfgs.minimize` (which stops
            sooner where ‖∇‖∞ ≤ 1e-7 or the loss stops falling).
        workspace: reachable configurations the output is normalised over.
    """

    equal_weight: float = 10.0
    decay: float = 1e-4
    max_iter: int = 400
    workspace: int = 2000

    def __post_init__(self) -> None:
        for name in ("equal_weight", "decay"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ValueError(f"{name} = {value} must be finite and >= 0")
        if self.max_iter < 1 or self.workspace < 10:
            raise ValueError("max_iter must be >= 1 and workspace >= 10")


def ranking_pairs(lengths: Sequence[int]) -> tuple[np.ndarray, np.ndarray]:
    """(ordered, equal): index pairs (i, j) into the stacked states. Ordered: i before j on one
    trace (f_i > f_j); equal: the starts of two traces, and their ends."""
    ordered, starts, ends, at = [], [], [], 0
    for n in lengths:
        i, j = np.triu_indices(n, 1)
        ordered.append(np.stack([i + at, j + at], axis=1))
        starts.append(at)
        ends.append(at + n - 1)
        at += n
    equal = [
        (a[x], a[y]) for a in (starts, ends) for x in range(len(a)) for y in range(x + 1, len(a))
    ]
    return np.concatenate(ordered), np.array(equal, int).reshape(-1, 2)


def _difference(pairs: np.ndarray, n: int) -> ca.DM:
    """The sparse matrix D with (D f)_p = f_i − f_j for pair p = (i, j)."""
    m = pairs.shape[0]
    rows = np.repeat(np.arange(m), 2)
    cols = pairs.ravel()
    vals = np.tile([1.0, -1.0], m)
    return ca.DM.triplet(rows.tolist(), cols.tolist(), ca.DM(vals), m, n) if m else ca.DM(0, n)


def train(
    network: Network,
    inputs: Sequence[np.ndarray],
    rng: np.random.Generator,
    training: Training = Training(),
) -> tuple[np.ndarray, float]:
    """Weights ψ (raw, not normalised) minimising FERL's ranking loss over the traces'
    ``inputs`` (each (n_in, n_i)); returns them and the final loss."""
    x = np.concatenate(inputs, axis=1)
    ordered, equal = ranking_pairs([a.shape[1] for a in inputs])
    n = x.shape[1]
    psi = ca.MX.sym("psi", network.n_params)
    f = network.forward(ca.DM(x), psi).T  # (n, 1)
    d_ord = ca.mtimes(_difference(ordered, n), f)
    loss = ca.sum1(_softplus(-d_ord)) / max(ordered.shape[0], 1)
    if equal.shape[0]:
        d_eq = ca.mtimes(_difference(equal, n), f)
        eq = 0.5 * (_softplus(d_eq) + _softplus(-d_eq)) - math.log(2.0)
        loss += training.equal_weight * ca.sum1(eq) / equal.shape[0]
    mask = np.concatenate(
        [np.r_[np.ones(o * i), np.zeros(o)] for i, o in network.layers]
    )  # weights decay, biases do not
    loss += training.decay * ca.sumsqr(psi * ca.DM(mask))
    fg = ca.Function("ranking_loss", [psi], [loss, ca.gradient(loss, psi)])

    def objective(v: np.ndarray) -> tuple[float, np.ndarray]:
        value, grad = fg(v)
        return float(value), np.asarray(grad).ravel()

    # Our own L-BFGS, not SciPy's: its path is the same bits on every CPU (see lbfgs.py).
    result = lbfgs.minimize(objective, network.initial(rng), max_iter=training.max_iter, gtol=1e-7)
    return result.x, result.fun


def _softplus(z):
    """log(1 + eˣ), stable for large |x|."""
    return ca.fmax(z, 0) + ca.log1p(ca.exp(-ca.fabs(z)))


# --- the learnt feature ------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Learnt:
    """A learnt feature with where it came from.

    Attributes:
        name: its registered name.
        network: its shape.
        weights: ψ normalised to [0, 1] over the workspace (the planner's parameters).
        raw: the trained ψ before normalisation.
        low, high: the raw output's range over the workspace.
        traces: the traces it learnt from, (n_i, 7) each.
        env: the environment the traces were given in (the scene's inputs read it).
        loss: the ranking loss at the end of training.
        training: the loss's and optimizer's settings.
    """

    name: str
    network: Network
    weights: np.ndarray
    raw: np.ndarray
    low: float
    high: float
    traces: tuple[np.ndarray, ...]
    env: Environment
    loss: float
    training: Training = field(default_factory=Training)

    def values(self, configs: np.ndarray, env: Environment | None = None) -> np.ndarray:
        """The feature at configurations (n, 7), in ``env`` (default: the traces')."""
        x = state_inputs(configs, env or self.env, self.network)
        return evaluate(self.network, self.weights, x)

    def feature(self) -> feats.LearntFeature:
        return feats.LearntFeature(self.network, np.array(self.weights, float))

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "inputs": list(self.network.inputs),
            "hidden": list(self.network.hidden),
            "weights": self.weights.tolist(),
            "raw": self.raw.tolist(),
            "low": self.low,
            "high": self.high,
            "loss": self.loss,
            "training": {
                "equal_weight": self.training.equal_weight,
                "decay": self.training.decay,
                "max_iter": self.training.max_iter,
                "workspace": self.training.workspace,
            },
            "env": {
                "name": self.env.name,
                "laptop": self.env.laptop.tolist(),
                "table": self.env.table.tolist(),
                "extra": dict(self.env.extra),
                "q_start": self.env.q_start.tolist(),
                "q_goal": self.env.q_goal.tolist(),
            },
            "traces": [t.tolist() for t in self.traces],
        }

    def save(self, path: Path | str) -> Path:
        """Write it as JSON (weights, normalisation, traces, environment); refuses to
        overwrite a different learnt feature."""
        path = Path(path)
        text = json.dumps(self.to_dict(), indent=1)
        if path.exists() and path.read_text() != text:
            raise FileExistsError(f"{path}: holds another learnt feature; not overwritten")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
        return path


def learn(
    traces: Sequence[np.ndarray],
    env: Environment,
    rng: np.random.Generator,
    *,
    network: Network = Network(),
    training: Training = Training(),
    name: str | None = None,
) -> Learnt:
    """Train a feature on ``traces`` (each (n_i, 7), high to low) given in ``env``.

    Its name is ``name`` or ``learnt-<digest of its weights>``. Not registered: see
    :func:`register`.
    """
    traces = check_traces(traces)
    inputs = [state_inputs(t, env, network) for t in traces]
    raw, loss = train(network, inputs, rng, training)
    ws = evaluate(network, raw, state_inputs(workspace(env, training.workspace), env, network))
    low, high = float(ws.min()), float(ws.max())
    if not high - low > 1e-9:
        raise ValueError("learnt feature: constant over the workspace; the traces rank nothing")
    weights = network.normalised(raw, low, high)
    if name is None:
        name = "learnt-" + hashlib.sha256(weights.tobytes()).hexdigest()[:10]
    return Learnt(name, network, weights, raw, low, high, traces, env, loss, training)


def prepare_slot(config, network: Network):
    """The planner of ``config``'s features and one learnt feature of ``network``'s shape,
    built now (fatrop's library and the Newton re-solve's: on a machine's first use about two
    minutes, then loaded from the cache), so that a feature learnt later plans at once."""
    import dataclasses

    from corrections_sim.planning.planner import shared_planner

    slot = f"{network.slot}-{len(config.features)}"
    if slot not in feats.FEATURES:
        feats.FEATURES.register(slot, feats.LearntFeature(network))
    planner = shared_planner(dataclasses.replace(config, features=(*config.features, slot)))
    if planner.config.warm == "newton":
        planner._newton_path()  # what a first warm start builds (same package)
    return planner


def register(learnt: Learnt) -> str:
    """Register ``learnt`` as a feature under its name (again: a no-op when it is the same
    feature); refused in one line when the name is another feature's."""
    return _register(learnt.name, learnt.feature())


def register_logged(detail: Mapping) -> str:
    """Register the feature a session's ``learnt`` event names, from the network and weights
    it logged (what the session planned with), as :func:`register` does; its name."""
    network = Network(tuple(detail["inputs"]), tuple(detail["hidden"]))
    feature = feats.LearntFeature(network, np.asarray(detail["weights"], float))
    return _register(str(detail["feature"]), feature)


def _register(name: str, mine: feats.LearntFeature) -> str:
    have = feats.FEATURES.get(name)
    if have is not None:
        same = isinstance(have, feats.LearntFeature) and have.source() == mine.source()
        if not same:
            raise ValueError(f"learnt feature {name!r}: the name is a registered feature's")
        return name
    feats.FEATURES.register(name, mine)
    return name


def load(path: Path | str) -> Learnt:
    """A saved learnt feature (:meth:`Learnt.save`), registered; one-line errors."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
        e = data["env"]
        env = Environment(
            q_start=e["q_start"], q_goal=e["q_goal"], laptop=e["laptop"], table=e["table"],
            name=e["name"], extra=e["extra"],
        )  # fmt: skip
        learnt = Learnt(
            name=str(data["name"]),
            network=Network(tuple(data["inputs"]), tuple(data["hidden"])),
            weights=np.asarray(data["weights"], float),
            raw=np.asarray(data["raw"], float),
            low=float(data["low"]),
            high=float(data["high"]),
            traces=check_traces([np.asarray(t, float) for t in data["traces"]]),
            env=env,
            loss=float(data["loss"]),
            training=Training(**data["training"]),
        )
    except FileNotFoundError:
        raise ValueError(f"{path}: no such learnt feature file") from None
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a learnt feature ({exc})") from None
    if learnt.weights.shape != (learnt.network.n_params,):
        raise ValueError(
            f"{path}: {learnt.weights.size} weights, its network takes {learnt.network.n_params}"
        )
    register(learnt)
    return learnt


# --- quality against a known feature -----------------------------------------------------


@dataclass(frozen=True)
class Quality:
    """A learnt feature against the true one over random reachable configurations.

    Attributes:
        spearman: Spearman's ρ between them (FERL's measure).
        scale, offset: the best affine fit true ≈ scale · learnt + offset (least squares).
        r2: that fit's R².
        n: how many configurations.
    """

    spearman: float
    scale: float
    offset: float
    r2: float
    n: int


def quality(learnt: str, true: str, env: Environment, n: int = 10_000, seed: int = 1) -> Quality:
    """Compare the registered feature ``learnt`` with the registered ``true`` on ``n``
    reachable configurations of ``env`` (FERL's measure, per waypoint)."""
    q = workspace(env, n, seed)
    values = feats.waypoint_features(q, env, (learnt, true))
    mine, truth = values[:, 0], values[:, 1]
    rho = spearman(mine, truth)
    a = np.vstack([mine, np.ones_like(mine)]).T
    (scale, offset), *_ = np.linalg.lstsq(a, truth, rcond=None)
    resid = truth - a @ np.array([scale, offset])
    total = np.sum((truth - truth.mean()) ** 2)
    r2 = float(1 - np.sum(resid**2) / total) if total > 0 else float("nan")
    return Quality(float(rho), float(scale), float(offset), r2, int(q.shape[0]))


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation (average ranks for ties)."""
    from scipy.stats import spearmanr

    return float(spearmanr(a, b).statistic)
