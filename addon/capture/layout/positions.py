"""Camera layouts for a capture: where the train/val/test cameras go. Pure functions, no bpy.

The position generators return lists of (x, y, z) tuples; ``layout.cameras.create_cameras`` turns a
layout into real camera objects in the "NeRF Cameras" collection (``layout.collection``), which users
can inspect and edit before capturing (a capture renders whatever cameras that collection holds).

Elevations are in degrees above the target's horizontal plane (+Z up, as in Blender).

Every layout but one looks in at the target from outside. ``inside`` is for rooms and other scenes
that surround the camera: cameras stand inside the target's box and look outward (see ``inside_poses``).
"""
from __future__ import annotations

import math
import random
from dataclasses import dataclass

COLLECTION_NAME = "NeRF Cameras"
SPLITS = ("train", "val", "test")
GENERATED_LAYOUTS = ("hemisphere", "sphere", "random", "rings", "spiral", "inside")
SCENE_LAYOUTS = ("scene-cameras", "animation")
LAYOUTS = GENERATED_LAYOUTS + SCENE_LAYOUTS
GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))
# The "inside" layout: cameras keep this fraction of each horizontal extent free along the walls, stand
# in this band of the height (fractions of it from the floor), and clip geometry nearer than 5 cm.
INSIDE_WALL_MARGIN = 0.12
INSIDE_HEIGHT_BAND = (0.4, 0.6)
INSIDE_CLIP_START = 0.05
RINGS_ELEVATION = (10.0, 60.0)  # the Capture panel's default for rings (ui.panel._layout_changed)
INSIDE_ELEVATION = (-25.0, 15.0)  # a room's furniture stands low: more floor than ceiling


class LayoutError(ValueError):
    """A layout cannot be built; the message says why and what to change."""


@dataclass
class LayoutSpec:
    """Everything that decides camera placement; stored in the manifest for reproducibility."""

    layout: str = "hemisphere"
    train: int = 100
    val: int = 10
    test: int = 10
    radius: float = 0.0  # 0 = auto: the target's bounding sphere fills the frame
    elevation_min: float | None = None  # None = layout default
    elevation_max: float | None = None
    seed: int = 0
    rings: int = 3
    turns: float = 3.0
    frame_step: int = 10
    focal_length: float = 50.0  # mm on a 36 mm sensor: camera_angle_x 0.6911, as in the NeRF synthetic data
    target: str = "SCENE"  # or SELECTION
    margin: float = 1.05

    def elevation_range(self) -> tuple[float, float]:
        default = (-90.0, 90.0) if self.layout in ("sphere", "random") else (0.0, 90.0)
        if self.layout == "inside":
            default = INSIDE_ELEVATION
        elif self.layout == "rings":
            default = RINGS_ELEVATION  # as the panel: a ring at 90 degrees would put all its cameras at the pole
        lo = default[0] if self.elevation_min is None else self.elevation_min
        hi = default[1] if self.elevation_max is None else self.elevation_max
        if not -90.0 <= lo <= hi <= 90.0:
            raise LayoutError(f"elevation range [{lo}, {hi}] must satisfy -90 <= min <= max <= 90 degrees")
        return lo, hi

    def to_dict(self) -> dict:
        d = dict(self.__dict__)
        d["elevation_min"], d["elevation_max"] = self.elevation_range()
        return d


# ---------------------------------------------------------------------------------------------
# Pure position generators: (n, radius, centre, elevation range) -> list of n (x, y, z)


def _on_sphere(centre, radius, z_unit, azimuth):
    r_xy = math.sqrt(max(0.0, 1.0 - z_unit * z_unit))
    return (
        centre[0] + radius * r_xy * math.cos(azimuth),
        centre[1] + radius * r_xy * math.sin(azimuth),
        centre[2] + radius * z_unit,
    )


def fibonacci_positions(n, radius, centre=(0, 0, 0), elevation=(-90.0, 90.0)):
    """n near-uniform points on the spherical band between two elevations (Fibonacci lattice).

    Heights are spaced evenly in z (equal-area bands), azimuths advance by the golden angle.
    """
    z0, z1 = (math.sin(math.radians(e)) for e in elevation)
    return [_on_sphere(centre, radius, z0 + (z1 - z0) * (i + 0.5) / n, i * GOLDEN_ANGLE) for i in range(n)]


