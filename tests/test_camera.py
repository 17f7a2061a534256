"""Camera geometry against kornia's PinholeCamera, hand-computed numbers and round trips."""

from __future__ import annotations

import math

import pytest
import torch
from kornia.geometry.camera import PinholeCamera

from particlesplat import Camera

DT = torch.float64


def _random_rotation(gen: torch.Generator) -> torch.Tensor:
    """(3, 3) proper rotation from a QR decomposition of a random matrix."""
    q, r = torch.linalg.qr(torch.randn(3, 3, generator=gen, dtype=DT))
    q = q * torch.sign(torch.diagonal(r))
    if torch.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def _random_camera(seed: int, width: int = 37, height: int = 23) -> Camera:
    gen = torch.Generator().manual_seed(seed)
    c2w = torch.eye(4, dtype=DT)
    c2w[:3, :3] = _random_rotation(gen)
    c2w[:3, 3] = torch.randn(3, generator=gen, dtype=DT) * 2.0
    fx, fy = 30.0 + 10 * torch.rand(1, generator=gen).item(), 25.0 + 10 * torch.rand(1, generator=gen).item()
    K = torch.tensor([[fx, 0.0, 17.3], [0.0, fy, 12.1], [0.0, 0.0, 1.0]], dtype=DT)
    return Camera(K, c2w, width, height)


def _points_in_front(cam: Camera, n: int, seed: int) -> torch.Tensor:
    """(n, 3) world points at camera depth 0.5..5 that project inside the image."""
    gen = torch.Generator().manual_seed(seed)
    u = torch.rand(n, generator=gen, dtype=DT) * cam.width
    v = torch.rand(n, generator=gen, dtype=DT) * cam.height
    z = 0.5 + 4.5 * torch.rand(n, generator=gen, dtype=DT)
    K = cam.K
    p_cam = torch.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], dim=-1)
    return p_cam @ cam.c2w[:3, :3].T + cam.c2w[:3, 3]


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_project_matches_kornia_with_half_pixel_shift(seed: int) -> None:
    cam = _random_camera(seed)
    pts = _points_in_front(cam, 50, seed + 10)
    uv, z = cam.project(pts)
    # kornia puts pixel centres on integers: its principal point is ours minus half a pixel.
    Kk = cam.K.clone()
    Kk[0, 2] -= 0.5
    Kk[1, 2] -= 0.5
    intr = torch.eye(4, dtype=DT)
    intr[:3, :3] = Kk
    w2c = torch.linalg.inv(cam.c2w)
    pin = PinholeCamera(intr[None], w2c[None], torch.tensor([cam.height]), torch.tensor([cam.width]))
    uv_k = pin.project(pts[None])[0]
    torch.testing.assert_close(uv, uv_k + 0.5, atol=1e-9, rtol=0)
    p_cam = pts @ w2c[:3, :3].T + w2c[:3, 3]
    torch.testing.assert_close(z, p_cam[:, 2], atol=1e-12, rtol=0)
    torch.testing.assert_close(cam.world_to_camera(pts), p_cam, atol=1e-12, rtol=0)
    # and kornia's unprojection of our pixels lands on the same world points
    back_k = pin.unproject(uv[None] - 0.5, z[None, :, None])[0]
    torch.testing.assert_close(back_k, pts, atol=1e-9, rtol=0)


def test_project_hand_computed() -> None:
    K = torch.tensor([[100.0, 0.0, 32.0], [0.0, 80.0, 24.0], [0.0, 0.0, 1.0]], dtype=DT)
    c2w = torch.eye(4, dtype=DT)
    c2w[:3, 3] = torch.tensor([1.0, 2.0, -3.0], dtype=DT)  # camera at (1, 2, -3), axes = world axes
    cam = Camera(K, c2w, 64, 48)
    uv, z = cam.project(torch.tensor([[1.5, 1.0, 1.0]], dtype=DT))  # camera coords (0.5, -1, 4)
    torch.testing.assert_close(uv, torch.tensor([[100 * 0.5 / 4 + 32, 80 * -1 / 4 + 24]], dtype=DT))
    torch.testing.assert_close(z, torch.tensor([4.0], dtype=DT))


