r"""A compiled clearance certificate (``PlannerConfig.certificate``): MuJoCo's check skipped
only where it could not find a contact.

Every plan is checked by :meth:`~corrections_sim.scene.world.CollisionChecker.check_trajectory`:
``mj_kinematics`` + ``mj_collision`` at 89 samples (12 waypoints, 8 samples a segment),
≈ 0.55 ms, a quarter of a warm re-solve. This module bounds, in one C call, every distance
MuJoCo could report at those same samples from below. When every bound exceeds
:data:`MARGIN`, no geom pair can touch, MuJoCo's check would report no contact, and
:class:`CertifiedChecker` returns that report without running it; otherwise MuJoCo's check
runs as before. So a check's answer never changes, only its cost.

**The bound.** Every step can only lower it:

* **The pairs** are MuJoCo's own filter (:func:`geom_pairs`): geoms of different weld
  bodies, not both static, with matching contype/conaffinity, not excluded, not parent and
  child. ``tests/test_clearance.py`` checks that every pair MuJoCo reports in contact on
  random configurations is among them.
* **Moving geoms are capsules**: a cylinder lies inside the capsule of its axis and radius, a
  sphere is a capsule of length 0, and a sphere inside a capsule of its frame joins it.
* **Static geoms are boxes** (a cylinder, sphere or capsule by its bounding box), or
  horizontal planes.
* **Capsule–box**: along each box axis the projections of the capsule's segment and of the
  box are at least the gap of their intervals apart, so the distance is at least the norm of
  the three gaps minus the radius. **Capsule–plane**: the lower end's height minus the
  radius. **Capsule–capsule**: each covered by two spheres of radius r + L/4 around its
  quarter points; the least of the four sphere–sphere distances.
* **Pruning**: each arm frame's capsules lie in one covering sphere. A frame's sphere is
  tested first against each static and each other frame's sphere; only a pair whose sphere
  bound is at most :data:`MARGIN` is bounded capsule by capsule. The C code stops at the
  first capsule bound at or below :data:`MARGIN`: the trajectory goes to MuJoCo.

Frames come from the same MuJoCo model by their own forward kinematics (a chain of hinges
about z, read from the model and checked against ``mj_kinematics`` in the tests); the static
geoms from the model after the environment is placed.

CasADi-generated code evaluates every pair at every sample (it has no branches): measured at
1.63 ms a trajectory (a bound per sample) and 1.04 ms (a swept bound per segment, certifying
82%), slower than MuJoCo. The pruning is what makes the bound cheap, so the bound is
hand-written C (``clearance.c``), compiled once per machine into the planner's cache.
"""

from __future__ import annotations

import ctypes
import hashlib
import inspect
import shutil
import tempfile
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np

from corrections_sim.planning import compiled
from corrections_sim.planning.compiled import build_once, build_shared_library
from corrections_sim.scene.environments import Environment
from corrections_sim.scene.world import CollisionChecker, CollisionReport, check_waypoints

#: A trajectory is certified when every bound exceeds this (metres): far above MuJoCo's
#: narrow-phase error and the two forward kinematics' difference (≈ 1e-15 m).
MARGIN = 1e-4

_PLANE, _SPHERE, _CAPSULE, _CYLINDER, _BOX = (
    int(mujoco.mjtGeom.mjGEOM_PLANE),
    int(mujoco.mjtGeom.mjGEOM_SPHERE),
    int(mujoco.mjtGeom.mjGEOM_CAPSULE),
    int(mujoco.mjtGeom.mjGEOM_CYLINDER),
    int(mujoco.mjtGeom.mjGEOM_BOX),
)
_HINGE = int(mujoco.mjtJoint.mjJNT_HINGE)
_SOURCE = "clearance.c"
#: Environments whose static geoms are kept (a figure meets 48).
_ENVIRONMENTS_KEPT = 256


class CertificateError(ValueError):
    """The model holds something the certificate cannot bound (the message says what)."""