def random_positions(n, radius, centre=(0, 0, 0), elevation=(-90.0, 90.0), seed=0):
    """n points uniform by area on the band, reproducible from ``seed``."""
    rng = random.Random(seed)
    z0, z1 = (math.sin(math.radians(e)) for e in elevation)
    return [_on_sphere(centre, radius, rng.uniform(z0, z1), rng.uniform(0, 2 * math.pi)) for _ in range(n)]


def ring_positions(n, radius, centre=(0, 0, 0), elevation=(10.0, 60.0), rings=3):
    """n points on ``rings`` horizontal circles at evenly spaced elevations; rings are offset in azimuth."""
    rings = max(1, min(rings, n))
    elevations = [elevation[0]] if rings == 1 else [
        elevation[0] + (elevation[1] - elevation[0]) * k / (rings - 1) for k in range(rings)]
    per_ring = [n // rings + (1 if k < n % rings else 0) for k in range(rings)]
    out = []
    for k, (elev, count) in enumerate(zip(elevations, per_ring)):
        z = math.sin(math.radians(elev))
        for j in range(count):
            out.append(_on_sphere(centre, radius, z, 2 * math.pi * (j + 0.5 * (k % 2)) / count))
    return out


def spiral_positions(n, radius, centre=(0, 0, 0), elevation=(0.0, 90.0), turns=3.0):
    """n points on a spiral climbing from the lower to the upper elevation over ``turns`` turns."""
    out = []
    for i in range(n):
        t = (i + 0.5) / n
        elev = math.radians(elevation[0] + (elevation[1] - elevation[0]) * t)
        out.append(_on_sphere(centre, radius, math.sin(elev), 2 * math.pi * turns * t))
    return out


def _exit_distance(p, d, lo, hi) -> float:
    """How far the ray p + t d (p inside the box) travels before it leaves the box (lo, hi)."""
    t = float("inf")
    for k in range(3):
        if d[k] > 1e-12:
            t = min(t, (hi[k] - p[k]) / d[k])
        elif d[k] < -1e-12:
            t = min(t, (lo[k] - p[k]) / d[k])
    return t


def _in_box(p, box) -> bool:
    return all(box[0][k] <= p[k] <= box[1][k] for k in range(3))


def inside_poses(n, lo, hi, elevation=INSIDE_ELEVATION, seed=0, obstacles=(), wall_margin=INSIDE_WALL_MARGIN,
                 height_band=INSIDE_HEIGHT_BAND, attempts=200):
    """n (position, unit view direction) pairs for cameras inside the box (lo, hi), looking outward.

    - Positions: uniform (seeded) in the box shrunk by ``wall_margin`` of each horizontal extent, at
      heights within ``height_band`` (fractions of the box height above its floor), so no camera sits
      in a wall, the floor or the ceiling.
    - Directions: azimuths advance by the golden angle from a seeded start (spread evenly over the
      circle, never two alike), elevations are stratified over ``elevation`` (degrees).
    - Each direction gets the first of up to ``attempts`` random positions that is outside every
      obstacle, at least ``0.02 x`` the smaller horizontal extent from the cameras placed so far, and
      sees at least ``0.4 x`` that extent of room ahead before the box's wall (so no camera stares at a
      wall from up close); failing that, the free position seeing the most room.
    - ``obstacles``: (min, max) boxes, e.g. the furniture's bounding boxes. They are padded by 3 % of
      the smaller horizontal extent; a box holding the whole camera region is the room's enclosure
      (one mesh for the walls) and is ignored.
    Raises LayoutError when the box is flat or obstacles leave no room.
    """
    lo, hi = tuple(map(float, lo)), tuple(map(float, hi))
    size = [h - l for l, h in zip(lo, hi)]
    if min(size) <= 0:
        raise LayoutError(f"layout 'inside': the target's box {lo}..{hi} has no volume to stand cameras in")
    lo_e, hi_e = elevation
    if not -90.0 <= lo_e <= hi_e <= 90.0:
        raise LayoutError(f"elevation range [{lo_e}, {hi_e}] must satisfy -90 <= min <= max <= 90 degrees")
    region = ((lo[0] + wall_margin * size[0], lo[1] + wall_margin * size[1], lo[2] + height_band[0] * size[2]),
              (hi[0] - wall_margin * size[0], hi[1] - wall_margin * size[1], lo[2] + height_band[1] * size[2]))
    horiz = min(size[0], size[1])
    pad = 0.03 * horiz
    blockers = []
    for b_lo, b_hi in obstacles:
        b_lo, b_hi = tuple(map(float, b_lo)), tuple(map(float, b_hi))
        if _in_box(region[0], (b_lo, b_hi)) and _in_box(region[1], (b_lo, b_hi)):
            continue  # the enclosure itself
        blockers.append((tuple(v - pad for v in b_lo), tuple(v + pad for v in b_hi)))
    want_free, min_gap = 0.4 * horiz, 0.02 * horiz
    rng = random.Random(seed)
    start = rng.uniform(0.0, 2.0 * math.pi)
    poses = []
    for i in range(n):
        az = start + i * GOLDEN_ANGLE
        el = math.radians(lo_e + (hi_e - lo_e) * (i + rng.random()) / n)
        d = (math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))
        best, best_score = None, -1.0
        for _ in range(attempts):
            p = tuple(rng.uniform(region[0][k], region[1][k]) for k in range(3))
            if any(_in_box(p, b) for b in blockers):
                continue
            spaced = all(math.dist(p, q) >= min_gap for q, _d in poses)
            free = min(_exit_distance(p, d, lo, hi), want_free)
            score = free + (want_free if spaced else 0.0)  # spacing first, then the view ahead
            if score > best_score:
                best, best_score = p, score
            if spaced and free >= want_free:
                break
        if best is None:
            raise LayoutError(f"layout 'inside': every position tried in {region[0]}..{region[1]} is inside an "
                              "object's bounding box; clear the middle of the room or lower the camera count")
        poses.append((best, d))
    return poses


