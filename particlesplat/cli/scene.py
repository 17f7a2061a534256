"""``particlesplat scene check DIR``: whether a scene folder (your own capture) is in the world frame the model was
trained in (+z up, the support surface at z = 0, metres, cameras at the family's distances; a robot scene with its
robot at -x as in robosuite), and the transform to apply when it is not (:mod:`particlesplat.analysis.world_frame`).
Exit code 0 when it is, 1 when it is not, 2 for a folder that cannot be read."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from particlesplat.data.families import DEFAULT_FAMILY, family_names


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    check = sub.add_parser(
        "check",
        help="report a scene folder's up axis, scale and support height against the expected world frame",
        description="Report a scene folder's up axis, scale, depth scale and support height against the world "
        "frame the model was trained in (+z up, support surface at z = 0, metres, cameras at the distances of the "
        "family's rigs), for a robot scene also whether it is turned about z (robosuite's convention: the robot "
        "base behind the table at -x), and the transform to apply.",
    )
    check.add_argument("scene", metavar="DIR", help="scene folder (transforms.json, images, optional depth)")
    check.add_argument(
        "--family",
        choices=family_names(),
        help="judge the scene as this family's (default: what its scene.json or its dataset's synth.json records, "
        f"else {DEFAULT_FAMILY})",
    )
    check.add_argument(
        "--write",
        metavar="FILE",
        help="write DIR's transforms.json with the transform applied to FILE (put it in a copy of the folder "
        "as its transforms.json); an existing FILE is kept beside it as FILE.orig (or FILE.orig-2, ...)",
    )


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from particlesplat.analysis.world_frame import check_world_frame, report_lines, transform_lines, transform_matrix
    from particlesplat.core.atomic import atomic_write
    from particlesplat.data import read_scene
    from particlesplat.data.families import get_family
    from particlesplat.data.scene_meta import read_family, read_robot_base

    scene = read_scene(args.scene)
    family = args.family or read_family(args.scene) or DEFAULT_FAMILY
    base = read_robot_base(args.scene) if get_family(family).robot else None
    report = check_world_frame(scene, family, None if base is None else np.asarray(base, dtype=np.float64))
    print(f"scene check: {scene.path} ({report.frames} frames, {report.depth_frames} with depth, {family} family)")
    for line in report_lines(report):
        print(f"  {line}")
    if report.ok:
        robot = ", the robot at -x" if get_family(family).robot and report.turn is not None else ""
        print(f"matches the expected world frame (+z up, support surface at z = 0, metres{robot})")
    else:
        for line in transform_lines(report):
            print(line)
    if args.write:
        from particlesplat.core.atomic import keep_original
        from particlesplat.core.jsonfile import read_json
        from particlesplat.core.outputs import guard_outputs
        from particlesplat.data.scene import MAX_TRANSFORMS_BYTES, SceneFormatError

        src = Path(scene.path) / "transforms.json"
        # DIR's own transforms.json may be replaced (it is kept beside); any other file of DIR is an input
        same = Path(args.write).resolve() == src.resolve()
        guard_outputs([("--write", args.write)], [] if same else [("DIR", scene.path)])
        meta = read_json(src, MAX_TRANSFORMS_BYTES, SceneFormatError)
        assert isinstance(meta, dict)  # read_scene has read and checked it

        def scaled(value: object, where: str) -> float:  # a depth scale read only here when no frame has depth
            from particlesplat.core.limits import float32_problem

            ok = isinstance(value, (int, float)) and not isinstance(value, bool)
            problem = float32_problem(value, positive=True) if ok else "not a number"  # type: ignore[arg-type]
            if problem:
                raise SceneFormatError(f"{src}: {where}'depth_unit_scale_factor' is {problem}")
            return float(value) * report.scale  # type: ignore[arg-type]

        for i, frame in enumerate(meta["frames"]):
            m = np.asarray(frame["transform_matrix"], dtype=np.float64)
            if m.shape == (3, 4):
                m = np.concatenate([m, [[0.0, 0.0, 0.0, 1.0]]])
            frame["transform_matrix"] = transform_matrix(m, report).tolist()
            if "depth_unit_scale_factor" in frame:
                frame["depth_unit_scale_factor"] = scaled(frame["depth_unit_scale_factor"], f"frames[{i}]: key ")
        if "depth_unit_scale_factor" in meta:
            meta["depth_unit_scale_factor"] = scaled(meta["depth_unit_scale_factor"], "key ")
        kept = keep_original(Path(args.write))
        with atomic_write(args.write, "w") as f:
            json.dump(meta, f, indent=1)
        print(
            f"wrote {args.write} ({src} with the transform applied)"
            + (f"; the file it replaced is {kept}" if kept else "")
        )
    return 0 if report.ok else 1