def geom_pairs(model: mujoco.MjModel) -> list[tuple[int, int]]:
    """The geom pairs ``mj_collision`` tests (its filter; explicit ``<pair>`` s refused)."""
    if model.npair:
        raise CertificateError(f"the model has {model.npair} explicit <pair> elements")
    weld, parent = model.body_weldid, model.body_parentid
    excluded = {int(s) for s in model.exclude_signature}
    filter_parent = not model.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT
    out = []
    for i in range(model.ngeom):
        for j in range(i + 1, model.ngeom):
            b1, b2 = int(model.geom_bodyid[i]), int(model.geom_bodyid[j])
            w1, w2 = int(weld[b1]), int(weld[b2])
            if w1 == w2:
                continue
            if not (model.geom_contype[i] & model.geom_conaffinity[j]) and not (
                model.geom_contype[j] & model.geom_conaffinity[i]
            ):
                continue
            if (min(b1, b2) << 16) + max(b1, b2) in excluded:
                continue
            p1, p2 = int(weld[parent[w1]]), int(weld[parent[w2]])
            if filter_parent and w1 != 0 and w2 != 0 and (w1 == p2 or w2 == p1):
                continue
            out.append((i, j))
    return out


@dataclass(frozen=True)
class _Capsule:
    frame: int  # index into the chain of arm frames
    a: np.ndarray  # segment ends and radius, in the frame
    b: np.ndarray
    radius: float
    geoms: tuple[int, ...]


def _chain(model: mujoco.MjModel) -> list[int]:
    """The weld bodies that move, base to tip: each a hinge about its z axis at its origin,
    the child of the one before, the i-th turned by qpos[i]."""
    weld = model.body_weldid
    moving = sorted({int(w) for w in weld if w != 0})
    for i, body in enumerate(moving):
        if model.body_jntnum[body] != 1:
            raise CertificateError(f"body {model.body(body).name!r}: expected one joint")
        j = int(model.body_jntadr[body])
        if (
            model.jnt_type[j] != _HINGE
            or not np.allclose(model.jnt_axis[j], [0, 0, 1])
            or np.any(model.jnt_pos[j] != 0)
            or model.jnt_qposadr[j] != i
        ):
            raise CertificateError(f"joint {j}: expected a hinge about z at qpos[{i}]")
        expected = moving[i - 1] if i else None
        up = int(weld[model.body_parentid[body]])
        if i and up != expected or not i and up != 0:
            raise CertificateError(f"body {model.body(body).name!r} is not on one chain")
    return moving


def _capsules(model, data, chain) -> list[_Capsule]:
    index = {body: i for i, body in enumerate(chain)}
    capsules, spheres = [], []
    for g in range(model.ngeom):
        frame_body = int(model.body_weldid[model.geom_bodyid[g]])
        if frame_body == 0:
            continue
        frame = index[frame_body]
        to_frame = np.array(data.xmat[frame_body]).reshape(3, 3).T
        centre = to_frame @ (data.geom_xpos[g] - data.xpos[frame_body])
        axis = to_frame @ np.array(data.geom_xmat[g]).reshape(3, 3)[:, 2]
        kind, size = int(model.geom_type[g]), model.geom_size[g]
        if kind in (_CYLINDER, _CAPSULE):
            r, h = float(size[0]), float(size[1])
            capsules.append(_Capsule(frame, centre - h * axis, centre + h * axis, r, (g,)))
        elif kind == _SPHERE:
            spheres.append((g, frame, centre, float(size[0])))
        else:
            raise CertificateError(
                f"moving geom {g}: type {kind} is not a sphere, capsule or cylinder"
            )
    for g, frame, centre, radius in spheres:
        for i, c in enumerate(capsules):
            if c.frame != frame or np.allclose(c.a, c.b):
                continue
            ab = c.b - c.a
            t = np.clip(np.dot(centre - c.a, ab) / np.dot(ab, ab), 0.0, 1.0)
            reach = np.linalg.norm(centre - (c.a + t * ab)) + radius
            if reach <= c.radius + 1e-9:  # inside (up to rounding, which widens the capsule)
                capsules[i] = _Capsule(c.frame, c.a, c.b, max(c.radius, reach), (*c.geoms, g))
                break
        else:
            capsules.append(_Capsule(frame, centre, centre, radius, (g,)))
    return capsules


