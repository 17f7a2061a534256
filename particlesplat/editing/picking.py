"""Picking: which object a pixel of an input frame shows, and which pixel names an object.

An edit file names each object it acts on by a pixel of an input frame (:class:`particlesplat.editing.edit_fields.
Pick`), resolved on the scene as the operations before it left it: the object whose particles weigh most at that
pixel. Saving goes the other way: the most interior pixel of the object in the frame that shows most of it.
"""

from __future__ import annotations

from dataclasses import replace

import torch
from torch import Tensor

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.editing.edit_fields import Pick, PickError
from particlesplat.editing.edited import EditedParticles
from particlesplat.model.particles import Particles
from particlesplat.rendering.api import render
from particlesplat.rendering.pixel import pixel_weights

MIN_PICK_PIXELS = 2  # an object must cover this many pixels of a frame to be picked there when saving


class Picker:
    """Picks on the input frames of one scene.

    Args:
        frame_cameras: the scene's input cameras at their stored size, indexed by frame (picks name these).
        context: the context frame indices (searched first when saving a pick).
    """

    def __init__(self, frame_cameras: list[Camera], context: list[int] | None) -> None:
        self.frame_cameras = frame_cameras
        self.context = context

    def frame_camera(self, frame: int, where: str) -> Camera:
        if not 0 <= frame < len(self.frame_cameras):
            raise PickError(f"{where}: pick.frame {frame}: the scene has frames 0..{len(self.frame_cameras) - 1}")
        return self.frame_cameras[frame]

    def object_map(
        self,
        scene: EditedParticles,
        frame: int,
        particles: Particles | None = None,
        where: str = "pick",
        labels: Tensor | None = None,
    ) -> Tensor:
        """(H, W) int64 object label per pixel of input frame ``frame`` at its stored size (-1 background), of
        ``particles`` (default: the current ones) grouped as ``labels`` (default: the current objects)."""
        p = scene.particles if particles is None else particles
        labels = (scene.objects().labels if labels is None else labels)[: p.num]
        return label_render(scene, scene.decode(p), self.frame_camera(frame, where), labels)

    def pixel_object(self, scene: EditedParticles, frame: int, cam: Camera, pixel: tuple[int, int]) -> int:
        """The object label at ``pixel`` of frame ``frame`` on the current particles, -1 for the background, as
        :meth:`object_map` has it there; composited from the Gaussians that reach the pixel alone, so a pick costs
        what they cost, not what the whole scene does."""
        g = scene.decoded.reaching(scene.particles, cam, frame, pixel)
        index, weights = pixel_weights(g, cam.to("cpu", torch.float32), pixel)
        labels = scene.objects().labels
        owner = g.owner[index]
        label = torch.where(owner >= 0, labels[owner.clamp_min(0)], owner)
        count = int(labels.max()) + 1 if labels.numel() else 0
        scores = torch.zeros(1 + count, dtype=torch.float64)
        scores.index_add_(0, (label + 1).clamp_min(0), weights.double())
        scores[0] += 1.0 - float(weights.double().sum())  # the empty remainder counts as background
        return int(scores.argmax()) - 1

    def pick(self, scene: EditedParticles, pick: Pick, where: str = "pick") -> int:
        """The first particle of the object under ``pick`` on the current particles; PickError names ``where``
        when the pixel shows no object."""
        cam = self.frame_camera(pick.frame, where)
        x, y = pick.pixel
        if not (0 <= x < cam.width and 0 <= y < cam.height):
            raise PickError(f"{where}: pick.pixel [{x}, {y}] is outside frame {pick.frame} ({cam.width}x{cam.height})")
        label = self.pixel_object(scene, pick.frame, cam, (x, y))
        if label < 0:
            raise PickError(f"{where}: pick {{frame: {pick.frame}, pixel: [{x}, {y}]}} hits no object (background)")
        return int(torch.nonzero(scene.objects().labels == label)[0])

    def pick_for(
        self, scene: EditedParticles, index: int, particles: Particles | None = None, labels: Tensor | None = None
    ) -> Pick:
        """A pixel of an input frame that picks particle ``index``'s object on ``particles`` grouped as ``labels``
        (default: now): the object's most interior pixel in the context frame (else any frame) where it covers most
        pixels."""
        labels = scene.objects().labels if labels is None else labels
        label = int(labels[index])
        if label < 0:
            raise PickError(f"object of particle {index}: it draws nothing, so no pick names it")
        context = list(self.context or [])
        frames = context + [f for f in range(len(self.frame_cameras)) if f not in context]
        best: tuple[int, int, Tensor] | None = None
        for i, f in enumerate(frames):
            mask = self.object_map(scene, f, particles, labels=labels) == label
            count = int(mask.sum())
            if count >= MIN_PICK_PIXELS and (best is None or count > best[1]):
                best = (f, count, mask)
            if best is not None and i + 1 >= len(context):
                break  # the context frames are searched in full, the others until one shows the object
        if best is None:
            raise PickError(f"object of particle {index}: not visible in any input frame, so no pick names it")
        f, _, mask = best
        x, y = interior_pixel(mask)
        return Pick(f, (x, y))


def interior_pixel(mask: Tensor) -> tuple[int, int]:
    """(x, y) of the pixel of (H, W) bool ``mask`` farthest inside it (erosion depth), the one nearest the mask's
    centroid among equals."""
    depth = torch.zeros(mask.shape, dtype=torch.float32)
    cur = mask.float()[None, None]
    while bool(cur.any()):
        depth += cur[0, 0]
        cur = -torch.nn.functional.max_pool2d(-cur, 3, stride=1, padding=1)
    ys, xs = torch.nonzero(depth == depth.max(), as_tuple=True)
    cy, cx = mask.nonzero().float().mean(0)
    k = int(((ys.float() - cy) ** 2 + (xs.float() - cx) ** 2).argmin())
    return int(xs[k]), int(ys[k])


def label_render(scene: EditedParticles, g: Gaussians, cam: Camera, labels: Tensor) -> Tensor:
    """(H, W) int64 object label per pixel of Gaussians ``g`` (owner = particle) seen by ``cam``; labels:
    (particles,) object per particle."""
    # the rasteriser sums each object's weights itself: owners are object labels (a particle in no object draws as
    # background, as object_segmentation counts it), so the owner weights hold one plane per object, not one per
    # particle (a scene grown by many duplicates would need particles x pixels of them)
    g = replace(g, owner=torch.where(g.owner >= 0, labels.to(g.owner.device)[g.owner.clamp_min(0)], g.owner))
    count = int(labels.max()) + 1 if labels.numel() else 0
    if count <= 0:
        return torch.full((cam.height, cam.width), -1, dtype=torch.int64)
    with torch.no_grad():
        res = render(
            g,
            cam.to("cpu", torch.float32),
            background=scene.model.backdrop(scene.particles).cpu(),
            owner_weights=True,
            num_owners=count,
        )
    return res.segmentation()