@pytest.mark.parametrize("seed", [0, 3])
def test_project_unproject_round_trip(seed: int) -> None:
    cam = _random_camera(seed)
    pts = _points_in_front(cam, 40, seed)
    uv, z = cam.project(pts)
    torch.testing.assert_close(cam.unproject(uv, z), pts, atol=1e-10, rtol=0)
    gen = torch.Generator().manual_seed(seed)
    uv2 = torch.rand(40, 2, generator=gen, dtype=DT) * torch.tensor([cam.width, cam.height], dtype=DT)
    d2 = 0.1 + torch.rand(40, generator=gen, dtype=DT) * 10
    uv3, z3 = cam.project(cam.unproject(uv2, d2))
    torch.testing.assert_close(uv3, uv2, atol=1e-9, rtol=0)
    torch.testing.assert_close(z3, d2, atol=1e-10, rtol=0)


def test_rays_pass_through_pixel_centres() -> None:
    cam = _random_camera(5, width=37, height=23)
    origins, dirs = cam.rays()
    assert origins.shape == (23, 37, 3) and dirs.shape == (23, 37, 3)
    torch.testing.assert_close(origins, cam.c2w[:3, 3].expand(23, 37, 3))
    for t in (0.3, 2.0, 7.5):
        uv, z = cam.project(origins + t * dirs)
        v, u = torch.meshgrid(torch.arange(23, dtype=DT), torch.arange(37, dtype=DT), indexing="ij")
        torch.testing.assert_close(uv, torch.stack([u + 0.5, v + 0.5], -1), atol=1e-9, rtol=0)
        # unnormalised directions have camera z = 1, so the planar depth is t
        torch.testing.assert_close(z, torch.full_like(z, t), atol=1e-10, rtol=0)
    # explicit uv argument
    uv_in = torch.tensor([[3.25, 7.75], [0.0, 0.0]], dtype=DT)
    o, d = cam.rays(uv_in)
    torch.testing.assert_close(cam.project(o + 1.7 * d)[0], uv_in, atol=1e-9, rtol=0)


def test_rays_hand_computed() -> None:
    K = torch.tensor([[2.0, 0.0, 2.0], [0.0, 2.0, 1.0], [0.0, 0.0, 1.0]], dtype=DT)
    cam = Camera(K, torch.eye(4, dtype=DT), 4, 2)
    _, dirs = cam.rays()
    # pixel (u=0, v=0) centre (0.5, 0.5): ((0.5-2)/2, (0.5-1)/2, 1)
    torch.testing.assert_close(dirs[0, 0], torch.tensor([-0.75, -0.25, 1.0], dtype=DT))
    torch.testing.assert_close(dirs[1, 3], torch.tensor([0.75, 0.25, 1.0], dtype=DT))


def test_plucker() -> None:
    """The Plücker ray map (particlesplat.model.geometry.plucker_map) against the camera's own rays."""
    from particlesplat.model.geometry import plucker_map

    cam = _random_camera(7, width=9, height=6)
    pl = plucker_map(cam.K[None], cam.c2w[None], 6, 9)[0].permute(1, 2, 0)
    assert pl.shape == (6, 9, 6)
    d, m = pl[..., :3], pl[..., 3:]
    torch.testing.assert_close(d.norm(dim=-1), torch.ones(6, 9, dtype=DT), atol=1e-12, rtol=0)
    torch.testing.assert_close((d * m).sum(-1), torch.zeros(6, 9, dtype=DT), atol=1e-12, rtol=0)
    origins, dirs = cam.rays()
    # the same line described from two other points on it gives the same coordinates
    p1, p2 = origins + 1.5 * dirs, origins + 4.0 * dirs
    d2 = (p2 - p1) / (p2 - p1).norm(dim=-1, keepdim=True)
    torch.testing.assert_close(d2, d, atol=1e-12, rtol=0)
    torch.testing.assert_close(torch.linalg.cross(p2, d2, dim=-1), m, atol=1e-10, rtol=0)
    # the moment's norm is the line's distance from the world origin
    t = -(origins * d).sum(-1, keepdim=True)
    closest = origins + t * d
    torch.testing.assert_close(m.norm(dim=-1), closest.norm(dim=-1), atol=1e-10, rtol=0)


