"""Row operations of :class:`Particles` (``cat``, ``take``, ``truncate``): every per-particle field moves row by
row, the background and the cameras stay those of the first operand."""

from __future__ import annotations

from dataclasses import fields, replace

import torch

from particlesplat.core.camera import Camera
from particlesplat.model.particles import Particles


def particles(n: int, seed: int, views: int = 2) -> Particles:
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.randn(*s, generator=g)  # noqa: E731
    return Particles(
        z_p=r(n, 2),
        z_s=r(n, 2),
        z_d=r(n, 1),
        z_e=r(n, 1),
        z_t=torch.rand(n, 1, generator=g),
        z_f=r(n, 3),
        view=torch.randint(views, (n,), generator=g),
        background=r(views, 2, 4, 4),
        cameras=[Camera.orbit((0, 0, 0), 30.0 * v, 20.0, 3.0, width=8, height=8) for v in range(views)],
    )


def rows(p: Particles) -> list[tuple]:
    """Each particle as a tuple of its per-particle fields' rows, in the dataclass's order (the support height as
    :meth:`Particles.support_heights` gives it, set or not)."""
    names = [f.name for f in fields(Particles) if f.name in Particles.row_fields()]
    values = {name: p.support_heights() if name == "support" else getattr(p, name) for name in names}
    return [tuple(values[name][i].tolist() for name in names) for i in range(p.num)]


def test_row_fields_are_every_field_with_one_row_per_particle():
    p = particles(5, 0)
    assert set(Particles.row_fields()) == {"z_p", "z_s", "z_d", "z_e", "z_t", "z_f", "view", "support"}
    assert p.support is None and p.support_heights().shape == (5, 1)  # unset: every one on the shared surface
    assert all(getattr(p, name).shape[0] == 5 for name in Particles.row_fields() if name != "support")


def test_support_heights_follow_the_rows_set_or_not():
    """An unset support height is the shared support surface's; setting one particle's sets the field; ``cat`` of
    set and unset particles keeps every row's height; ``take`` and ``truncate`` keep them."""
    a, b = particles(3, 1), particles(2, 2)
    placed = a.with_attribute(1, "support", [-0.5])
    assert placed.support is not None and placed.support[:, 0].tolist() == [0.0, -0.5, 0.0] and a.support is None
    assert placed.attribute(1, "support").tolist() == [-0.5] and a.attribute(1, "support").tolist() == [0.0]
    for ab, heights in ((placed.cat(b), [0.0, -0.5, 0.0, 0.0, 0.0]), (b.cat(placed), [0.0, 0.0, 0.0, -0.5, 0.0])):
        assert ab.support is not None and ab.support[:, 0].tolist() == heights
    assert a.cat(b).support is None
    assert placed.take([1, 1]).support[:, 0].tolist() == [-0.5, -0.5] and placed.truncate(1).support.shape == (1, 1)
    assert placed.clone().support is not placed.support and torch.equal(placed.detach().support, placed.support)


def test_cat_take_truncate_move_whole_rows():
    a, b = particles(4, 1), particles(3, 2, views=3)
    ab = a.cat(b)
    assert rows(ab) == rows(a) + rows(b)
    assert ab.background is a.background and ab.cameras is a.cameras
    posed = replace(a, pose=torch.tensor([0.1, 0.2]))
    assert posed.cat(b).pose is posed.pose and posed.take([1]).pose is posed.pose  # the scene's pose stays
    assert torch.equal(posed.clone().pose, posed.pose) and posed.clone().pose is not posed.pose
    picked = ab.take([5, 0, 0, 2])
    assert rows(picked) == [rows(ab)[5], rows(ab)[0], rows(ab)[0], rows(ab)[2]]
    assert rows(ab.take(torch.tensor([6]))) == [rows(b)[2]]
    assert rows(ab.take(slice(4, None))) == rows(b)
    assert rows(ab.truncate(4)) == rows(a)
    assert ab.truncate(0).num == 0 and ab.take([]).num == 0
    assert ab.take([1]).view.dtype == torch.int64
    # the operands are unchanged
    assert rows(a) == rows(particles(4, 1)) and a.num == 4
