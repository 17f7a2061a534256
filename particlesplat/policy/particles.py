"""The particle input: a decision's two views encoded by a frozen ParticleSplat model (the shipped robot model
unless told otherwise) exactly as ``particlesplat encode`` encodes a scene folder, and the particle arrays turned
into a policy's rows.

A decision is written as a scene folder of the robot family (its two views' RGB, depth and masks, the rig's
cameras, and the robot's joint angles, base and gripper in ``scene.json``, which the robot model reads), then
encoded with :func:`particlesplat.analysis.particle_arrays.encode_scene_arrays` (context views 0 and 1): the same
arrays ``particlesplat encode`` writes to an ``.npz``. :func:`particle_rows` is the loader a user can take into
their own code: per particle, its decoded centroid, extent and colour, its transparency ``z_t``, whether it draws
the robot, its view, and its appearance latent (the first ``d_obj`` numbers of ``z_f``).
"""

from __future__ import annotations

import tempfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from .features import Step

CONTEXT = [0, 1]
STAT_DIMS = 3 + 3 + 3 + 1 + 1  # centroid, extent, colour, z_t, robot
PARTICLE_COLOUR = slice(6, 9)  # a particle row's RGB


def write_decision_scene(folder: Path, step: Step) -> None:
    """Write ``step``'s two views as a robot scene folder (it must not exist; its parent must)."""
    import torch

    from particlesplat.core.camera import Camera
    from particlesplat.data.families.robot_wide import GENERATOR
    from particlesplat.data.scene_files import write_scene_files

    if step.rgb is None or step.depth is None or step.intrinsics is None or step.c2w is None:
        raise ValueError("a decision's scene needs its views and cameras")
    H, W = step.rgb.shape[1:3]
    cams = [
        Camera(torch.as_tensor(K, dtype=torch.float64), torch.as_tensor(c2w, dtype=torch.float64), W, H)
        for K, c2w in zip(step.intrinsics, step.c2w, strict=True)
    ]
    meta = {
        "generator": GENERATOR,
        "family": "robot",
        "world": "wide",
        "world_frame": "robosuite",
        "support_z": 0.0,
        "arm_joints_rad": held_to_limits(step.joints),
        "robot_base": np.asarray(step.robot_base, dtype=np.float64).tolist(),
        "gripper": "panda",
    }
    folder.mkdir()
    masks = np.zeros(step.depth.shape, np.uint8)
    write_scene_files(folder, cams, step.rgb, step.depth, masks, meta)


def held_to_limits(joints) -> list[float]:
    """The arm's joint angles (7,) clipped to the Panda's limits: the simulator's limits are soft, and a joint
    pressed against one overshoots it by a milliradian, which a scene's reader refuses as no pose of the robot."""
    from particlesplat.data.pose_ranges import PANDA_JOINT_LIMITS

    lo, hi = np.array(PANDA_JOINT_LIMITS).T
    return np.clip(np.asarray(joints, np.float64), lo, hi).tolist()


class DecisionEncoder:
    """A frozen model that encodes decisions' views (``checkpoint``: None for the shipped robot model)."""

    def __init__(self, checkpoint: str | Path | None = None) -> None:
        from particlesplat.analysis.particle_arrays import file_sha256
        from particlesplat.data.families import get_family
        from particlesplat.model import load_model

        path = checkpoint if checkpoint is not None else get_family("robot").shipped_model_path()
        self.checkpoint = str(path)
        self.model = load_model(path)
        self.sha256 = file_sha256(path)
        self.d_obj = int(self.model.config.d_obj)

    @property
    def dims(self) -> int:
        """Numbers a particle's row holds."""
        return STAT_DIMS + self.d_obj

    def arrays(self, step: Step):
        """The decision's particle arrays (:class:`~particlesplat.analysis.particle_arrays.ParticleArrays`)."""
        from particlesplat.analysis.particle_arrays import encode_scene_arrays

        return self._in_scene(step, lambda folder: encode_scene_arrays(self.model, folder, CONTEXT))

    def _in_scene(self, step: Step, encode):
        """``encode(folder)`` without gradients, ``folder`` the decision written as a temporary scene folder."""
        import torch

        with tempfile.TemporaryDirectory(prefix="particlesplat-decision-") as tmp:
            folder = Path(tmp) / "scene"
            write_decision_scene(folder, step)
            with torch.no_grad():
                return encode(folder)

    def live_rows(self, step: Step) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`particle_rows` of the decision, the same numbers as its arrays' but without what rows do not
        read (the background's Gaussians, the objects' grouping and centres): a closed-loop decision's path."""
        import torch

        from particlesplat.analysis.particle_arrays import particle_stats
        from particlesplat.editing.open_scene import encode_scene

        def encode(folder: Path):
            p = encode_scene(self.model, folder, CONTEXT).particles
            return p, self.model.decode(p, background=False)

        p, g = self._in_scene(step, encode)
        p, g = p.detach().to("cpu"), g.detach().to("cpu")
        centroid, extent, colour, active, robot = particle_stats(self.model, p, g)

        def f32(t) -> np.ndarray:
            return t.detach().cpu().to(torch.float32).numpy()

        stats = SimpleNamespace(
            centroid=f32(centroid),
            extent=f32(extent),
            colour=f32(colour),
            z_t=f32(p.z_t),
            robot=robot.numpy().astype(bool),
            z_f=f32(p.z_f),
            active=active.numpy().astype(bool),
            view=p.view.cpu().to(torch.int64).numpy(),
        )
        return particle_rows(stats, self.d_obj)

    def rows(self, step: Step, cache: Path | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:func:`particle_rows` of the decision's arrays; with ``cache`` (an ``.npz`` path), read from there when
        it holds this model's encoding (its meta's checkpoint SHA-256), else encoded and written there; without,
        :meth:`live_rows`."""
        from particlesplat.analysis.particle_arrays import ParticleArrays

        if cache is None:
            return self.live_rows(step)
        if cache.is_file():
            arrays = ParticleArrays.load(cache)
            if arrays.meta.get("checkpoint_sha256") == self.sha256:
                return particle_rows(arrays, self.d_obj)
        arrays = self.arrays(step)
        arrays.meta["checkpoint_sha256"] = self.sha256
        cache.parent.mkdir(parents=True, exist_ok=True)
        arrays.save(cache)
        return particle_rows(arrays, self.d_obj)


def particle_rows(arrays, d_obj: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A policy's rows of particle arrays (``particlesplat encode``'s, :meth:`DecisionEncoder.arrays`, or anything
    with their ``centroid extent colour z_t robot z_f active view``):
    features (P, 11 + d_obj) float32 (centroid, extent and colour of its Gaussians, ``z_t``, the robot flag, then
    ``z_f[:, :d_obj]``), views (P,) int64 and active (P,) bool."""
    feats = np.concatenate(
        [
            arrays.centroid,
            arrays.extent,
            arrays.colour,
            arrays.z_t.reshape(-1, 1),
            arrays.robot.reshape(-1, 1).astype(np.float32),
            arrays.z_f[:, :d_obj],
        ],
        1,
    ).astype(np.float32)
    feats[~arrays.active] = 0.0
    return feats, arrays.view.astype(np.int64), arrays.active.astype(bool)
