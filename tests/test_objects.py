"""Grouping particles into objects: analytic geometry cases and a brute-force segmentation."""

from __future__ import annotations

import pytest
import torch

from particlesplat.core.gaussians import Gaussians
from particlesplat.editing.grouping import particle_objects
from particlesplat.rendering.api import object_segmentation


def gaussians(means, scale, owner, opacity=0.9) -> Gaussians:
    """Isotropic Gaussians of std ``scale`` (metres) at ``means`` (N, 3) with ``owner`` (N,)."""
    m = torch.as_tensor(means, dtype=torch.float32).reshape(-1, 3)
    n = m.shape[0]
    op = torch.as_tensor(opacity, dtype=torch.float32).expand(n).clone()
    return Gaussians(
        m,
        torch.tensor([[1.0, 0, 0, 0]]).expand(n, 4).clone(),
        torch.full((n, 3), float(scale)),
        op,
        torch.zeros(n, 1, 3),
        torch.as_tensor(owner, dtype=torch.int64).reshape(n),
    )


def sphere_points(centre, radius, n, seed, hemisphere):
    """n points on one hemisphere (+1: facing +x, -1: facing -x) of a sphere."""
    g = torch.Generator().manual_seed(seed)
    d = torch.randn(n, 3, generator=g, dtype=torch.float64)
    d = d / d.norm(dim=1, keepdim=True)
    d[:, 0] = d[:, 0].abs() * hemisphere
    return torch.as_tensor(centre, dtype=torch.float64) + radius * d


def test_two_views_of_one_sphere_are_one_object_and_a_neighbour_is_not():
    """Particles 0 and 2 see two overlapping halves (the +x and -x hemispheres, each with a band across the
    top) of one sphere; particle 1 is a sphere 0.1 m (surface to surface) away."""
    a = sphere_points([0, 0, 0.2], 0.2, 200, 0, +1)
    b = sphere_points([0, 0, 0.2], 0.2, 200, 1, -1)
    a = torch.cat([a, sphere_points([0, 0, 0.2], 0.2, 60, 2, -1)])  # the band seen from both views
    c = sphere_points([0.5, 0, 0.2], 0.2, 200, 3, -1)
    g = gaussians(torch.cat([a, c, b]), 0.02, [0] * 260 + [1] * 200 + [2] * 200)
    assert particle_objects(g, 3).tolist() == [0, 1, 0]
    assert particle_objects(g, 3, reach=0.0).tolist() == [0, 1, 2]


@pytest.mark.parametrize("distance, grouped", [(0.079, True), (0.081, False)])
def test_touching_is_within_reach_times_the_sum_of_the_largest_stds(distance, grouped):
    """Single Gaussians with largest stds 0.02 and 0.03 (one axis stretched): touching below 0.05 x reach."""
    g = gaussians([[0, 0, 0], [distance, 0, 0]], 0.01, [0, 1])
    g.scales[0, 2] = 0.02
    g.scales[1, 1] = 0.03
    labels = particle_objects(g, 2, reach=1.6)  # 1.6 x 0.05 = 0.08 m
    assert labels.tolist() == ([0, 0] if grouped else [0, 1])


def test_transparent_and_background_gaussians_do_not_join_objects():
    """A faint Gaussian (opacity below ``opaque``) and a background Gaussian between two particles
    bridge nothing; an inactive particle (no opaque Gaussian) stays its own object."""
    g = gaussians(
        [[0, 0, 0], [0.05, 0, 0], [0.1, 0, 0], [0.05, 0.01, 0], [3, 3, 3]],
        0.03,
        [0, 2, 1, -1, 3],
        opacity=[0.9, 0.1, 0.9, 0.9, 0.05],
    )
    assert particle_objects(g, 4).tolist() == [0, 1, 2, 3]
    g.opacities[1] = 0.5  # now particle 2 is opaque and touches both: one chain 0-2-1
    assert particle_objects(g, 4).tolist() == [0, 0, 0, 3]


def test_chains_are_transitive_and_labels_are_the_smallest_index():
    g = gaussians([[0, 0, 0], [0.06, 0, 0], [0.12, 0, 0], [0.18, 0, 0], [2, 0, 0]], 0.035, [3, 1, 4, 2, 0])
    assert particle_objects(g, 5).tolist() == [0, 1, 1, 1, 1]
    assert particle_objects(gaussians(torch.zeros(0, 3), 0.02, []), 3).tolist() == [0, 1, 2]
    with pytest.raises(ValueError):
        particle_objects(g, 5, reach=-1.0)


def test_objects_a_few_centimetres_apart_stay_apart():
    """Two spheres (radius 0.2 m) 4 cm apart surface to surface, each held by two particles (two views:
    each particle a hemisphere plus a wide band of the other one), Gaussians of std 0.03 m: their rims touch,
    so touching alone (overlap 0) makes one object of all four; with the overlap share each sphere is one
    object of its own two particles."""
    parts = []
    for k, centre in enumerate(([0, 0, 0.2], [0.44, 0, 0.2])):
        for h in (+1, -1):
            parts.append(
                torch.cat(
                    [
                        sphere_points(centre, 0.2, 150, 10 * k + 2 * (h > 0), h),
                        sphere_points(centre, 0.2, 100, 10 * k + 1 + 2 * (h > 0), -h),
                    ]
                )
            )
    g = gaussians(torch.cat(parts), 0.03, [0] * 250 + [1] * 250 + [2] * 250 + [3] * 250)
    assert particle_objects(g, 4).tolist() == [0, 0, 2, 2]
    assert particle_objects(g, 4, overlap=0.0).tolist() == [0, 0, 0, 0]


