"""Edit YAML files: round trip, validation messages naming file and field, apply/diff."""

from __future__ import annotations

import pytest
import torch

from particlesplat.editing.editor import load_edit_file
from particlesplat.editing.particle_edits import (
    EditsError,
    apply_edits,
    diff_edits,
    validate_edits,
)
from particlesplat.model.particles import Particles


def particles(n: int = 4) -> Particles:
    g = torch.Generator().manual_seed(0)
    r = lambda *s: torch.randn(*s, generator=g)  # noqa: E731
    return Particles(
        z_p=r(n, 2),
        z_s=r(n, 2),
        z_d=r(n, 1),
        z_e=r(n, 1),
        z_t=torch.rand(n, 1, generator=g),
        z_f=r(n, 3),
        view=torch.zeros(n, dtype=torch.int64),
        background=r(1, 2, 4, 4),
    )


def load_edits(path):
    """The particle edits of a version 1 edit file, through the one reader of edit files."""
    file = load_edit_file(path)
    assert file.version == 1
    return file.particles


def test_a_version_1_file_loads(tmp_path):
    path = tmp_path / "e.yaml"
    path.write_text(
        "version: 1\nmodel: m.pt\nscene: scene_0\nparticles:\n  3:\n    z_p: [0.25, -0.5]\n    z_t: [0.0]\n"
        "  0:\n    z_d: [1.5]\n"
    )
    assert load_edits(path) == {3: {"z_p": (0.25, -0.5), "z_t": (0.0,)}, 0: {"z_d": (1.5,)}}
    assert load_edit_file(path).scene == "scene_0"


def test_apply_then_diff_recovers_the_edits():
    p = particles()
    edits = {1: {"z_s": (0.5, 0.25)}, 2: {"z_e": (-1.0,), "z_t": (1.0,)}}
    q = apply_edits(p, edits)
    assert torch.equal(q.z_s[1], torch.tensor([0.5, 0.25]))
    assert torch.equal(q.z_p, p.z_p)  # untouched attributes stay
    assert diff_edits(p, q) == edits


@pytest.mark.parametrize(
    "text,field",
    [
        ("particles: {1: {z_q: [1]}}", "particles.1.z_q"),
        ("particles: {1: {z_p: [1, 2, 3]}}", "particles.1.z_p"),
        ("particles: {-2: {z_d: 1}}", "particles.-2"),
        ("particles: {x: {z_d: 1}}", "particles.x"),
        ("particles: {0: {z_t: 2.0}}", "particles.0.z_t"),
        ("particles: {0: {z_d: [.nan]}}", "particles.0.z_d"),
        ("particles: {0: {z_d: [yes]}}", "particles.0.z_d"),
        ("particles: [1, 2]", "particles"),
        ("version: 7\nparticles: {}", "version"),
        ("particles: {}\ncolour: red", "unknown key"),
        ("particles: {3: {z_d: 1}, '3': {z_d: 2}}", "particles.3: particle 3 is listed twice"),
    ],
)
def test_validation_names_file_and_field(tmp_path, text, field):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(EditsError) as e:
        load_edits(path)
    assert str(path) in str(e.value) and field in str(e.value)


def test_bad_yaml_and_missing_file(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("particles: {1: [")
    with pytest.raises(EditsError, match="broken.yaml"):
        load_edits(path)
    with pytest.raises(FileNotFoundError, match="nope.yaml"):
        load_edits(tmp_path / "nope.yaml")


def test_index_out_of_range_and_bare_numbers():
    assert validate_edits({"particles": {"2": {"z_d": 0.5}}}) == {2: {"z_d": (0.5,)}}
    with pytest.raises(EditsError, match="particles.9"):
        apply_edits(particles(4), {9: {"z_d": (0.0,)}})