def _covering_sphere(capsules: list[_Capsule]) -> tuple[np.ndarray, float]:
    """A sphere holding every capsule (centre of their ends' bounding box)."""
    ends = np.array([e for c in capsules for e in (c.a, c.b)])
    centre = 0.5 * (ends.min(axis=0) + ends.max(axis=0))
    radius = max(
        max(np.linalg.norm(c.a - centre), np.linalg.norm(c.b - centre)) + c.radius for c in capsules
    )
    return centre, radius * (1 + 1e-12) + 1e-12


def _group_pairs(pairs, capsules):
    """The geom pairs by arm frame: {(frame, static geom): capsules} and
    {(frame, frame): capsule pairs}, lower frame first."""
    owner = {g: i for i, c in enumerate(capsules) for g in c.geoms}
    static_pairs: dict[tuple[int, int], set[int]] = {}
    moving_pairs: dict[tuple[int, int], set[tuple[int, int]]] = {}
    for g1, g2 in pairs:
        if g1 in owner and g2 in owner:
            i, j = sorted((owner[g1], owner[g2]))
            fi, fj = capsules[i].frame, capsules[j].frame
            key = (fi, fj) if fi < fj else (fj, fi)
            moving_pairs.setdefault(key, set()).add((i, j) if fi < fj else (j, i))
        else:
            cap, other = (owner[g1], g2) if g1 in owner else (owner[g2], g1)
            static_pairs.setdefault((capsules[cap].frame, other), set()).add(cap)
    return static_pairs, moving_pairs