@pytest.mark.parametrize("shared, grouped", [(2, False), (3, True)])
@pytest.mark.parametrize("swap", [False, True])
def test_overlap_is_the_share_of_either_particles_gaussians(shared, grouped, swap):
    """Particle A: 10 Gaussians 0.1 m apart on a line; particle B: 20 Gaussians, ``shared`` of them next to the
    first ``shared`` of A, the rest far away. A's share touching B is shared / 10, B's shared / 20: with overlap
    0.3 they are one object from 3 shared Gaussians on, whichever of the two is the smaller particle."""
    a = [[0.1 * i, 0, 0] for i in range(10)]
    b = [[0.1 * i, 0.005, 0] for i in range(shared)] + [[5 + 0.1 * i, 0, 0] for i in range(20 - shared)]
    owners = [1] * 10 + [0] * 20 if swap else [0] * 10 + [1] * 20
    g = gaussians(a + b, 0.01, owners)
    assert particle_objects(g, 2, overlap=0.3).tolist() == ([0, 0] if grouped else [0, 1])
    assert particle_objects(g, 2, overlap=0.0).tolist() == [0, 0]  # one touching pair is enough at 0
    assert particle_objects(g, 2, overlap=1.0).tolist() == [0, 1]
    with pytest.raises(ValueError):
        particle_objects(g, 2, overlap=1.5)


def test_touching_counts_match_a_brute_force_loop(monkeypatch):
    """The chunked count against a float64 double loop over Gaussian pairs (chunk smaller than the set)."""
    import particlesplat.editing.grouping as objects_module

    gen = torch.Generator().manual_seed(3)
    M, P = 300, 5
    means = torch.rand(M, 3, generator=gen, dtype=torch.float64)
    radius = torch.rand(M, generator=gen, dtype=torch.float64) * 0.08
    owner = torch.randint(0, P, (M,), generator=gen)
    monkeypatch.setattr(objects_module, "CHUNK", 64)
    counts = objects_module.touching_counts(means, radius, owner, P)
    want = torch.zeros(P, P, dtype=torch.int64)
    for i in range(M):
        touched = set()
        for j in range(M):
            if owner[j] != owner[i] and (means[i] - means[j]).norm() < radius[i] + radius[j]:
                touched.add(int(owner[j]))
        for b in touched:
            want[owner[i], b] += 1
    assert torch.equal(counts, want)


def test_object_segmentation_matches_brute_force():
    """Against a per-pixel float64 loop: sum each object's particle weights, argmax with the background first."""
    gen = torch.Generator().manual_seed(0)
    P, H, W = 6, 9, 7
    w = torch.rand(P, H, W, generator=gen, dtype=torch.float64) * 0.3
    bg = torch.rand(H, W, generator=gen, dtype=torch.float64) * 0.6
    objects = torch.tensor([0, 1, 0, 3, 1, 5])
    seg = object_segmentation(w, bg, objects)
    for y in range(H):
        for x in range(W):
            best, label = bg[y, x].item(), -1
            for obj in sorted(set(objects.tolist())):
                s = sum(w[p, y, x].item() for p in range(P) if objects[p] == obj)
                if s > best:
                    best, label = s, obj
            assert seg[y, x].item() == label
    # one object drawn by two particles at 0.3 each beats a background of 0.4; each particle alone does not
    w2 = torch.tensor([[[0.3]], [[0.3]]])
    bg2 = torch.tensor([[0.4]])
    assert object_segmentation(w2, bg2, torch.tensor([0, 0])).item() == 0
    assert object_segmentation(w2, bg2, torch.tensor([0, 1])).item() == -1
    with pytest.raises(ValueError):
        object_segmentation(w2, bg2, torch.tensor([0]))


def test_render_segmentation_by_objects():
    """render(...).segmentation(objects) over two particles of one object gives that object's label."""
    from particlesplat.core.camera import Camera
    from particlesplat.rendering.api import render

    f = 30.0
    K = torch.tensor([[f, 0, 10.5], [0, f, 7.5], [0, 0, 1.0]])
    cam = Camera(K, torch.eye(4), 21, 15)
    g = gaussians([[-0.05, 0, 2.0], [0.05, 0, 2.0], [0.6, 0, 2.0]], 0.06, [0, 1, 2])
    res = render(g, cam, owner_weights=True, num_owners=3)
    labels = particle_objects(g, 3)
    assert labels.tolist() == [0, 0, 2]
    seg = res.segmentation(labels)
    assert set(seg.unique().tolist()) == {-1, 0, 2}
    per_particle = res.segmentation()
    # a pixel either particle wins alone, the object wins too (its summed weight is at least as large)
    assert bool((seg[(per_particle == 0) | (per_particle == 1)] == 0).all())
    assert int((seg == 0).sum()) > int((per_particle == 0).sum())