def layout_positions(spec: LayoutSpec, n: int, centre, radius: float):
    """The n positions of a generated layout (not scene-cameras/animation)."""
    elev = spec.elevation_range()
    if spec.layout in ("hemisphere", "sphere"):
        return fibonacci_positions(n, radius, centre, elev)
    if spec.layout == "random":
        return random_positions(n, radius, centre, elev, spec.seed)
    if spec.layout == "rings":
        return ring_positions(n, radius, centre, elev, spec.rings)
    if spec.layout == "spiral":
        return spiral_positions(n, radius, centre, elev, spec.turns)
    raise LayoutError(f"unknown layout {spec.layout!r}; choose one of {', '.join(LAYOUTS)}")


# Share of a generated layout's cameras, the lowest ones, that always train. Only low cameras see the
# sky above the horizon (their top rows look up when a camera's elevation is under half its vertical
# field of view), and the lowest of them see the highest sky. Held out, such a camera shows world
# that no train view does, which no model can learn: on a 100-view hemisphere, 3-9 of 21 held-out
# views had 3-26 % of such pixels (``nerf_core.fields.world_coverage``; the hdri benchmark's view 0 scored
# 12.9 dB there). Keeping the lowest tenth in training leaves none (blender_tests/test_layouts.py).
# Held-out views therefore measure interpolation between train views, as they should.
LOWEST_TRAIN_SHARE = 0.1


