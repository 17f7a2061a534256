"""The per-view background under an object (``background.opaque_under_objects``) and the least width of its
Gaussians (``background.min_width``): a camera 45° above the plane z = 0, anchors at the plane's exact depths, an
object's pixels hidden from the background. Once no particle's box covers them (an edit moved the object away), a
view from above sees the table's colour where the object stood, drawn opaque; the blocks a particle's box hides
with no object there, and every block while the boxes stay, are drawn as without the key."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
import torch
import torch.nn.functional as F

from particlesplat.core.camera import Camera
from particlesplat.core.gaussians import Gaussians
from particlesplat.core.sh import SH_C0
from particlesplat.model import ModelConfig
from particlesplat.model.config import ConfigError
from particlesplat.model.decoder import (
    UNDER_OBJECT_OPACITY,
    UNDER_OBJECT_PIXELS,
    UNDER_OBJECT_WIDTH,
    background_gaussians,
    block_anchors,
    gaussian_channels,
    split_gaussian_params,
)
from particlesplat.model.evidence import dilate
from particlesplat.model.geometry import quaternion_to_rotation_matrix
from particlesplat.rendering.api import render

RES, K_BLOCK, FOCAL = 32, 2, 40.0
TABLE = torch.tensor([0.9, 0.8, 0.7], dtype=torch.float64)


def _config(**kw) -> ModelConfig:
    base = {
        "resolution": RES,
        "bg_block": K_BLOCK,
        "bg_latent_stride": K_BLOCK,
        "bg_per_view": True,
        "bg_static_grid": 0,
        "fg_evidence": True,
        "bg_hidden_from_views": True,
        "d_min": 0.3,
        "d_max": 5.0,
    }
    return ModelConfig(**{**base, **kw})


def _camera() -> tuple[torch.Tensor, torch.Tensor]:
    """K (1, 3, 3), c2w (1, 4, 4) float64: 45° above the plane, 1.41 m from the point it looks at."""
    K = torch.tensor([[[FOCAL, 0, RES / 2], [0, FOCAL, RES / 2], [0, 0, 1]]], dtype=torch.float64)
    a = math.radians(45)
    R = torch.tensor([[1.0, 0, 0], [0, -math.sin(a), -math.cos(a)], [0, math.cos(a), -math.sin(a)]])
    c2w = torch.eye(4, dtype=torch.float64)[None]
    c2w[0, :3, :3] = R
    c2w[0, :3, 3] = torch.tensor([0.0, -1.0, 1.0])
    return K, c2w


def _scene():
    """The view's anchors (1, N, 6) with an object's pixels (rows and columns 12-19) hidden and counted as under an
    object (in its particle's box), and another particle's box (rows 2-7, columns 22-29) hidden but over no object;
    the hidden blocks' and object blocks' (N,) bool masks."""
    K, c2w = _camera()
    v, u = torch.meshgrid(torch.arange(RES) + 0.5, torch.arange(RES) + 0.5, indexing="ij")
    rays = torch.stack([(u - RES / 2) / FOCAL, (v - RES / 2) / FOCAL, torch.ones_like(u)], -1).double()
    rays = rays @ c2w[0, :3, :3].T
    depth = (-c2w[0, 2, 3] / rays[..., 2])[None, None]  # planar depth where each pixel's ray meets z = 0
    rgb = TABLE[None, :, None, None].expand(1, 3, RES, RES).clone()
    obj = torch.zeros(1, 1, RES, RES, dtype=torch.float64)
    obj[..., 12:20, 12:20] = 1.0
    box = torch.zeros_like(obj)
    box[..., 2:8, 22:30] = 1.0
    hidden = torch.maximum(obj, box)
    anchor = block_anchors(rgb, depth, hidden, K_BLOCK, dilate(obj, UNDER_OBJECT_PIXELS))
    anchor = anchor.flatten(2).transpose(1, 2)

    def blocks(m: torch.Tensor) -> torch.Tensor:
        return (F.avg_pool2d(m, K_BLOCK) > 0.5).flatten()

    return anchor, blocks(hidden), blocks(obj)


def _raw(hidden: torch.Tensor) -> torch.Tensor:
    """Head outputs (1, N, C) as a trained model gives them: seen blocks opaque, hidden ones nearly transparent."""
    channels = gaussian_channels(0)
    index = split_gaussian_params(torch.arange(channels, dtype=torch.float64), 0)  # each part's channel numbers
    raw = torch.zeros(1, hidden.shape[0], channels, dtype=torch.float64)
    raw[..., int(index["quat"][0])] = 1.0  # identity quaternion (anchored shapes ignore it)
    raw[0, :, int(index["opacity"][0])] = torch.where(hidden, -3.0, 4.0).double()
    return raw


def _scale_channels() -> list[int]:
    return [int(i) for i in split_gaussian_params(torch.arange(gaussian_channels(0)), 0)["scale"]]


def _gaussians(fields: dict[str, torch.Tensor]) -> Gaussians:
    n = fields["means"].shape[1]
    return Gaussians(
        fields["means"][0],
        fields["quats"][0],
        fields["scales"][0],
        fields["opacities"][0],
        fields["sh"][0],
        torch.full((n,), -1, dtype=torch.int64),
    )


def test_the_anchors_carry_each_block_s_share_of_pixels_under_an_object():
    gen = torch.Generator().manual_seed(3)
    under = (torch.rand(2, 1, 8, 8, generator=gen) > 0.6).double()
    anchor = block_anchors(torch.rand(2, 3, 8, 8, generator=gen).double(), None, torch.zeros_like(under), 2, under)
    share = under.reshape(2, 1, 4, 2, 4, 2).mean(dim=(3, 5))  # each 2 x 2 block's mean, by reshape
    torch.testing.assert_close(anchor[:, 5:6], share)
    none = block_anchors(torch.rand(2, 3, 8, 8).double(), None, torch.zeros_like(under), 2)  # no object: share 0
    assert torch.equal(none[:, 5], torch.zeros_like(share[:, 0]))


def test_blocks_under_an_object_draw_the_table_opaque_and_the_rest_stay():
    K, c2w = _camera()
    anchor, hidden, obj = _scene()
    raw = _raw(hidden)
    off = background_gaussians(raw, K, c2w, _config(), anchor)
    keyed = _config(bg_opaque_under_objects=True)
    moved = torch.zeros(1, hidden.shape[0], dtype=torch.float64)  # no particle's box covers a block any longer
    on = background_gaussians(raw, K, c2w, keyed, anchor, moved)
    # while the boxes cover their blocks (nothing moved), or with no boxes given (training), nothing changes
    for covered in (torch.ones_like(moved), None):
        same = background_gaussians(raw, K, c2w, keyed, anchor, covered)
        for key in ("means", "quats", "scales", "opacities", "sh"):
            assert torch.equal(same[key], off[key]), key
    assert int(obj.sum()) == 16 and int((hidden & ~obj).sum()) == 12
    # the object's blocks: opaque, in the table's colour, lying flat on the table (means on it, the thinnest axis
    # along z) and at least half the step to the next block wide there
    assert torch.equal(on["opacities"][0, obj], torch.full((16,), UNDER_OBJECT_OPACITY, dtype=torch.float64))
    rgb = on["sh"][0, obj, 0] * SH_C0 + 0.5
    torch.testing.assert_close(rgb, TABLE.expand(16, 3))
    assert float(on["means"][0, obj, 2].abs().max()) < 1e-9
    axes = quaternion_to_rotation_matrix(on["quats"][0, obj])  # (16, 3, 3), columns the axes
    scales = on["scales"][0, obj]
    normal = axes[torch.arange(16), :, scales.argmin(-1)]
    assert float(normal[:, 2].abs().min()) > 0.999
    step = (on["means"][0, obj][:, None] - on["means"][0, obj][None]).norm(dim=-1)
    nearest = torch.where(step > 0, step, torch.full_like(step, float("inf"))).min(dim=1).values
    assert bool((scales.sort(dim=-1).values[:, 1] >= UNDER_OBJECT_WIDTH * nearest * 0.95).all())
    # every other block, the box's hidden ones included, is drawn as without the key; those next to the object's
    # blocks span the step to them on the table instead of the other way
    rest = ~obj
    for key in ("means", "opacities", "sh"):
        assert torch.equal(on[key][0, rest], off[key][0, rest]), key
    n = RES // K_BLOCK
    far = F.max_pool2d(obj.reshape(1, 1, n, n).double(), 3, stride=1, padding=1).flatten() == 0
    for key in ("quats", "scales"):
        assert torch.equal(on[key][0, far], off[key][0, far]), key
    assert bool((on["opacities"][0, hidden & ~obj] < 0.1).all())
    # anchors of five channels (particles encoded before the share was kept): nothing is under an object
    five = background_gaussians(raw, K, c2w, keyed, anchor[..., :5], moved)
    for key in ("means", "opacities", "sh"):
        assert torch.equal(five[key], off[key]), key


def test_where_the_object_stood_a_view_from_above_sees_the_table():
    """The object moved away (its particles gone): a camera straight above the hidden square sees the table's
    colour there with the key (alpha > 0.95), and mostly what is behind without it."""
    K, c2w = _camera()
    anchor, hidden, obj = _scene()
    raw = _raw(hidden)
    # the object square's centre on the plane: the pixel (16, 16) ray from the context camera
    d = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64) @ c2w[0, :3, :3].T
    centre = c2w[0, :3, 3] - c2w[0, 2, 3] / d[2] * d
    x, y = float(centre[0]), float(centre[1])
    above = Camera.look_at((x, y, 0.6), (x, y, 0.0), up=(0.0, 1.0, 0.0), fov_y_deg=10.0, width=16, height=16)
    black = torch.zeros(3, dtype=torch.float32)
    images = {}
    for key in (False, True):
        moved = torch.zeros(1, hidden.shape[0], dtype=torch.float64)  # the object's particles left
        fields = background_gaussians(raw, K, c2w, _config(bg_opaque_under_objects=key), anchor, moved)
        g = _gaussians({k: v.float() for k, v in fields.items()})
        images[key] = render(g, above, background=black)
    window = (slice(6, 10), slice(6, 10))  # the centre of the view: the middle of where the object stood
    on, off = images[True], images[False]
    assert float(on.alpha[window].min()) > 0.95
    torch.testing.assert_close(on.rgb[window], TABLE.float().expand(4, 4, 3), atol=0.05, rtol=0)
    assert float(off.alpha[window].mean()) < 0.5


def test_a_least_width_widens_the_in_surface_axes_only():
    K, c2w = _camera()
    anchor, hidden, _ = _scene()
    raw = _raw(hidden)
    raw[..., _scale_channels()] = -40.0  # every scale factor at its lower bound
    narrow = background_gaussians(raw, K, c2w, _config(), anchor)["scales"][0].sort(dim=-1).values
    wide = background_gaussians(raw, K, c2w, _config(bg_min_width=0.4), anchor)["scales"][0].sort(dim=-1).values
    torch.testing.assert_close(wide[:, 1:], narrow[:, 1:] * 2.0)  # 0.4 of the step instead of s_min = 0.2
    torch.testing.assert_close(wide[:, 0], narrow[:, 0])  # the thickness


@pytest.mark.parametrize(
    ("changes", "key"),
    [
        ({"bg_min_width": 0.1}, "min_width"),
        ({"bg_min_width": 0.8}, "min_width"),
        ({"bg_opaque_under_objects": True, "bg_hidden_from_views": False}, "opaque_under_objects"),
        ({"bg_min_width": 0.4, "fg_evidence": False}, "min_width"),
    ],
)
def test_the_keys_are_checked_and_named(changes, key):
    with pytest.raises(ConfigError, match=f"background.{key}"):
        replace(_config(), **changes).validate()


def _object_scene(size: int = 32):
    """Two views 45° above the table z = 0 (every pixel's depth where its ray meets it) with a 0.1 m tall block
    standing on it: the pixels of a square see its top (their depth where their ray meets z = 0.1), the object's
    evidence. Returns rgb (2, 3, H, W), depth (2, 1, H, W), cameras."""
    cams = [Camera.orbit((0.0, 0.0, 0.0), az, 45.0, 1.2, width=size, height=size) for az in (-20, 25)]
    rgb = torch.empty(2, 3, size, size)
    depth = torch.empty(2, 1, size, size)
    for v, cam in enumerate(cams):
        c = cam.to(dtype=torch.float64)
        origins, dirs = c.rays()  # (H, W, 3), camera z = 1
        t = -origins[..., 2] / dirs[..., 2]
        top = (0.1 - origins[..., 2]) / dirs[..., 2]
        hit = origins + top[..., None] * dirs
        block = (hit[..., :2].abs() < 0.06).all(-1)
        depth[v, 0] = torch.where(block, top, t).float()
        rgb[v] = torch.where(block[None], torch.tensor([0.1, 0.2, 0.9])[:, None, None], TABLE.float()[:, None, None])
        assert 8 < int(block.sum()) < size * size // 4
    return rgb, depth, cams


def _evidence_model(**kw):
    from test_model import tiny_model

    return tiny_model(
        resolution=32,
        bg_per_view=True,
        bg_static_grid=0,
        bg_block=1,
        bg_latent_stride=1,
        fg_evidence=True,
        bg_hidden_from_views=True,
        bg_mask_threshold=0.0,  # every particle is active: its box hides part of the view
        **kw,
    )


def test_an_unedited_scene_draws_alike_and_a_removed_object_uncovers_the_table():
    """The key changes nothing while every particle is where it was encoded; once the particles are gone (an
    edit removed them), the blocks under the object draw the table, opaque; the editor's kept Gaussians follow."""
    from particlesplat.editing.decoded import DecodedParticles

    rgb, depth, cams = _object_scene()
    plain, keyed = _evidence_model(), _evidence_model(bg_opaque_under_objects=True)
    particles = keyed.encode(rgb, depth, cams)
    assert torch.equal(particles.background, plain.encode(rgb, depth, cams).background)
    under = particles.background[:, -1].flatten(1) > 0.5  # (V, N) blocks under the object, in a box
    assert int(under.sum()) > 0
    a, b = keyed.decode(particles), plain.decode(particles)
    for key in ("means", "scales", "opacities", "sh"):
        assert torch.equal(getattr(a, key), getattr(b, key)), key
    gone = particles.with_attribute(0, "z_t", torch.zeros(1))
    for i in range(1, particles.num):
        gone = gone.with_attribute(i, "z_t", torch.zeros(1))
    before, after = plain.decode(gone), keyed.decode(gone)
    bg_before, bg_after = before.opacities[before.owner < 0], after.opacities[after.owner < 0]
    changed = bg_before != bg_after
    assert torch.equal(changed, under.flatten())  # exactly the blocks under the object
    assert bool((bg_after[changed] == UNDER_OBJECT_OPACITY).all())
    kept = DecodedParticles(keyed)
    kept.gaussians(particles)
    again = kept.gaussians(gone)
    assert torch.equal(again.opacities[again.owner < 0], bg_after)


def test_the_editor_decodes_the_background_again_only_when_its_table_fill_changes():
    """A drag that keeps every block under the object inside a box leaves the background as it was decoded (no new
    decode, equal to a fresh one); a removal changes which blocks draw the table and decodes it again. A model
    without the key has no fill key."""
    from particlesplat.editing.decoded import DecodedParticles

    rgb, depth, cams = _object_scene()
    plain, keyed = _evidence_model(), _evidence_model(bg_opaque_under_objects=True)
    particles = keyed.encode(rgb, depth, cams)
    assert plain.table_fill_key(particles) is None
    key = keyed.table_fill_key(particles)
    assert key is not None and key.shape == (2, 32 * 32) and not bool(key.any())  # every under block is covered
    kept = DecodedParticles(keyed)

    def background(g: Gaussians) -> Gaussians:
        return g.subset(g.owner < 0)

    kept.gaussians(particles)
    nudged = particles
    for i in range(particles.num):  # every box 1e-4 of the image to the right: no block changes side
        nudged = nudged.with_attribute(i, "z_p", particles.z_p[i] + torch.tensor([1e-4, 0.0]))
    assert torch.equal(keyed.table_fill_key(nudged), key)
    g = kept.gaussians(nudged)
    assert kept.backgrounds_decoded == 1
    fresh = background(keyed.decode(nudged))
    assert torch.allclose(background(g).means, fresh.means) and torch.equal(background(g).opacities, fresh.opacities)
    gone = nudged
    for i in range(particles.num):
        gone = gone.with_attribute(i, "z_t", torch.zeros(1))
    assert bool(keyed.table_fill_key(gone).any())
    g = kept.gaussians(gone)
    assert kept.backgrounds_decoded == 2
    assert torch.equal(background(g).opacities, background(keyed.decode(gone)).opacities)


def test_a_drag_keeps_the_background_until_it_ends_then_draws_the_table():
    """While a drag is under way the editor keeps the background it decoded (a whole decode a step would slow every
    step of it); once the drag ends, the next decode equals a fresh one, with the table drawn where the object was."""
    from particlesplat.editing.editor import SceneEditor

    rgb, depth, cams = _object_scene()
    keyed = _evidence_model(bg_opaque_under_objects=True)
    particles = keyed.encode(rgb, depth, cams)
    editor = SceneEditor(keyed, particles)
    before = editor.decode()
    before_bg = before.opacities[before.owner < 0]
    for i in range(particles.num):  # a drag of each particle's z_t slider to 0, one gesture id throughout
        editor.set_attribute(i, "z_t", [0.0], gesture="drag")
        during = editor.decode()
        assert torch.equal(during.opacities[during.owner < 0], before_bg)
    fresh = keyed.decode(editor.scene.particles)
    fresh_bg = fresh.opacities[fresh.owner < 0]
    assert not torch.equal(fresh_bg, before_bg)  # the table under the object now draws
    editor.end_gesture()
    after = editor.decode()
    assert torch.equal(after.opacities[after.owner < 0], fresh_bg)
    assert torch.equal(after.means[after.owner < 0], fresh.means[fresh.owner < 0])


def test_the_editor_reports_the_background_when_the_table_it_draws_changes():
    """A viewer uploads only what take_changes reports: an edit that uncovers the table reports the background
    (owner -1), and the background then handed out is a fresh decode's; during a drag nothing is reported until the
    drag ends, which counts as a change (the version moves) and reports it."""
    from particlesplat.core.gaussians import BACKGROUND_OWNER
    from particlesplat.editing.editor import SceneEditor

    rgb, depth, cams = _object_scene()
    keyed = _evidence_model(bg_opaque_under_objects=True)
    particles = keyed.encode(rgb, depth, cams)
    fresh = keyed.decode(particles.with_attribute(0, "z_t", torch.zeros(1)))
    for gesture in (None, "drag"):
        editor = SceneEditor(keyed, particles)
        assert editor.take_changes() is None  # the first upload: everything
        reported = set()
        for i in range(particles.num):
            editor.set_attribute(i, "z_t", [0.0], gesture=gesture)
            reported |= editor.take_changes() or set()
        assert (BACKGROUND_OWNER in reported) == (gesture is None)
        if gesture is not None:
            version = editor.version
            editor.end_gesture()
            assert editor.version > version and BACKGROUND_OWNER in editor.take_changes()
        assert editor.take_changes() == set()  # reported once
        fresh = keyed.decode(editor.scene.particles)
        background = editor.background()
        assert torch.equal(background.opacities, fresh.opacities[fresh.owner < 0])
        assert bool((background.owner == BACKGROUND_OWNER).all())


def test_the_table_is_filled_from_the_support_map_and_only_on_the_support():
    """With a support map, the table drawn where an object stood takes the map's colour where each block's ray
    meets the plane; where the map says the plane there is no support (the floor past the table's edge), no block
    is filled. Maps built by hand: one colour and support everywhere, then no support anywhere."""
    from dataclasses import replace as replace_fields

    from particlesplat.model.support_map import CELLS

    rgb, depth, cams = _object_scene()
    model = _evidence_model(bg_opaque_under_objects=True, bg_support_map=True)
    particles = model.encode(rgb, depth, cams)
    gone = particles
    for i in range(particles.num):
        gone = gone.with_attribute(i, "z_t", torch.zeros(1))
    under = particles.background[:, -1].flatten(1) > 0.5
    paint = torch.tensor([0.3, 0.6, 0.2])
    table = torch.cat([paint[:, None, None].expand(3, CELLS, CELLS), torch.ones(1, CELLS, CELLS)])
    g = model.decode(replace_fields(gone, support_map=table))
    bg = g.owner < 0
    filled = g.opacities[bg] == UNDER_OBJECT_OPACITY
    assert torch.equal(filled, under.flatten())
    colours = g.sh[bg][filled, 0] * SH_C0 + 0.5
    torch.testing.assert_close(colours, paint.expand_as(colours), atol=1e-5, rtol=0)
    floor = torch.cat([paint[:, None, None].expand(3, CELLS, CELLS), torch.zeros(1, CELLS, CELLS)])
    g = model.decode(replace_fields(gone, support_map=floor))
    assert not bool((g.opacities[g.owner < 0] == UNDER_OBJECT_OPACITY).any())


def test_with_the_key_the_support_map_leaves_out_the_object_and_its_foot():
    """The object's top is painted red and the table pixels next to it (its foot) green: the map of a model with
    the key holds no green, the same map without the key does."""
    from particlesplat.model.evidence import foreground_evidence
    from particlesplat.model.geometry import stack_cameras
    from particlesplat.model.support_map import views_support_map

    rgb, depth, cams = _object_scene()
    K, c2w = stack_cameras(cams)
    evidence = foreground_evidence(depth, K, c2w)
    foot = (dilate(evidence, 1) > 0.5) & (evidence < 0.5)  # table pixels right next to the object
    assert int(foot.sum()) > 0
    rgb = torch.where(foot, torch.tensor([0.0, 1.0, 0.0])[None, :, None, None], rgb)
    keyed = _evidence_model(bg_opaque_under_objects=True, bg_support_map=True)
    plain = _evidence_model(bg_support_map=True)
    for model, green in ((keyed, False), (plain, True)):
        m = model.views_support_map(rgb, depth, K, c2w)
        assert m is not None
        assert bool((m[1] - m[0] > 0.5).any()) == green  # a cell far greener than the table (0.9, 0.8, 0.7)
    assert views_support_map(rgb, depth, K, c2w, torch.ones_like(depth)) is None  # nothing left: no map
