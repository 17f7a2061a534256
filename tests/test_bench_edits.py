"""The edit-fidelity benchmark's ground truth: one scene, the object moved on the floor, removed, copied."""

from __future__ import annotations

import math

import numpy as np
import torch

from particlesplat.bench.edits import MOVE_RANGE, _dilate, _interior_pixel, edit_pairs
from particlesplat.data.families import tabletop
from particlesplat.data.synth import scene_cameras


def test_edit_pairs_move_remove_and_copy_one_object_on_the_floor():
    pairs = edit_pairs(0, "test", 1, 64, [4, 16])
    orig, k = pairs["original"], pairs["object"]
    obj = orig.objects[k]
    dx, dy = pairs["offsets"]["move"]
    assert MOVE_RANGE[0] <= math.hypot(dx, dy) <= MOVE_RANGE[1]
    moved = pairs["move"].objects[k]  # the same instance id
    np.testing.assert_allclose(np.subtract(moved.center, obj.center), [dx, dy, 0.0], atol=1e-12)
    assert [o for i, o in enumerate(pairs["move"].objects) if i != k] == orig.objects[:k] + orig.objects[k + 1 :]
    assert pairs["remove"].objects == orig.objects[:k] + orig.objects[k + 1 :]
    copy = pairs["duplicate"].objects[-1]
    assert pairs["duplicate"].objects[:-1] == orig.objects
    np.testing.assert_allclose(np.subtract(copy.center, obj.center), [*pairs["offsets"]["duplicate"], 0.0])
    for scene in (pairs["move"], pairs["duplicate"]):  # nothing overlaps on the floor
        for i, a in enumerate(scene.objects):
            for b in scene.objects[i + 1 :]:
                assert (
                    math.hypot(a.center[0] - b.center[0], a.center[1] - b.center[1])
                    >= a.footprint_radius + b.footprint_radius
                )
    # the pick lies on the object in its frame
    cam = scene_cameras(orig, 64)[pairs["pick"].frame]
    _, _, inst = tabletop.render_view(orig, cam.K.numpy(), cam.c2w.numpy(), 64, 64)
    x, y = pairs["pick"].pixel
    assert inst[y, x] == k + 1


def test_interior_pixel_and_dilation():
    mask = torch.zeros(9, 12, dtype=torch.bool)
    mask[2:7, 3:10] = True  # rows 2..6, columns 3..9: the centre is (6, 4)
    assert _interior_pixel(mask) == (6, 4)
    grown = _dilate(mask[None], 1)[0]
    assert int(grown.sum()) == 7 * 9 and bool(grown[1, 2]) and not bool(grown[0, 2])
