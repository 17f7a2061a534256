"""The policy: one small transformer over tokens, whose input tokens come from one of four sources behind one
interface (:class:`TokenSource`), trained by behaviour cloning on the expert's keyposes.

Every policy has the robot-state token (:data:`.features.ROBOT_DIMS` numbers through a two-layer MLP). The
input adds its own tokens:

- ``particles``: one token per particle of the shipped robot model's encoding of the two views (its statistics
  and latent features, :data:`PARTICLE_DIMS` numbers; a view embedding added), inactive particles masked out;
- ``images``: the two RGB-D views through a small CNN trained end to end (a 4 x 4 patch convolution, then three
  stride-2 3 x 3 convolutions: a 4 x 4 grid of 128-channel features a 128-pixel view, one cell per
  :data:`.features.IMAGE_CELL` pixels square), each cell a token with a learned position and view embedding:
  32 tokens (the shipped model's particles: 16);
- ``state``: one token per object and one for the goal pad (:data:`.features.OBJECT_DIMS` numbers);
- ``robot``: none (the floor: the robot's state alone).

Every token has a point in the world (metres): an object's box centre, a particle's decoded centroid, the mean
back-projected depth of an image cell, the grasp point for the robot token. The transformer (:data:`WIDTH` wide,
:data:`LAYERS` layers of :data:`HEADS` heads, pre-norm) reads the robot token first. The keypose's position is
*pointed at* (a keypose is a place relative to something seen: above the target, on the pad), and the head is
blind to where things are in the table's plane; see :class:`KeyposePolicy`. Sizes are the same for every input.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

from .features import ACTION_DIMS, GRASP_POINT, IMAGE_CELL, OBJECT_DIMS, ROBOT_DIMS
from .options import INPUT_NAMES, ROBOT_ALONE

INPUTS = INPUT_NAMES
WIDTH, LAYERS, HEADS = 128, 3, 4

VIEWS = 2
PARTICLE_DIMS = 16  # filled in by the particle source's features (see particle_tokens)


def _mlp(dims_in: int, width: int = WIDTH) -> nn.Sequential:
    return nn.Sequential(nn.Linear(dims_in, width), nn.GELU(), nn.Linear(width, width))


class TokenSource(nn.Module):
    """One input's tokens: ``forward(batch)`` -> (tokens (B, N, WIDTH), padding (B, N) bool, True = ignored,
    points (B, N, 3) world metres)."""

    name = ""

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor, Tensor]:  # pragma: no cover - interface
        raise NotImplementedError


class NoTokens(TokenSource):
    """The robot's state alone: no tokens."""

    name = "robot"

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor, Tensor]:
        B = batch["robot"].shape[0]
        dev = batch["robot"].device
        empty = torch.zeros(B, 0, dtype=torch.bool, device=dev)
        return torch.zeros(B, 0, WIDTH, device=dev), empty, torch.zeros(B, 0, 3, device=dev)


class SetTokens(TokenSource):
    """A padded set of rows (B, N, F) with a mask (B, N) (True: a real row): objects, or particles with their
    view (``views``: a learned embedding per view index in ``batch[key + "_view"]``). A row's first three numbers
    are its point (world metres)."""

    def __init__(self, name: str, key: str, dims: int, views: bool = False) -> None:
        super().__init__()
        self.name, self.key = name, key
        self.embed = _mlp(dims)
        self.view = nn.Embedding(VIEWS, WIDTH) if views else None

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor, Tensor]:
        rows = batch[self.key]
        tokens = self.embed(torch.cat([torch.zeros_like(rows[..., :2]), rows[..., 2:]], -1))  # x, y: see KeyposePolicy
        if self.view is not None:
            tokens = tokens + self.view(batch[self.key + "_view"])
        return tokens, ~batch[self.key + "_mask"], rows[..., :3]


