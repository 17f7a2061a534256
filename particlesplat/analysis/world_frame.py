"""Whether a scene folder is in the world frame the model was trained in (+z up, the support surface at z = 0,
metres, cameras at the family's distances from the objects) and, when it is not, the similarity transform that
brings it there.

The family picks the camera distances the scale is judged against (its registered
:attr:`particlesplat.data.families.Family.camera_distances`: the tabletop scenes' 3.0-3.6 m, the robot rigs'
0.8-1.25 m). A scene of a family with a robot (:attr:`~particlesplat.data.families.Family.robot`) is also checked
for a turn about z: robosuite's convention has the robot base behind the table at -x (facing +x). The base's
direction comes from scene.json's ``robot_base`` where the scene records one, else from the depth: the robot is
what stands above the support surface near the scene, beyond the table's edge (:func:`robot_azimuth`).

The up axis is the normal of the largest plane of the depth points (the table or floor; found by RANSAC), turned
towards the cameras; without depth, the normal of the plane of the camera centres (cameras around a scene), else
the cameras' mean up vector. The scale compares the cameras' distance to the point they look at with the training
scenes' (metres); a factor near a power of ten reads as a unit mistake (millimetres, centimetres). The support
height is that plane's height once up is +z.

A transform ``x' = s R x + t`` (world points) is applied to a camera-to-world matrix with rotation ``R_c`` and
translation ``t_c`` as ``R_c' = R R_c``, ``t_c' = s R t_c + t`` (in any camera axis convention), and to depth as
``depth_unit_scale_factor' = s depth_unit_scale_factor``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from particlesplat.core.viewpoints import focus_point
from particlesplat.data.families import DEFAULT_FAMILY, get_family
from particlesplat.data.scene import RawScene

UpSource = Literal["support plane", "camera centres", "camera up vectors"]
RobotSource = Literal["scene.json robot_base", "depth above the table"]
ROBOT_AZIMUTH = 180.0  # degrees: robosuite's convention, the robot base at -x of the table centre
TURN_TOLERANCE_DEG = 15.0  # a robot within this of -x is not turned
TURN_SNAP_DEG = 20.0  # a measured turn within this of a quarter turn is read as that quarter turn
ROBOT_HEIGHT = (0.02, 1.2)  # metres above the support: what stands this high beyond the table's edge is the robot
ROBOT_EDGE_MARGIN = 0.03  # metres beyond the support's edge in a direction
EDGE_PERCENTILE = 95.0  # the edge: this percentile of the support points' distances in a direction (a few stray
# points at the support's height, e.g. the top of a robot base level with the table, do not move it)
ROBOT_RADIUS = 1.0  # metres (x, y) from the looked-at point within which the robot is looked for
ROBOT_MIN_POINTS = 50
UP_TOLERANCE_DEG = 3.0  # the up axis is +z when within this angle (and snapped to an axis when within it of one)
SUPPORT_TOLERANCE = 0.05  # metres: the support surface is at z = 0 within this
CENTRE_RADIUS = 1.0  # metres: the training scenes' objects lie within this of the origin (x, y)
SCALE_SLACK = 2.0  # the camera distance may be this factor outside the family's distances before the scale is flagged
DEPTH_RATIO_RANGE = (0.3, 3.0)  # median depth / camera distance of a plausible depth scale
POINTS_PER_FRAME = 3000
RANSAC_ITERATIONS = 300
UNITS = {1e-3: "millimetres", 1e-2: "centimetres", 1e3: "kilometres"}


@dataclass(frozen=True)
class WorldFrameReport:
    """What :func:`check_world_frame` found, in the scene's own units, and the transform to apply.

    Attributes:
        frames: frames in the scene; depth_frames: those with depth.
        up: (3,) unit vector, the measured up direction in the scene's world; up_source: how it was measured.
        up_angle: degrees between ``up`` and +z.
        camera_distance: median distance of the cameras to the point they look at (scene units).
        depth_ratio: median depth / camera distance (None without depth).
        support: the support surface's height along ``up`` after ``rotation`` and ``scale`` (metres), or None.
        centre: (2,) x, y of the looked-at point after the transform's rotation and scale (metres).
        rotation: (3, 3); scale: metres per scene unit; translation: (3,) metres (the transform to apply).
        unit: the unit mistake the scale suggests, or "".
        family: a registered family's name (the camera distances it was judged against).
        robot_azimuth: robot scenes: degrees (counter-clockwise from +x, after the up rotation) of the robot base
            seen from the looked-at point, or None when it could not be told; robot_source: where it came from.
        turn: degrees the robot stands turned from robosuite's -x (0 when within the tolerance; the transform's
            rotation turns it back), None when not measured.
    """

    frames: int
    depth_frames: int
    up: np.ndarray
    up_source: UpSource
    up_angle: float
    camera_distance: float
    depth_ratio: float | None
    support: float | None
    centre: np.ndarray
    rotation: np.ndarray
    scale: float
    translation: np.ndarray
    unit: str
    family: str = DEFAULT_FAMILY
    robot_azimuth: float | None = None
    robot_source: RobotSource | None = None
    turn: float | None = None

    @property
    def turn_ok(self) -> bool:
        return self.turn is None or self.turn == 0.0

    @property
    def up_ok(self) -> bool:
        return self.up_angle <= UP_TOLERANCE_DEG

    @property
    def scale_ok(self) -> bool:
        return self.scale == 1.0

    @property
    def depth_ok(self) -> bool:
        return self.depth_ratio is None or DEPTH_RATIO_RANGE[0] <= self.depth_ratio <= DEPTH_RATIO_RANGE[1]

    @property
    def support_ok(self) -> bool:
        return self.support is None or abs(self.support) <= SUPPORT_TOLERANCE

    @property
    def centre_ok(self) -> bool:
        return float(np.hypot(*self.centre)) <= CENTRE_RADIUS

    @property
    def ok(self) -> bool:
        return self.up_ok and self.scale_ok and self.depth_ok and self.support_ok and self.centre_ok and self.turn_ok


def _c2w(scene: RawScene) -> np.ndarray:
    return np.stack([c.c2w.detach().double().cpu().numpy() for c in scene.cameras])  # (V, 4, 4) OpenCV


def depth_points(scene: RawScene, per_frame: int = POINTS_PER_FRAME) -> np.ndarray:
    """(N, 3) world points of the frames' depth (planar camera z), about ``per_frame`` per frame with depth."""
    out = []
    for cam, depth in zip(scene.cameras, scene.depth, strict=True):
        if depth is None:
            continue
        h, w = depth.shape
        step = max(1, int(math.sqrt(h * w / per_frame)))
        v, u = np.mgrid[0:h:step, 0:w:step]
        d = depth[v, u].astype(np.float64)
        keep = d > 0
        if not keep.any():
            continue
        K = cam.K.detach().double().cpu().numpy()
        c2w = cam.c2w.detach().double().cpu().numpy()
        x = (u[keep] + 0.5 - K[0, 2]) / K[0, 0] * d[keep]
        y = (v[keep] + 0.5 - K[1, 2]) / K[1, 1] * d[keep]
        pts = np.stack([x, y, d[keep]], 1)
        out.append(pts @ c2w[:3, :3].T + c2w[:3, 3])
    return np.concatenate(out) if out else np.zeros((0, 3))


