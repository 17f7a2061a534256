"""The policy: one small transformer over tokens, whose input tokens come from one of four sources behind one
interface (:class:`TokenSource`), trained by behaviour cloning on the expert's keyposes.

Every policy has the robot-state token (:data:`.features.ROBOT_DIMS` numbers through a two-layer MLP). The
input adds its own tokens:

- ``particles``: one token per particle of the shipped robot model's encoding of the two views (its statistics
  and latent features, :data:`PARTICLE_DIMS` numbers; a view embedding added), inactive particles masked out;
- ``images``: the two RGB-D views through a small CNN trained end to end (four stride-2 convolutions: an 8 x 8
  grid of 128-channel features a 128-pixel view), each cell a token with a learned position and view embedding;
- ``state``: one token per object and one for the goal pad (:data:`.features.OBJECT_DIMS` numbers);
- ``robot``: none (the floor: the robot's state alone).

The transformer (:data:`WIDTH` wide, :data:`LAYERS` layers of :data:`HEADS` heads, pre-norm) reads the robot
token first; its output there is mapped to the action (:data:`.features.ACTION_DIMS`: position, 6-D rotation,
gripper). Sizes are the same for every input.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from .features import ACTION_DIMS, OBJECT_DIMS, ROBOT_DIMS
from .options import INPUT_NAMES, ROBOT_ALONE

INPUTS = INPUT_NAMES
WIDTH, LAYERS, HEADS = 128, 3, 4
VIEWS = 2
PARTICLE_DIMS = 16  # filled in by the particle source's features (see particle_tokens)


def _mlp(dims_in: int, width: int = WIDTH) -> nn.Sequential:
    return nn.Sequential(nn.Linear(dims_in, width), nn.GELU(), nn.Linear(width, width))


class TokenSource(nn.Module):
    """One input's tokens: ``forward(batch)`` -> (tokens (B, N, WIDTH), padding (B, N) bool, True = ignored)."""

    name = ""

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:  # pragma: no cover - interface
        raise NotImplementedError


class NoTokens(TokenSource):
    """The robot's state alone: no tokens."""

    name = "robot"

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        B = batch["robot"].shape[0]
        dev = batch["robot"].device
        return torch.zeros(B, 0, WIDTH, device=dev), torch.zeros(B, 0, dtype=torch.bool, device=dev)


class SetTokens(TokenSource):
    """A padded set of rows (B, N, F) with a mask (B, N) (True: a real row): objects, or particles with their
    view (``views``: a learned embedding per view index in ``batch[key + "_view"]``)."""

    def __init__(self, name: str, key: str, dims: int, views: bool = False) -> None:
        super().__init__()
        self.name, self.key = name, key
        self.embed = _mlp(dims)
        self.view = nn.Embedding(VIEWS, WIDTH) if views else None

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        tokens = self.embed(batch[self.key])
        if self.view is not None:
            tokens = tokens + self.view(batch[self.key + "_view"])
        return tokens, ~batch[self.key + "_mask"]


class ImageTokens(TokenSource):
    """RGB-D views (B, V, 4, H, W) through a small CNN shared by the views: each cell of its last feature map is
    a token, with a learned position embedding per cell and one per view."""

    name = "images"

    def __init__(self, resolution: int = 128) -> None:
        super().__init__()
        chans = (4, 32, 64, 64, WIDTH)
        layers: list[nn.Module] = []
        for i in range(4):
            layers += [nn.Conv2d(chans[i], chans[i + 1], 3, stride=2, padding=1), nn.GELU()]
        self.cnn = nn.Sequential(*layers[:-1])
        cells = (resolution // 16) ** 2
        self.position = nn.Parameter(torch.zeros(1, 1, cells, WIDTH))
        self.view = nn.Parameter(torch.zeros(1, VIEWS, 1, WIDTH))
        nn.init.normal_(self.position, std=0.02)
        nn.init.normal_(self.view, std=0.02)

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        x = batch["images"]
        B, V = x.shape[:2]
        f = self.cnn(x.flatten(0, 1))  # (B V, C, h, w)
        f = f.flatten(2).transpose(1, 2).reshape(B, V, -1, WIDTH)
        tokens = (f + self.position + self.view).reshape(B, -1, WIDTH)
        return tokens, torch.zeros(tokens.shape[:2], dtype=torch.bool, device=tokens.device)


def token_source(kind: str, particle_dims: int = PARTICLE_DIMS) -> TokenSource:
    """The token source of input ``kind`` (one of :data:`INPUTS`)."""
    if kind == ROBOT_ALONE:
        return NoTokens()
    if kind == "state":
        return SetTokens("state", "objects", OBJECT_DIMS)
    if kind == "particles":
        return SetTokens("particles", "particles", particle_dims, views=True)
    if kind == "images":
        return ImageTokens()
    raise ValueError(f"unknown input {kind!r}; one of {', '.join(INPUTS)}")


class KeyposePolicy(nn.Module):
    """The policy head over one token source: ``forward(batch)`` -> (B, ACTION_DIMS) actions; ``batch`` holds
    ``robot`` (B, ROBOT_DIMS) and what the source reads."""

    def __init__(self, source: TokenSource) -> None:
        super().__init__()
        self.source = source
        self.robot = _mlp(ROBOT_DIMS)
        layer = nn.TransformerEncoderLayer(
            WIDTH, HEADS, dim_feedforward=4 * WIDTH, dropout=0.0, batch_first=True, norm_first=True
        )
        self.transformer = nn.TransformerEncoder(layer, LAYERS, enable_nested_tensor=False)
        self.out = nn.Sequential(nn.LayerNorm(WIDTH), nn.Linear(WIDTH, WIDTH), nn.GELU(), nn.Linear(WIDTH, ACTION_DIMS))

    def forward(self, batch: dict[str, Tensor]) -> Tensor:
        robot = self.robot(batch["robot"])[:, None]
        tokens, padding = self.source(batch)
        x = torch.cat([robot, tokens], 1)
        pad = torch.cat([torch.zeros(padding.shape[0], 1, dtype=torch.bool, device=padding.device), padding], 1)
        return self.out(self.transformer(x, src_key_padding_mask=pad)[:, 0])