class ImageTokens(TokenSource):
    """RGB-D views (B, V, 4, H, W) through a small CNN shared by the views: each cell of its last feature map is
    a token, with a learned position embedding per cell and one per view; its point is the mean world point of
    the cell's pixels (``batch["images_points"]`` (B, V * cells, 3), from depth and cameras)."""

    name = "images"

    def __init__(self, resolution: int = 128) -> None:
        super().__init__()
        # a 4 x 4 patch stem (3x cheaper here than stride-2 3 x 3 layers from full resolution), then stride 2 to
        # IMAGE_CELL pixels a cell: 32 tokens, near the particles' 16, and a step 2.3x cheaper than at 16 pixels
        self.cnn = nn.Sequential(
            nn.Conv2d(4, 32, 4, stride=4),
            nn.GELU(),
            nn.Conv2d(32, 64, 3, stride=2, padding=1),
            nn.GELU(),
            nn.Conv2d(64, WIDTH, 3, stride=2, padding=1),
            nn.GELU(),
            nn.Conv2d(WIDTH, WIDTH, 3, stride=2, padding=1),
        )
        cells = (resolution // IMAGE_CELL) ** 2
        self.position = nn.Parameter(torch.zeros(1, 1, cells, WIDTH))
        self.view = nn.Parameter(torch.zeros(1, VIEWS, 1, WIDTH))
        nn.init.normal_(self.position, std=0.02)
        nn.init.normal_(self.view, std=0.02)

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, Tensor, Tensor]:
        x = batch["images"]
        B, V = x.shape[:2]
        f = self.cnn(x.flatten(0, 1))  # (B V, C, h, w)
        f = f.flatten(2).transpose(1, 2).reshape(B, V, -1, WIDTH)
        tokens = (f + self.position + self.view).reshape(B, -1, WIDTH)
        padding = torch.zeros(tokens.shape[:2], dtype=torch.bool, device=tokens.device)
        return tokens, padding, batch["images_points"]


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


def planar_blind(robot: Tensor) -> Tensor:
    """The robot's state (B, ROBOT_DIMS) without where the arm is in the table's plane: the joint angles and the
    grasp point's x and y zeroed (its height, the hand's rotation, the fingers and the gripper kept)."""
    out = robot.clone()
    out[:, : GRASP_POINT.start] = 0.0
    out[:, GRASP_POINT.start : GRASP_POINT.start + 2] = 0.0
    return out


class KeyposePolicy(nn.Module):
    """The policy head over one token source: ``forward(batch)`` -> (B, ACTION_DIMS) actions; ``batch`` holds
    ``robot`` (B, ROBOT_DIMS) and what the source reads.

    A keypose is a place relative to the scene, wherever on the table the scene is, so the head is blind to where
    things are in the table's plane: the robot token does not see the arm's x and y (:func:`planar_blind`), a
    set's rows lose their point's x and y, and every token instead gets an embedding of its point relative to the
    grasp point. The position is the pointed point (a softmax over the output tokens weighting their points, the
    robot token's being the grasp point) plus an offset read from the robot token's output, the pointed tokens'
    mean output, and the pointed point relative to the grasp point and its height. Moving the whole scene and the
    arm in x and y moves the predicted position with them and changes nothing else."""

    def __init__(self, source: TokenSource) -> None:
        super().__init__()
        self.source = source
        self.robot = _mlp(ROBOT_DIMS)
        self.where = _mlp(3)
        layer = nn.TransformerEncoderLayer(
            WIDTH, HEADS, dim_feedforward=4 * WIDTH, dropout=0.0, batch_first=True, norm_first=True
        )
        self.transformer = nn.TransformerEncoder(layer, LAYERS, enable_nested_tensor=False)
        self.norm = nn.LayerNorm(WIDTH)
        self.pointer = nn.Linear(WIDTH, 1)
        self.out = nn.Sequential(nn.Linear(2 * WIDTH + 4, WIDTH), nn.GELU(), nn.Linear(WIDTH, ACTION_DIMS))

    def forward(self, batch: dict[str, Tensor]) -> Tensor:
        robot = batch["robot"]
        grasp = robot[:, GRASP_POINT]  # (B, 3)
        tokens, padding, points = self.source(batch)
        tokens = tokens + self.where(points - grasp[:, None])
        x = torch.cat([self.robot(planar_blind(robot))[:, None], tokens], 1)
        pad = torch.cat([torch.zeros(padding.shape[0], 1, dtype=torch.bool, device=padding.device), padding], 1)
        points = torch.cat([grasp[:, None], points], 1)  # (B, 1 + N, 3)
        h = self.norm(self.transformer(x, src_key_padding_mask=pad))
        weights = self.pointer(h).squeeze(-1).masked_fill(pad, float("-inf")).softmax(-1)  # (B, 1 + N)
        pointed = torch.einsum("bn,bnc->bc", weights, h)
        point = torch.einsum("bn,bnk->bk", weights, points)
        action = self.out(torch.cat([h[:, 0], pointed, point - grasp, point[:, 2:]], 1))
        return torch.cat([point + action[:, :3], action[:, 3:]], 1)