def largest_plane(points: np.ndarray, threshold: float, seed: int = 0) -> tuple[np.ndarray, float, np.ndarray] | None:
    """RANSAC: the plane ``n . x = c`` holding most of ``points`` within ``threshold``: (unit n, c, inlier mask),
    refined by least squares on its inliers; None for fewer than 3 points."""
    if len(points) < 3:
        return None
    rng = np.random.default_rng(seed)
    best, best_count = None, -1
    for _ in range(RANSAC_ITERATIONS):
        a, b, c = points[rng.choice(len(points), 3, replace=False)]
        n = np.cross(b - a, c - a)
        norm = np.linalg.norm(n)
        if norm < 1e-12:
            continue
        n /= norm
        count = int((np.abs(points @ n - n @ a) < threshold).sum())
        if count > best_count:
            best, best_count = (n, float(n @ a)), count
    if best is None:
        return None
    inliers = np.abs(points @ best[0] - best[1]) < threshold
    p = points[inliers]
    mean = p.mean(0)
    n = np.linalg.svd(p - mean, full_matrices=False)[2][-1]
    return n, float(n @ mean), np.abs(points @ n - n @ mean) < threshold


def rotation_to_z(up: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking unit ``up`` to +z."""
    z = np.array([0.0, 0.0, 1.0])
    v, c = np.cross(up, z), float(up @ z)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])
    vx = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def _snap(up: np.ndarray) -> np.ndarray:
    """``up`` replaced by the signed world axis it is within UP_TOLERANCE_DEG of, if any."""
    axis = np.zeros(3)
    k = int(np.abs(up).argmax())
    axis[k] = math.copysign(1.0, up[k])
    return axis if math.degrees(math.acos(min(1.0, float(up @ axis)))) <= UP_TOLERANCE_DEG else up


def distance_range(family: str) -> tuple[float, float]:
    """The training cameras' distances (metres) of a family's scenes (its registered ``camera_distances``)."""
    return get_family(family).camera_distances


def _scale(distance: float, family: str) -> tuple[float, str]:
    lo, hi = distance_range(family)
    if lo / SCALE_SLACK <= distance <= hi * SCALE_SLACK:
        return 1.0, ""
    s = 0.5 * (lo + hi) / distance
    power = 10.0 ** round(math.log10(s))
    if power != 1.0 and abs(math.log10(s / power)) < math.log10(SCALE_SLACK):
        return power, UNITS.get(power, "")
    return float(f"{s:.3g}"), ""


def _rot_z(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def robot_azimuth(points: np.ndarray, on_support: np.ndarray, centre: np.ndarray) -> float | None:
    """Degrees (counter-clockwise from +x) of the robot seen from ``centre`` (2,): the direction of the mean of
    the ``points`` (N, 3; metres, +z up, the support at z = 0) that stand :data:`ROBOT_HEIGHT` above the support,
    within :data:`ROBOT_RADIUS` of the centre, beyond the support's edge (the base and mount behind the table; an
    arm over the table and the objects on it are within its edge, walls farther). The edge, per 5-degree sector
    about the support points' (``on_support``, (N,) bool) centroid, is the :data:`EDGE_PERCENTILE` of their
    distances. None when fewer than :data:`ROBOT_MIN_POINTS` points qualify."""
    near = np.hypot(*(points[:, :2] - centre).T) < ROBOT_RADIUS
    table = points[on_support & near, :2]  # (a wall crossing the support's height far away is no table)
    if len(table) < ROBOT_MIN_POINTS:
        return None
    middle = table.mean(0)
    sectors = 72

    def polar(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        d = xy - middle
        ang = ((np.arctan2(d[:, 1], d[:, 0]) + math.pi) / (2 * math.pi) * sectors).astype(np.int64) % sectors
        return ang, np.hypot(d[:, 0], d[:, 1])

    ang, rad = polar(table)
    edge = np.array(
        [np.percentile(rad[ang == k], EDGE_PERCENTILE) if (ang == k).any() else 0.0 for k in range(sectors)]
    )
    ang, rad = polar(points[:, :2])
    xy = points[:, :2] - centre
    keep = (
        (points[:, 2] > ROBOT_HEIGHT[0])
        & (points[:, 2] < ROBOT_HEIGHT[1])
        & near
        & (rad > edge[ang] + ROBOT_EDGE_MARGIN)
    )
    if int(keep.sum()) < ROBOT_MIN_POINTS:
        return None
    mx, my = xy[keep].mean(0)
    return round(math.degrees(math.atan2(my, mx)), 1) % 360.0


def _turn(azimuth: float, exact: bool) -> float:
    """Degrees in (-180, 180] the robot at ``azimuth`` stands turned from -x: 0 within the tolerance, and a
    measured (not ``exact``) turn near a quarter turn snapped to it."""
    turn = (azimuth - ROBOT_AZIMUTH + 180.0) % 360.0 - 180.0
    if abs(turn) <= TURN_TOLERANCE_DEG:
        return 0.0
    quarter = 90.0 * round(turn / 90.0)
    if not exact and abs(turn - quarter) <= TURN_SNAP_DEG:
        turn = quarter
    return 180.0 if turn == -180.0 else turn


def check_world_frame(
    scene: RawScene, family: str = DEFAULT_FAMILY, robot_base: np.ndarray | None = None
) -> WorldFrameReport:
    """Measure a scene's up axis, scale, depth scale and support height and, for a scene of a family with a robot
    (``family``), the robot's turn about z from ``robot_base`` (4, 4; scene.json's) or the depth (see the module's
    docstring)."""
    c2w = _c2w(scene)
    centres = c2w[:, :3, 3]
    cam_up = -c2w[:, :3, 1].mean(0)  # OpenCV: image y points down
    focus = focus_point(scene.cameras).double().cpu().numpy()
    distance = float(np.median(np.linalg.norm(centres - focus, axis=1)))
    if not distance > 1e-9 * max(1.0, float(np.abs(centres).max())):
        from particlesplat.data.scene import TRANSFORMS, SceneFormatError

        raise SceneFormatError(
            f"{scene.path / TRANSFORMS}: the cameras stand where they look (median distance {distance:.3g} m from the "
            "point they face): no scale or up axis can be measured from this rig"
        )
    pts = depth_points(scene)
    depth_frames = sum(d is not None and bool((d > 0).any()) for d in scene.depth)
    depth_ratio: float | None = None  # set exactly when there are depth points
    if len(pts):
        depths = np.concatenate([d[d > 0] for d in scene.depth if d is not None])
        depth_ratio = float(np.median(depths)) / max(distance, 1e-12)
    plane = None
    if depth_ratio is not None and DEPTH_RATIO_RANGE[0] <= depth_ratio <= DEPTH_RATIO_RANGE[1]:
        plane = largest_plane(pts, 0.01 * distance)
    source: UpSource
    if plane is not None:
        up, source = plane[0], "support plane"
    else:
        sv = np.linalg.svd(centres - centres.mean(0), full_matrices=False) if len(centres) >= 3 else None
        if sv is not None and sv[1][1] > 0.2 * sv[1][0] and sv[1][2] < 0.2 * sv[1][1]:
            up, source = sv[2][-1], "camera centres"  # cameras spread around the scene, in a plane
        else:
            up, source = cam_up, "camera up vectors"
    up = up / np.linalg.norm(up)
    towards = centres.mean(0) - focus if source == "support plane" else cam_up
    if float(up @ towards) < 0:
        up = -up  # towards the cameras (they look down at the support)
    angle = math.degrees(math.acos(max(-1.0, min(1.0, float(up[2])))))
    R = np.eye(3) if angle <= UP_TOLERANCE_DEG else rotation_to_z(_snap(up))
    s, unit = _scale(distance, family)
    support = None
    if plane is not None:
        support = float(np.median((pts[plane[2]] @ R.T)[:, 2])) * s
    azimuth: float | None = None
    robot_source: RobotSource | None = None
    turn: float | None = None
    if get_family(family).robot:
        if robot_base is not None:
            base = R @ robot_base[:3, 3] - R @ focus
            azimuth = round(math.degrees(math.atan2(base[1], base[0])), 1) % 360.0
            robot_source = "scene.json robot_base"
        elif support is not None and plane is not None:
            lifted = s * (pts @ R.T) - np.array([0.0, 0.0, support])
            azimuth = robot_azimuth(lifted, plane[2], s * (R @ focus)[:2])
            robot_source = "depth above the table"
        if azimuth is not None:
            turn = _turn(azimuth, robot_source == "scene.json robot_base")
            R = _rot_z(-turn) @ R
    centre = (s * (R @ focus))[:2]
    t = np.zeros(3)
    if float(np.hypot(*centre)) > CENTRE_RADIUS:
        t[:2] = -centre
    if support is not None and abs(support) > SUPPORT_TOLERANCE:
        t[2] = -support
    return WorldFrameReport(
        frames=len(scene.cameras),
        depth_frames=depth_frames,
        up=up,
        up_source=source,
        up_angle=angle,
        camera_distance=distance,
        depth_ratio=depth_ratio,
        support=support,
        centre=centre,
        rotation=R,
        scale=s,
        translation=t,
        unit=unit,
        family=family,
        robot_azimuth=azimuth,
        robot_source=robot_source if azimuth is not None else None,
        turn=turn,
    )


def report_lines(r: WorldFrameReport) -> list[str]:
    """The report, one finding a line, each ending in ``ok`` or ``differs``."""
    mark = lambda good: "ok" if good else "differs"  # noqa: E731
    lo, hi = distance_range(r.family)
    lines = [
        f"up axis: ({r.up[0]:+.3f}, {r.up[1]:+.3f}, {r.up[2]:+.3f}) from the {r.up_source}, {r.up_angle:.1f} degrees "
        f"from +z: {mark(r.up_ok)}",
        f"scale: the cameras are {r.camera_distance:.4g} units from the point they look at; the {r.family} "
        f"training scenes' are {lo:g}-{hi:g} m"
        + (
            f" (the units look like {r.unit})"
            if r.unit
            else ""
            if r.scale_ok
            else f" (in metres, a {'closer' if r.scale > 1 else 'farther'} capture than the model saw: scaling by "
            f"{r.scale:g} gives their camera distance and object sizes)"
        )
        + f": {mark(r.scale_ok)}",
    ]
    if r.depth_ratio is not None:
        lines.append(
            f"depth: median depth {r.depth_ratio:.3g} x the camera distance (depth_unit_scale_factor "
            f"{'agrees with' if r.depth_ok else 'does not agree with'} the camera positions): {mark(r.depth_ok)}"
        )
    if r.support is None:
        lines.append("support surface: not measured (it needs depth that agrees with the cameras)")
    else:
        lines.append(f"support surface: z = {r.support:+.3f} m once up is +z: {mark(r.support_ok)}")
    lines.append(
        f"scene centre: x, y = ({r.centre[0]:+.3f}, {r.centre[1]:+.3f}) m, within {CENTRE_RADIUS:g} m of the "
        f"origin: {mark(r.centre_ok)}"
    )
    if get_family(r.family).robot:
        if r.robot_azimuth is None or r.turn is None:
            lines.append(
                "robot: not found (it needs scene.json's robot_base, or depth of the arm standing above the table)"
            )
        else:
            where = (
                "at -x, robosuite's convention"
                if r.turn == 0.0
                else f"turned {r.turn:+.0f} degrees about z from robosuite's convention (-x)"
            )
            lines.append(
                f"robot: its base is at azimuth {round(r.robot_azimuth) % 360} degrees from the scene centre (from the "
                f"{r.robot_source}), {where}: {mark(r.turn_ok)}"
            )
    return lines


def transform_lines(r: WorldFrameReport) -> list[str]:
    """How to apply the report's transform to a scene folder's transforms.json."""
    R = "; ".join(" ".join(f"{v:+.6f}" for v in row) for row in r.rotation)
    t = " ".join(f"{v:+.6f}" for v in r.translation)
    lines = [
        "to bring it into the expected frame, transform the world by x' = s R x + t with",
        f"  R = [{R}], s = {r.scale:g}, t = [{t}] (metres)",
        "  every frame's transform_matrix [R_c | t_c]: R_c' = R R_c, t_c' = s R t_c + t",
    ]
    if not r.depth_ok:
        lines.append(
            f"  and fix depth_unit_scale_factor: it makes depth {r.depth_ratio:.3g} x the camera distance "
            "(about 1 is expected); check the depth images' units"
        )
    elif r.scale != 1.0:
        lines.append(f"  and depth_unit_scale_factor' = {r.scale:g} x depth_unit_scale_factor")
    lines.append("  (particlesplat scene check DIR --write FILE writes the transformed transforms.json)")
    return lines


def transform_matrix(m: np.ndarray, r: WorldFrameReport) -> np.ndarray:
    """A (4, 4) camera-to-world matrix (any camera axis convention) in the corrected world."""
    out = np.eye(4)
    out[:3, :3] = r.rotation @ m[:3, :3]
    out[:3, 3] = r.scale * (r.rotation @ m[:3, 3]) + r.translation
    return out
