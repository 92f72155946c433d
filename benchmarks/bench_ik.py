"""The package's IK against dm-control's: ``python -m benchmarks.bench_ik``.

Needs the optional extra (``pip install -e ".[compare]"``: dm-control 1.0.50, which also
needs mujoco < 4). Both solve the same problems: the cup centre at a position with the hand
pointing down, from the seed :func:`corrections_sim.scene.environments.configuration_at` uses; the
study's 4 starts and its goal, then ``--samples`` random positions over the table (the kind
of points figs. 1-2 grid over). A solution counts when it converged and lies within the
joint limits (dm-control's solver does not know them). Errors are measured independently
with pinocchio's FK. It prints and never asserts.
"""

from __future__ import annotations

import argparse
import time

import mujoco
import numpy as np

from corrections_sim.scene import environments, robot
from corrections_sim.scene import world as scene


def _dm_control_solver():
    try:
        from dm_control import mujoco as dm_mujoco
        from dm_control.utils.inverse_kinematics import qpos_from_site_pose
    except ImportError:
        raise SystemExit('dm-control is not installed: pip install -e ".[compare]"') from None
    spec = scene.build_spec()
    spec.body(scene.CUP_BODY).add_site(name="cup_site")
    physics = dm_mujoco.Physics.from_xml_string(spec.to_xml())

    def solve(target: np.ndarray, yaw: float, seed: np.ndarray) -> np.ndarray | None:
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, robot.hand_down_rotation(yaw).ravel())
        physics.data.qpos[:] = seed
        result = qpos_from_site_pose(
            physics, "cup_site", target_pos=target, target_quat=quat, tol=1e-6, max_steps=200
        )
        return result.qpos[: robot.N_ARM_JOINTS].copy() if result.success else None

    return solve


def _errors(q: np.ndarray, target: np.ndarray, yaw: float) -> tuple[float, float]:
    """Cup position error (m) and hand orientation error (rad)."""
    rot, pos = robot.cup_pose(q)
    cos = (np.trace(robot.hand_down_rotation(yaw).T @ rot) - 1) / 2
    return float(np.linalg.norm(pos - target)), float(np.arccos(np.clip(cos, -1.0, 1.0)))


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.bench_ik", description=__doc__)
    p.add_argument("--samples", type=int, default=300, help="random cup positions (300)")
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    import logging

    logging.getLogger("absl").setLevel(logging.ERROR)  # one warning per failed solve
    rng = np.random.default_rng(args.seed)
    targets = [np.array(x, float) for x in environments.START_POSITIONS]
    targets.append(np.array(environments.GOAL_POSITION, float))
    low, high = (0.25, -0.5, 0.1), (0.75, 0.5, 0.45)
    targets += list(rng.uniform(low, high, size=(args.samples, 3)))
    lo, hi = robot.joint_limits()
    solvers = {"corrections_sim": robot.inverse_kinematics, "dm-control": _dm_control_solver()}
    solved = {}
    for name, solve in solvers.items():
        times, errors, ok, outside = [], [], [], 0
        for target in targets:
            seed = environments._IK_SEED.copy()  # the seed configuration_at uses
            seed[0] = np.arctan2(target[1], target[0])
            t0 = time.perf_counter()
            q = solve(target, 0.0, seed)
            times.append(time.perf_counter() - t0)
            if q is not None and not np.all((lo <= q) & (q <= hi)):
                outside += 1
                q = None
            ok.append(q is not None)
            if q is not None:
                errors.append(_errors(q, target, 0.0))
        solved[name] = np.array(ok)
        err = np.array(errors)
        print(
            f"{name:16s} solved {sum(ok)}/{len(targets)} (converged outside the joint limits: "
            f"{outside}); time median {1e3 * np.median(times):.2f} ms, 90th percentile "
            f"{1e3 * np.percentile(times, 90):.2f} ms; worst position error {err[:, 0].max():.1e}"
            f" m, orientation {err[:, 1].max():.1e} rad"
        )
    a, b = solved.values()
    print(f"solved by only one of them: {int(np.sum(a != b))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
