"""A contact sheet of scene folders: one row per scene, a few views across the arc and the front view's instance
mask, as one small palette PNG (for the README's data section).

    python -m particlesplat.data.families.robot_sheet SPLIT_DIR OUT.png [--scenes 6] [--views 0,5,10,15,20]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from particlesplat.core.errors import run_command
from particlesplat.core.jsonfile import read_json

# instance-id colours for the mask column: background dark grey, then distinct hues
MASK_COLOURS = np.array(
    [(40, 40, 40), (230, 80, 70), (80, 190, 90), (70, 120, 230), (240, 200, 60), (170, 90, 210), (60, 200, 210)],
    dtype=np.uint8,
)


def contact_sheet(scene_dirs: list[Path], views: list[int], thumb: int = 96) -> Image.Image:
    """Rows of ``views`` (RGB) plus the middle view's mask per scene, each ``thumb`` x ``thumb`` pixels."""
    rows = []
    for d in scene_dirs:
        frames = read_json(d / "transforms.json")["frames"]  # type: ignore[index]
        tiles = [Image.open(d / frames[v]["file_path"]).convert("RGB").resize((thumb, thumb)) for v in views]
        mid = views[len(views) // 2]
        mask = np.asarray(Image.open(d / frames[mid]["instance_mask_path"]))
        tiles.append(
            Image.fromarray(MASK_COLOURS[mask % len(MASK_COLOURS)]).resize((thumb, thumb), Image.Resampling.NEAREST)
        )
        rows.append(np.concatenate([np.asarray(t) for t in tiles], axis=1))
    return Image.fromarray(np.concatenate(rows, axis=0))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m particlesplat.data.families.robot_sheet", description=__doc__)
    parser.add_argument("split", type=Path, help="a folder of scene folders (e.g. DATA/train)")
    parser.add_argument("out", type=Path, help="PNG to write")
    parser.add_argument("--scenes", type=int, default=6)
    parser.add_argument("--views", default="0,5,10,15,20", help="frame indices across the arc")
    parser.add_argument("--thumb", type=int, default=96, help="tile size in pixels")
    args = parser.parse_args(argv)
    scenes = sorted(p for p in args.split.iterdir() if (p / "transforms.json").is_file())[: args.scenes]
    if not scenes:
        raise ValueError(f"{args.split}: no scene folders")
    sheet = contact_sheet(scenes, [int(v) for v in args.views.split(",")], args.thumb)
    sheet.quantize(colors=256, method=Image.Quantize.MEDIANCUT).save(args.out, optimize=True)
    print(f"wrote {args.out} ({args.out.stat().st_size // 1024} KB)")
    return 0


if __name__ == "__main__":
    sys.exit(run_command("robot_sheet", main))