def assign_splits(n_total: int, n_val: int, n_test: int, seed: int = 0, heights=None) -> list[str]:
    """Split names for n_total cameras: a seeded shuffle spreads val/test over the whole layout.

    ``heights`` (one z per camera; a generated layout's): the lowest ``LOWEST_TRAIN_SHARE`` of the
    cameras stay in train while enough others remain to hold val and test.
    """
    if min(n_val, n_test) < 0 or n_val + n_test >= n_total:
        raise LayoutError(f"{n_total} cameras cannot hold {n_val} val + {n_test} test views and still train")
    candidates = list(range(n_total))
    if heights is not None:
        keep = math.ceil(LOWEST_TRAIN_SHARE * n_total)
        if n_total - keep >= n_val + n_test:
            lowest = set(sorted(candidates, key=lambda k: (heights[k], k))[:keep])
            candidates = [k for k in candidates if k not in lowest]
    random.Random(seed).shuffle(candidates)
    splits = ["train"] * n_total
    for k, idx in enumerate(candidates[: n_val + n_test]):
        splits[idx] = "val" if k < n_val else "test"
    return splits


def fov_from_lens(focal_length_mm: float, res_x: int, res_y: int, sensor_mm: float = 36.0) -> tuple[float, float]:
    """Horizontal and vertical field of view (radians) of an AUTO-fit camera with square pixels."""
    if res_x >= res_y:
        fov_x = 2 * math.atan(sensor_mm / (2 * focal_length_mm))
        fov_y = 2 * math.atan(math.tan(fov_x / 2) * res_y / res_x)
    else:
        fov_y = 2 * math.atan(sensor_mm / (2 * focal_length_mm))
        fov_x = 2 * math.atan(math.tan(fov_y / 2) * res_x / res_y)
    return fov_x, fov_y


def auto_radius(sphere_radius: float, fov_x: float, fov_y: float, margin: float = 1.05) -> float:
    """Distance at which a sphere of ``sphere_radius`` just fits the narrower field of view."""
    return margin * sphere_radius / math.sin(min(fov_x, fov_y) / 2)


def look_at(position, target, up=(0.0, 0.0, 1.0)):
    """4x4 camera-to-world rows (OpenGL: camera looks along -Z, +Y up) for a camera at ``position``."""
    fwd = [t - p for p, t in zip(position, target)]
    norm = math.sqrt(sum(c * c for c in fwd))
    if norm < 1e-9:
        raise LayoutError("camera position coincides with its target")
    fwd = [c / norm for c in fwd]
    if abs(sum(f * u for f, u in zip(fwd, up))) > 0.999:  # looking straight up/down: any other up works
        up = (0.0, 1.0, 0.0)
    right = [fwd[1] * up[2] - fwd[2] * up[1], fwd[2] * up[0] - fwd[0] * up[2], fwd[0] * up[1] - fwd[1] * up[0]]
    rn = math.sqrt(sum(c * c for c in right))
    right = [c / rn for c in right]
    true_up = [right[1] * fwd[2] - right[2] * fwd[1], right[2] * fwd[0] - right[0] * fwd[2],
               right[0] * fwd[1] - right[1] * fwd[0]]
    back = [-c for c in fwd]
    return [[right[i], true_up[i], back[i], position[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]


# ---------------------------------------------------------------------------------------------
# Blender side: camera objects in their own collection


POSE_TOLERANCE = 1e-5  # matrix entries closer than this (scene units / cosines) count as the same pose


def check_distinct_poses(matrices, layout: str = "") -> None:
    """Refuse (LayoutError naming the cameras) a plan in which two cameras share one pose: the same view
    twice teaches a NeRF nothing, and a held-out copy of a train view measures nothing new.

    The one place every layout passes through before cameras are made (create_cameras). A ring at
    elevation 90, a zero-radius layout, a static camera sampled by "animation" all end here.
    """
    seen = {}
    for k, m in enumerate(matrices):
        rows = [list(r) for r in m]
        key = tuple(round(float(v) / POSE_TOLERANCE) for r in rows[:3] for v in r)
        if key in seen:
            j = seen[key]
            hint = {"rings": "lower the top elevation below 90 degrees or use fewer rings",
                    "animation": "the camera stands still between those frames: raise the frame step or animate it",
                    "scene-cameras": "two of the scene's cameras stand at one place looking the same way"}.get(
                layout, "check the radius (> 0), the elevation range and the camera count")
            raise LayoutError(f"layout {layout!r}: cameras {j} and {k} have the same pose (position "
                              f"{[round(float(r[3]), 4) for r in rows[:3]]}); {hint}")
        seen[key] = k