class ClearanceCertificate:
    """The certificate for one :class:`CollisionChecker`'s model (see the module docstring).

    Args:
        checker: the checker whose verdicts the certificate stands in for; its model places
            the environments.
        library: the compiled ``clearance.c`` (built there when missing, see
            :func:`library_key`).

    Raises:
        CertificateError: the model is not a chain of z hinges with sphere, capsule and
            cylinder geoms against boxes, cylinders, spheres, capsules and horizontal planes.

    Attributes:
        pairs: the geom pairs MuJoCo tests (:func:`geom_pairs`).
        capsules: the moving geoms as capsules, each with the geoms it covers.
        statics: the static geoms some pair meets.
        entries: what :meth:`details` bounds, in order: ("static", capsule, geom) and
            ("moving", capsule, capsule).
    """

    def __init__(self, checker: CollisionChecker, library: Path) -> None:
        self.checker = checker
        model = checker.model
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        chain = _chain(model)
        self.n_frames = len(chain)
        self.capsules = _capsules(model, data, chain)
        self.pairs = geom_pairs(model)
        static_pairs, moving_pairs = _group_pairs(self.pairs, self.capsules)
        self.statics = sorted({s for _, s in static_pairs})
        self._mi, self.entries = self._integer_tables(model, data, static_pairs, moving_pairs)
        self._md = self._double_tables(model, data, chain)
        self._placed: dict[bytes, np.ndarray] = {}
        library = Path(library)
        build_once(library, build_library)
        lib = ctypes.CDLL(str(library))
        p, i, d = ctypes.c_void_p, ctypes.c_int, ctypes.c_double
        self._bound = lib.clearance_bound
        self._bound.restype = d
        self._bound.argtypes = [p, p, p, p, i, i, i, d, d]
        self._details = lib.clearance_details
        self._details.restype = i
        self._details.argtypes = [p, p, p, p, p, p, p]

    def _integer_tables(self, model, data, static_pairs, moving_pairs):
        """``clearance.c``'s integer table (its layout is in the C file's opening comment),
        and the entries :meth:`details` reports, in order: ("static", capsule, geom) and
        ("moving", capsule, capsule)."""
        kinds = []
        for g in self.statics:
            kind = int(model.geom_type[g])
            if kind == _PLANE:
                normal = np.array(data.geom_xmat[g]).reshape(3, 3)[:, 2]
                if not np.allclose(normal, [0, 0, 1]):
                    raise CertificateError(f"plane geom {g} is not horizontal")
            elif kind not in (_BOX, _CYLINDER, _SPHERE, _CAPSULE):
                raise CertificateError(f"static geom {g}: type {kind} has no bounding box here")
            kinds.append(1 if kind == _PLANE else 0)
        column = {g: i for i, g in enumerate(self.statics)}
        entries: list[tuple[str, int, int]] = []
        fs, caps = [], []
        for (frame, geom), members in sorted(static_pairs.items()):
            fs += [frame, column[geom], len(caps), len(members)]
            caps += sorted(members)
            entries += [("static", c, geom) for c in sorted(members)]
        ff, cap_pairs = [], []
        for (f1, f2), members in sorted(moving_pairs.items()):
            ff += [f1, f2, len(cap_pairs) // 2, len(members)]
            for i, j in sorted(members):
                cap_pairs += [i, j]
                entries.append(("moving", i, j))
        header = [self.n_frames, len(self.capsules), len(self.statics), len(fs) // 4, len(ff) // 4]
        frames = [c.frame for c in self.capsules]
        table = np.array(header + kinds + frames + fs + ff + caps + cap_pairs, dtype=np.intc)
        return table, entries

    def _double_tables(self, model, data, chain) -> np.ndarray:
        """``clearance.c``'s table of doubles: the base frame, each frame's offset, sphere
        and reach, each capsule."""
        base = int(model.body_weldid[model.body_parentid[chain[0]]])
        doubles = [np.array(data.xmat[base]), np.array(data.xpos[base])]
        for body in chain:
            rot = np.zeros(9)
            mujoco.mju_quat2Mat(rot, model.body_quat[body])
            doubles += [np.array(model.body_pos[body]), rot]
        spheres = [
            _covering_sphere([c for c in self.capsules if c.frame == f])
            for f in range(self.n_frames)
        ]
        for centre, radius in spheres:
            doubles += [centre, [radius]]
        for c in self.capsules:
            doubles += [c.a, c.b, [c.radius]]
        # reach[f][j]: joint j's axis passes through frame j's origin, so a point of frame
        # f's sphere lies within the offsets from frame j to f plus the sphere's far side.
        links = [float(np.linalg.norm(model.body_pos[body])) for body in chain]
        reach = np.zeros((self.n_frames, self.n_frames))
        for f, (centre, radius) in enumerate(spheres):
            for j in range(f + 1):
                reach[f, j] = sum(links[j + 1 : f + 1]) + np.linalg.norm(centre) + radius
        doubles.append(reach)
        return np.concatenate([np.ravel(d) for d in doubles]).astype(float)

    def _place(self, env: Environment) -> np.ndarray:
        """The static geoms (centre, axes, half-sizes; a plane's height) in ``env``,
        computed once per environment."""
        key = env.key()
        found = self._placed.get(key)
        if found is not None:
            return found
        self.checker.set_environment(env)
        model = self.checker.model
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        rows = []
        for g in self.statics:
            rot = np.array(data.geom_xmat[g]).reshape(3, 3)
            kind, size = int(model.geom_type[g]), model.geom_size[g]
            half = {
                _BOX: size[:3],
                _CYLINDER: [size[0], size[0], size[1]],
                _CAPSULE: [size[0], size[0], size[1] + size[0]],
                _SPHERE: [size[0]] * 3,
                _PLANE: [0.0] * 3,
            }[kind]
            rows.append(np.concatenate([data.geom_xpos[g], rot.T.ravel(), half]))
        if len(self._placed) >= _ENVIRONMENTS_KEPT:
            self._placed.pop(next(iter(self._placed)))
        placed = self._placed[key] = np.ascontiguousarray(np.concatenate(rows), dtype=float)
        return placed

    def bound(
        self, waypoints: np.ndarray, env: Environment, substeps: int = 8, stop: float | None = None
    ) -> float:
        """The least lower bound on any pair's distance at the samples ``check_trajectory``
        takes of ``waypoints`` (T, 7) with ``substeps``, metres. With ``stop``, only pairs
        whose frames' spheres come within ``stop`` are bounded capsule by capsule, and the
        first capsule bound at or below ``stop`` is returned at once: the answer is above
        ``stop`` exactly when every pair's is."""
        waypoints, substeps = check_waypoints(waypoints, substeps)
        statics = self._place(env)
        value = self._bound(
            self._mi.ctypes.data,
            self._md.ctypes.data,
            statics.ctypes.data,
            waypoints.ctypes.data,
            waypoints.shape[0],
            waypoints.shape[1],
            substeps,
            np.inf if stop is None else float(stop),
            -np.inf if stop is None else float(stop),
        )
        if np.isnan(value):
            raise RuntimeError("clearance_bound refused its tables")
        return float(value)

    def certifies(self, waypoints: np.ndarray, env: Environment, substeps: int = 8) -> bool:
        """True when ``check_trajectory(waypoints, env, substeps=substeps)`` would find no
        contact for certain."""
        return self.bound(waypoints, env, substeps, MARGIN) > MARGIN

    def details(self, q: np.ndarray, env: Environment) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """At one configuration q (7,): the frames' world poses (n_frames, 3, 4), and per
        :attr:`entries` its capsule bound and its frames' sphere bound (for the tests)."""
        q = np.ascontiguousarray(q, dtype=float)
        poses = np.zeros(12 * self.n_frames)
        fine, coarse = np.zeros(len(self.entries)), np.zeros(len(self.entries))
        statics = self._place(env)
        args = (self._mi, self._md, statics, q, poses, fine, coarse)
        if self._details(*(a.ctypes.data for a in args)) != 0:
            raise RuntimeError("clearance_details refused its tables")
        poses = poses.reshape(self.n_frames, 12)
        frames = np.concatenate([poses[:, :9].reshape(-1, 3, 3), poses[:, 9:, None]], axis=2)
        return frames, fine, coarse


class CertifiedChecker:
    """A :class:`CollisionChecker` whose trajectory checks skip MuJoCo where the certificate
    holds (same answers; see the module docstring). ``certified`` and ``checked`` count the
    trajectories each way."""

    def __init__(self, checker: CollisionChecker, library: Path) -> None:
        self.checker = checker
        self.certificate = ClearanceCertificate(checker, library)
        self.certified = 0
        self.checked = 0

    def check_trajectory(
        self, waypoints: np.ndarray, env: Environment, *, substeps: int = 8
    ) -> CollisionReport:
        if self.certificate.certifies(waypoints, env, substeps):
            self.certified += 1
            n_samples = (len(waypoints) - 1) * int(substeps) + 1
            return CollisionReport((), n_samples, int(substeps))
        self.checked += 1
        return self.checker.check_trajectory(waypoints, env, substeps=substeps)


def library_key() -> str:
    """The compiled certificate's file name key: its C source, this module and how it is
    compiled."""
    h = hashlib.sha256(resources.files(__package__).joinpath(_SOURCE).read_bytes())
    for module in (inspect.getmodule(ClearanceCertificate), compiled):
        h.update(inspect.getsource(module).encode())
    return h.hexdigest()[:20]


def build_library(library: Path) -> None:
    """``clearance.c`` compiled into ``library`` (atomically)."""
    library.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=library.parent) as scratch:
        source = Path(scratch) / _SOURCE
        with resources.as_file(resources.files(__package__).joinpath(_SOURCE)) as packaged:
            shutil.copyfile(packaged, source)
        build_shared_library(source, library)