@pytest.mark.parametrize(
    "eye,target",
    [((3.0, -4.0, 2.0), (0.5, 0.2, 0.1)), ((0.0, -2.0, 0.0), (0.0, 0.0, 0.0)), ((-1.0, 5.0, -2.0), (0.0, 0.0, 0.3))],
)
def test_look_at_target_centred_no_roll(eye, target) -> None:
    cam = Camera.look_at(eye, target, fov_y_deg=50.0, width=40, height=30, dtype=DT)
    uv, z = cam.project(torch.tensor([target], dtype=DT))
    torch.testing.assert_close(uv, torch.tensor([[20.0, 15.0]], dtype=DT), atol=1e-9, rtol=0)
    dist = math.dist(eye, target)
    assert abs(float(z[0]) - dist) < 1e-9
    torch.testing.assert_close(cam.center, torch.tensor(eye, dtype=DT))
    R = cam.R
    torch.testing.assert_close(R.T @ R, torch.eye(3, dtype=DT), atol=1e-12, rtol=0)
    assert abs(float(torch.det(R)) - 1.0) < 1e-12
    # no roll: camera x axis is horizontal; world up projects upward (smaller v), straight above
    assert abs(float(R[2, 0])) < 1e-12
    up_pt = torch.tensor([target], dtype=DT) + torch.tensor([[0.0, 0.0, 0.1]], dtype=DT)
    uv_up, _ = cam.project(up_pt)
    assert float(uv_up[0, 1]) < 15.0 - 1e-3
    assert abs(float(uv_up[0, 0]) - 20.0) < 1e-9
    # vertical field of view: a point at the top edge of the view is at tan(fov/2) * z
    assert abs(cam.fov_y - 50.0) < 1e-9


def test_look_at_rejects_coincident_eye_and_target() -> None:
    with pytest.raises(ValueError):
        Camera.look_at((1.0, 1.0, 1.0), (1.0, 1.0, 1.0))


def test_orbit_conventions() -> None:
    target = (0.2, -0.1, 0.3)
    cam0 = Camera.orbit(target, 0.0, 0.0, 2.0, width=32, height=32, dtype=DT)
    # azimuth 0: camera on the -y side looking along +y, world x to the right
    torch.testing.assert_close(cam0.center, torch.tensor([0.2, -2.1, 0.3], dtype=DT), atol=1e-12, rtol=0)
    torch.testing.assert_close(cam0.R[:, 2], torch.tensor([0.0, 1.0, 0.0], dtype=DT), atol=1e-12, rtol=0)
    uv_x, _ = cam0.project(torch.tensor([[0.3, -0.1, 0.3]], dtype=DT))
    assert float(uv_x[0, 0]) > 16.0 + 1e-3
    # positive azimuth turns counter-clockwise seen from above: 90 deg puts the camera on +x
    cam90 = Camera.orbit(target, 90.0, 0.0, 2.0, width=32, height=32, dtype=DT)
    torch.testing.assert_close(cam90.center, torch.tensor([2.2, -0.1, 0.3], dtype=DT), atol=1e-12, rtol=0)
    # elevation 30 deg: above the target, distance kept, target centred, up still upward
    cam = Camera.orbit(target, 37.0, 30.0, 3.0, width=32, height=24, dtype=DT)
    off = cam.center - torch.tensor(target, dtype=DT)
    assert abs(float(off.norm()) - 3.0) < 1e-12
    assert abs(float(off[2]) - 1.5) < 1e-12
    uv, _ = cam.project(torch.tensor([target], dtype=DT))
    torch.testing.assert_close(uv, torch.tensor([[16.0, 12.0]], dtype=DT), atol=1e-9, rtol=0)
    uv_up, _ = cam.project(torch.tensor([target], dtype=DT) + torch.tensor([[0.0, 0.0, 0.2]], dtype=DT))
    assert float(uv_up[0, 1]) < 12.0 - 1e-3 and abs(float(uv_up[0, 0]) - 16.0) < 1e-9


