"""IK on the robot's MuJoCo model (mink) for hands and head where an axis map is not enough.

A robot whose arm is not a copy of the human chain (two shoulder hinges at odd angles, say) cannot
be driven joint by joint. Instead the canonical skeleton's forward kinematics says where each hand
is relative to an anchor (the shoulder), in the canonical root's frame; that vector is turned into
the robot's axes, scaled, and added to the robot's own anchor, and mink moves the robot's frame
there. Joints not listed under ``ik.joints`` are frozen at their axis-map values, which also serve
as the posture the solution leans toward, so IK only fills in what the maps cannot.
"""

from __future__ import annotations

import mink  # noqa: E402  (after the loader, which picks the GL platform before mujoco loads)
import mujoco  # noqa: E402
import numpy as np

from convodrive import FPS
from convodrive.motion.rotations import axis_angle_to_matrix
from convodrive.motion.skeleton import JOINT_INDEX, forward_kinematics
from convodrive.plumbing.errors import InputFileError
from convodrive.retargeting.profile import RobotProfile
from convodrive.retargeting.profile_schema import IKConfig
from convodrive.sims.mjcf import hinge_qpos_addresses, load_model


class IKSolver:
    """Per-frame differential IK: ``solve(q_maps, rotmats) -> values of ik.joints``."""

    def __init__(self, profile: RobotProfile) -> None:
        assert profile.ik is not None and profile.model_path is not None
        self.cfg: IKConfig = profile.ik
        source = profile.path or profile.name
        self.model = load_model(profile.model_path, weld_root=True)
        model = self.model
        present = [n for n in profile.spec.names if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) >= 0]
        self.seed_cols = np.array([profile.spec.index[n] for n in present], dtype=int)
        self.seed_adr = np.array(hinge_qpos_addresses(model, present, source), dtype=int)
        self.ik_cols = np.array([profile.spec.index[n] for n in self.cfg.joints], dtype=int)
        self.ik_adr = np.array(hinge_qpos_addresses(model, self.cfg.joints, source), dtype=int)
        ik_dofs = {
            int(model.jnt_dofadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n)]) for n in self.cfg.joints
        }
        frozen = [d for d in range(model.nv) if d not in ik_dofs]

        kinds = {"body": mujoco.mjtObj.mjOBJ_BODY, "site": mujoco.mjtObj.mjOBJ_SITE, "geom": mujoco.mjtObj.mjOBJ_GEOM}
        for i, t in enumerate(self.cfg.tasks):
            if mujoco.mj_name2id(model, kinds[t.frame_type], t.frame) < 0:
                raise InputFileError(source, f"ik.tasks[{i}].frame: no {t.frame_type} {t.frame!r} in the model")
            if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, t.anchor_body) < 0:
                raise InputFileError(source, f"ik.tasks[{i}].anchor.body: no body {t.anchor_body!r} in the model")
        self.root_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, self.cfg.root_body)
        if self.root_body < 0:
            raise InputFileError(source, f"ik.root.body: no body {self.cfg.root_body!r} in the model")
        self.anchor_ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, t.anchor_body) for t in self.cfg.tasks]

        # Start from the rest pose moved inside every joint's range (a knee at rest may sit outside
        # it); otherwise the range limits of frozen joints make the QP infeasible.
        q_base = model.qpos0.copy()
        for j in range(model.njnt):
            if model.jnt_limited[j] and int(model.jnt_type[j]) in (
                int(mujoco.mjtJoint.mjJNT_HINGE),
                int(mujoco.mjtJoint.mjJNT_SLIDE),
            ):
                adr = model.jnt_qposadr[j]
                q_base[adr] = np.clip(q_base[adr], *model.jnt_range[j])
        self.q_base = q_base
        self.configuration = mink.Configuration(model, q_base)
        self.frame_tasks = [
            mink.FrameTask(
                t.frame,
                t.frame_type,
                position_cost=t.position_cost,
                orientation_cost=t.orientation_cost,
                lm_damping=1.0,
            )
            for t in self.cfg.tasks
        ]
        self.posture = mink.PostureTask(model, cost=self.cfg.posture_cost)
        self.limits = [mink.ConfigurationLimit(model)]
        self.constraints = [mink.DofFreezingTask(model, dof_indices=frozen)] if frozen else []
        # Each task frame's orientation in its root body's frame at rest, where the canonical
        # skeleton's global rotations are all identity: the offset that orientation targets keep.
        data = self.configuration.data
        mujoco.mj_forward(model, data)
        root_rot0 = data.xmat[self.root_body].reshape(3, 3)
        self.rest_offset = [
            root_rot0.T @ self.configuration.get_transform_frame_to_world(t.frame, t.frame_type).rotation().as_matrix()
            for t in self.cfg.tasks
        ]
        self.root_idx = JOINT_INDEX[self.cfg.root_canonical]
        self.q_prev: np.ndarray | None = None
        self.last_errors = np.zeros(len(self.cfg.tasks))

    def reset(self) -> None:
        self.q_prev = None

    def canonical_fk(self, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Global rotations and positions (T, 55, ...) of the canonical skeleton."""
        return forward_kinematics(axis_angle_to_matrix(np.asarray(pose, np.float64)))

    def targets(self, glob_r: np.ndarray, glob_p: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
        """World position and rotation targets for one frame, from the current configuration."""
        data = self.configuration.data
        a = self.cfg.axes
        root_rot = data.xmat[self.root_body].reshape(3, 3)
        c_root_t = glob_r[self.root_idx].T
        out = []
        for task, anchor, offset in zip(self.cfg.tasks, self.anchor_ids, self.rest_offset):
            v = c_root_t @ (glob_p[JOINT_INDEX[task.canonical]] - glob_p[JOINT_INDEX[task.anchor_canonical]])
            pos = data.xpos[anchor] + root_rot @ (self.cfg.scale * (a @ v))
            rot = root_rot @ a @ (c_root_t @ glob_r[JOINT_INDEX[task.canonical]]) @ a.T @ offset
            out.append((pos, rot))
        return out

    def solve(self, q_maps: np.ndarray, glob_r: np.ndarray, glob_p: np.ndarray) -> np.ndarray:
        """IK joint values for one frame; ``q_maps`` are all profile joints from the axis maps."""
        q = self.q_base.copy()
        q[self.seed_adr] = q_maps[self.seed_cols]
        self.posture.set_target(q.copy())
        if self.q_prev is not None:
            q[self.ik_adr] = self.q_prev
        self.configuration.update(q)
        first = self.q_prev is None
        goals = self.targets(glob_r, glob_p)
        for task, (pos, rot) in zip(self.frame_tasks, goals):
            task.set_target(mink.SE3.from_rotation_and_translation(mink.SO3.from_matrix(rot), pos))
        tasks = [*self.frame_tasks, self.posture]
        dt = 1.0 / FPS
        for _ in range(self.cfg.iterations * (4 if first else 1)):  # a cold start needs more steps
            try:
                vel = mink.solve_ik(
                    self.configuration,
                    tasks,
                    dt,
                    self.cfg.solver,
                    damping=self.cfg.damping,
                    limits=self.limits,
                    constraints=self.constraints,
                )
            except (mink.NoSolutionFound, TypeError, ValueError):
                break  # keep the last feasible configuration rather than fail the frame
            self.configuration.integrate_inplace(vel, dt)
        self.last_errors = np.array(
            [
                np.linalg.norm(
                    self.configuration.get_transform_frame_to_world(t.frame, t.frame_type).translation() - pos
                )
                for t, (pos, _) in zip(self.cfg.tasks, goals)
            ]
        )
        self.q_prev = self.configuration.q[self.ik_adr].copy()
        return self.q_prev.copy()