def test_opengl_round_trip_and_flip_rule() -> None:
    cam = _random_camera(11)
    gl = cam.to_opengl_c2w()
    back = Camera.from_opengl_c2w(gl, cam.K, cam.width, cam.height)
    torch.testing.assert_close(back.c2w, cam.c2w, atol=0, rtol=0)
    # dataset.md: c2w_opencv = c2w_opengl @ diag(1, -1, -1, 1)
    torch.testing.assert_close(cam.c2w, gl @ torch.diag(torch.tensor([1.0, -1.0, -1.0, 1.0], dtype=DT)))
    # hand case: an OpenGL camera at (0, 0, 5) with identity rotation looks down world -z, y up
    gl_c2w = torch.eye(4, dtype=DT)
    gl_c2w[2, 3] = 5.0
    K = torch.tensor([[50.0, 0.0, 32.0], [0.0, 50.0, 24.0], [0.0, 0.0, 1.0]], dtype=DT)
    c = Camera.from_opengl_c2w(gl_c2w, K, 64, 48)
    uv, z = c.project(torch.tensor([[0.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]], dtype=DT))
    torch.testing.assert_close(z, torch.tensor([5.0, 5.0, 5.0], dtype=DT))
    torch.testing.assert_close(uv, torch.tensor([[32.0, 24.0], [32.0, 24.0 - 10.0], [42.0, 24.0]], dtype=DT))


@pytest.mark.parametrize("size", [(74, 46), (19, 11), (37, 23), (111, 23)])
def test_resized_scales_pixel_coordinates(size) -> None:
    cam = _random_camera(13, width=37, height=23)
    new = cam.resized(*size)
    assert (new.width, new.height) == size
    pts = _points_in_front(cam, 30, 2)
    uv, z = cam.project(pts)
    uv2, z2 = new.project(pts)
    ratio = torch.tensor([size[0] / 37, size[1] / 23], dtype=DT)
    torch.testing.assert_close(uv2, uv * ratio, atol=1e-9, rtol=0)
    torch.testing.assert_close(z2, z, atol=0, rtol=0)
    # the image corners stay the image corners: ray through (0,0) and (W,H) is the same line
    _, d_old = cam.rays(torch.tensor([[0.0, 0.0], [37.0, 23.0]], dtype=DT))
    _, d_new = new.rays(torch.tensor([[0.0, 0.0], [float(size[0]), float(size[1])]], dtype=DT))
    torch.testing.assert_close(d_new, d_old, atol=1e-12, rtol=0)


def test_intrinsics_from_fov() -> None:
    K = Camera.intrinsics_from_fov(90.0, 64, 48, dtype=DT)
    torch.testing.assert_close(K, torch.tensor([[24.0, 0.0, 32.0], [0.0, 24.0, 24.0], [0.0, 0.0, 1.0]], dtype=DT))


def test_camera_validation_and_to() -> None:
    with pytest.raises(ValueError, match="K"):
        Camera(torch.eye(4), torch.eye(4), 4, 4)
    with pytest.raises(ValueError, match="c2w"):
        Camera(torch.eye(3), torch.eye(3), 4, 4)
    with pytest.raises(ValueError):
        Camera(torch.eye(3), torch.eye(4), 0, 4)
    cam = _random_camera(1).to(dtype=torch.float32)
    assert cam.K.dtype == torch.float32 and cam.c2w.dtype == torch.float32 and cam.dtype == torch.float32
    torch.testing.assert_close(cam.w2c.double(), torch.linalg.inv(_random_camera(1).c2w), atol=1e-5, rtol=0)


@pytest.mark.parametrize("up", [(0.0, 0.0, 1.0), (0.0, 1.0, 0.0), (1.0, 0.0, 0.0)])
@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_look_at_along_up_is_a_valid_camera(up, sign: float) -> None:
    """Looking straight along (or against) ``up``: any roll is fine, but a finite rotation."""
    target = tuple(sign * 3.0 * u for u in up)
    cam = Camera.look_at((0.0, 0.0, 0.0), target, up=up, width=16, height=16, dtype=DT)
    R = cam.R
    assert torch.isfinite(cam.c2w).all()
    torch.testing.assert_close(R.T @ R, torch.eye(3, dtype=DT), atol=1e-12, rtol=0)
    assert abs(float(torch.det(R)) - 1.0) < 1e-12
    uv, z = cam.project(torch.tensor([target], dtype=DT))
    torch.testing.assert_close(uv, torch.tensor([[8.0, 8.0]], dtype=DT), atol=1e-9, rtol=0)
