"""The design: board, light, scratch tool and views (SPEC sections 2, 3 and 5).

Loaded from TOML into frozen dataclasses. Views may be given by position or by
azimuth/elevation/distance, and ``fov_deg`` may be ``"auto"``; both are resolved at load
time so that every :class:`View` the rest of the code sees has a position and a numeric
field of view.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from scratchfab.errors import ConfigError
from scratchfab.fileio import write_text
from scratchfab.model.schema import (
    check_bounds,
    load_toml,
    parse_table,
    reject_unknown_keys,
    spec,
    to_table,
)

Vec3 = tuple[float, float, float]

#: Tables of a pipeline file that belong to stages, not to the design (SPEC section 5).
STAGE_TABLES = ("pipeline", "optimize", "verify", "toolpath", "export", "stream")

#: Sanity limits: far beyond any engraver, small enough to fail early instead of in numpy.
MAX_SCRATCHES = 10_000_000
MAX_RESOLUTION = 16384
#: Any length or coordinate (1 km): keeps the camera arithmetic far from overflow.
MAX_MM = 1e6
#: A view's vertical field of view lies in (0, MAX_FOV_DEG) degrees.
MAX_FOV_DEG = 170.0
_COORD = spec(ge=-MAX_MM, le=MAX_MM)

_NAME_RE = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]*")  # fullmatch: no "sun\n"
#: Names Windows keeps for devices (with any extension, in any case): no file can have them.
RESERVED_NAME_RE = re.compile(r"^(con|prn|aux|nul|com[1-9]|lpt[1-9])(\..*)?$", re.IGNORECASE)


@dataclass(frozen=True)
class Board:
    """The polished metal board, centred on the origin in the plane z = 0."""

    width_mm: float = field(default=100.0, metadata=spec(gt=0))
    height_mm: float = field(default=100.0, metadata=spec(gt=0))
    # Below 0.005 the renderer's closed form loses accuracy as 1/alpha^4 (render/ndf.py).
    roughness: float = field(default=0.05, metadata=spec(ge=0.005, le=1))
    f0: float = field(default=0.91, metadata=spec(ge=0, le=1))
    margin_mm: float = field(default=2.0, metadata=spec(ge=0))

    def __post_init__(self) -> None:
        check_bounds(self)
        for key in ("width_mm", "height_mm"):
            if getattr(self, key) > MAX_MM:
                raise ValueError(
                    f"{key}: expected at most {MAX_MM:g} mm, got {getattr(self, key):g}"
                )
        if 2 * self.margin_mm >= min(self.width_mm, self.height_mm):
            raise ValueError(
                f"margin_mm ({self.margin_mm}) leaves no room on a "
                f"{self.width_mm} x {self.height_mm} mm board"
            )

    @property
    def half_extent(self) -> tuple[float, float]:
        """Half width and half height in mm."""
        return self.width_mm / 2, self.height_mm / 2


@dataclass(frozen=True)
class Light:
    """The point light."""

    position_mm: Vec3 = field(metadata=_COORD)
    intensity: float = field(default=1.0, metadata=spec(gt=0))

    def __post_init__(self) -> None:
        check_bounds(self)
        if self.position_mm[2] <= 0:
            raise ValueError(
                f"position_mm: the light must be in front of the board (z > 0), "
                f"got z = {self.position_mm[2]}"
            )


#: depth/width of a dent whose profile (eq. 2) resolves in double precision: a flatter one's
#: shape parameter overflows, a deeper one's wall reaches 90 degrees.
DENT_RATIO = (1e-9, 30.0)


def dent_problem(width_mm: float, depth_mm: float) -> str | None:
    """Why a dent of full width ``width_mm`` and depth ``depth_mm`` cannot be modelled, or None."""
    ratio = depth_mm / width_mm
    lo, hi = DENT_RATIO
    if lo <= ratio <= hi:
        return None
    return (
        f"depth/width = {ratio:.3g}: expected {lo:g} to {hi:g} (a dent flatter or deeper "
        "than that has no computable profile, eq. 2)"
    )


@dataclass(frozen=True)
class ScratchTool:
    """The tool's dent and the layout bounds of ``design`` and ``optimize``."""

    width_mm: float = field(default=0.1, metadata=spec(gt=0))
    depth_mm: float = field(default=0.01, metadata=spec(gt=0))
    count: int = field(default=5000, metadata=spec(gt=0, le=MAX_SCRATCHES))
    min_length_mm: float = field(default=2.0, metadata=spec(gt=0))
    max_length_mm: float = field(default=12.0, metadata=spec(gt=0))

    def __post_init__(self) -> None:
        check_bounds(self)
        if (why := dent_problem(self.width_mm, self.depth_mm)) is not None:
            raise ValueError(f"width_mm {self.width_mm:g} and depth_mm {self.depth_mm:g}: {why}")
        if self.min_length_mm > self.max_length_mm:
            raise ValueError(
                f"min_length_mm ({self.min_length_mm}) is larger than "
                f"max_length_mm ({self.max_length_mm})"
            )


@dataclass(frozen=True)
class View:
    """One camera (SPEC section 2) and its target image.

    Either ``position_mm`` or all of ``azimuth_deg``, ``elevation_deg`` and
    ``distance_mm`` are given. Azimuth turns from +z toward +x (positive: the viewer
    stands to the right), elevation from the board's horizontal toward +y, both about
    ``look_at_mm``. ``invert`` turns the target picture's colours negative before it is
    fitted; a transparent ground stays black (:func:`scratchfab.design.images.invert_picture`).
    """

    name: str
    target: str | None = None
    position_mm: Vec3 | None = field(default=None, metadata=_COORD)
    azimuth_deg: float | None = None
    elevation_deg: float | None = None
    distance_mm: float | None = field(default=None, metadata=spec(gt=0))
    look_at_mm: Vec3 = field(default=(0.0, 0.0, 0.0), metadata=_COORD)
    up: Vec3 = field(default=(0.0, 1.0, 0.0), metadata=_COORD)
    fov_deg: float | str = 12.0
    resolution: tuple[int, int] = (256, 256)
    light_position_mm: Vec3 | None = field(default=None, metadata=_COORD)
    invert: bool = False

    def __post_init__(self) -> None:
        check_bounds(self)
        if not _NAME_RE.fullmatch(self.name) or RESERVED_NAME_RE.match(self.name):
            raise ValueError(
                f"name {self.name!r} is not file-name safe (letters, digits, '_', '-', '.'; "
                "not a Windows device name such as con or com1)"
            )
        polar = (self.azimuth_deg, self.elevation_deg, self.distance_mm)
        if self.distance_mm is not None and self.distance_mm > MAX_MM:
            raise ValueError(
                f"view '{self.name}': distance_mm: expected at most {MAX_MM:g} mm, "
                f"got {self.distance_mm:g}"
            )
        if self.position_mm is None and any(v is None for v in polar):
            raise ValueError(
                f"view '{self.name}': give position_mm, or azimuth_deg, elevation_deg "
                "and distance_mm"
            )
        if self.position_mm is not None and any(v is not None for v in polar):
            raise ValueError(
                f"view '{self.name}': give either position_mm or azimuth/elevation/distance, "
                "not both"
            )
        if isinstance(self.fov_deg, str):
            if self.fov_deg != "auto":
                raise ValueError(
                    f"view '{self.name}': fov_deg must be a number or \"auto\", "
                    f"got {self.fov_deg!r}"
                )
        elif not 0 < self.fov_deg < MAX_FOV_DEG:
            raise ValueError(
                f"view '{self.name}': fov_deg must be in (0, {MAX_FOV_DEG:g}), got {self.fov_deg}"
            )
        if min(self.resolution) < 1 or max(self.resolution) > MAX_RESOLUTION:
            raise ValueError(
                f"view '{self.name}': resolution must be two integers in 1..{MAX_RESOLUTION}, "
                f"got {list(self.resolution)}"
            )
        if self.light_position_mm is not None and self.light_position_mm[2] <= 0:
            raise ValueError(
                f"view '{self.name}': light_position_mm must be in front of the board "
                f"(z > 0), got z = {self.light_position_mm[2]}"
            )

    @property
    def width(self) -> int:
        """Image width W in pixels."""
        return self.resolution[0]

    @property
    def height(self) -> int:
        """Image height H in pixels."""
        return self.resolution[1]

    @property
    def camera_position(self) -> np.ndarray:
        """The camera position in mm (only valid on resolved views)."""
        assert self.position_mm is not None
        return np.asarray(self.position_mm, dtype=np.float64)

    @property
    def fov(self) -> float:
        """Numeric vertical field of view in degrees (only valid on resolved views)."""
        assert not isinstance(self.fov_deg, str)
        return float(self.fov_deg)


@dataclass(frozen=True)
class _DesignTables:
    board: Board = Board()
    light: Light | None = None
    scratch: ScratchTool = ScratchTool()
    views: tuple[View, ...] = ()


@dataclass(frozen=True)
class Design:
    """A complete, resolved design.

    Attributes:
        board: The board.
        light: The point light.
        scratch: The tool and layout bounds.
        views: Resolved views (positions and numeric fov filled in).
        base_dir: Folder that relative target paths are resolved against.
        source: The file it came from (for messages).
    """

    board: Board
    light: Light
    scratch: ScratchTool
    views: tuple[View, ...]
    base_dir: Path = Path(".")
    source: str = "<design>"

    def view(self, name: str) -> View:
        """The view called ``name``.

        Raises:
            KeyError: No view has that name.
        """
        for v in self.views:
            if v.name == name:
                return v
        raise KeyError(name)

    def light_for(self, view: View) -> np.ndarray:
        """The light position that applies to ``view`` (its own, or the design's)."""
        pos = (
            view.light_position_mm if view.light_position_mm is not None else self.light.position_mm
        )
        return np.asarray(pos, dtype=np.float64)

    def target_path(self, view: View) -> Path | None:
        """The absolute path of the view's target image, or None."""
        if view.target is None:
            return None
        path = Path(view.target)
        return path if path.is_absolute() else (self.base_dir / path).resolve()

    def with_views(self, views: tuple[View, ...]) -> Design:
        """A copy with other views."""
        return replace(self, views=views)

    def to_toml(self) -> str:
        """The resolved design as TOML text (absolute target paths, every default filled in).

        Views stand by position. A fov that is ``"auto"``'s (:func:`fov_is_auto`) is written
        ``"auto"`` with its number in a comment, so that the file, edited to another board
        or camera position and run again, frames the whole board: a number would keep the
        old frame and crop the new board.
        """
        views = []
        autos = []
        for v in self.views:
            table = to_table(v)
            for key in ("azimuth_deg", "elevation_deg", "distance_mm"):
                table.pop(key, None)
            target = self.target_path(v)
            if target is not None:
                table["target"] = str(target)
            if fov_is_auto(v, self.board):
                table["fov_deg"] = "auto"
                autos.append(v.fov)
            views.append(table)
        data: dict[str, Any] = {
            "board": to_table(self.board),
            "light": to_table(self.light),
            "scratch": to_table(self.scratch),
            "views": views,
        }
        text = _numbers_on_one_line(tomli_w.dumps(data))
        # tomli_w writes no comments: each "auto" gets its number, in the views' order
        fovs = iter(autos)
        board = f"{self.board.width_mm:g} x {self.board.height_mm:g} mm board"
        return _AUTO_FOV_LINE.sub(
            lambda m: f"{m[0]}  # {next(fovs)!r} degrees on this {board}", text
        )

    def save(self, path: str | Path) -> None:
        """Write the resolved design atomically."""
        write_text(path, self.to_toml())


#: A view's ``fov_deg = "auto"`` line as tomli_w writes it (no other key holds "auto").
_AUTO_FOV_LINE = re.compile(r'^fov_deg = "auto"$', re.MULTILINE)

#: An array of numbers as tomli_w writes it: one item per line.
_NUMBER_ARRAY = re.compile(r"\[\n((?:[ \t]+[-+0-9.eEinfa]+,\n)+)\]")


def _numbers_on_one_line(text: str) -> str:
    """``[x, y, z]`` on one line, as a person writes a point (tomli_w spreads it over five)."""

    def join(match: re.Match[str]) -> str:
        items = [item.strip().rstrip(",") for item in match.group(1).splitlines()]
        return "[" + ", ".join(items) + "]"

    return _NUMBER_ARRAY.sub(join, text)


def position_from_polar(
    azimuth_deg: float, elevation_deg: float, distance_mm: float, centre: Vec3 = (0.0, 0.0, 0.0)
) -> Vec3:
    """The point at azimuth, elevation and distance about ``centre``.

    Azimuth turns from +z toward +x (positive: to the right, seen from the front),
    elevation from the board's horizontal toward +y, as a view's keys say.
    """
    az = math.radians(azimuth_deg)
    el = math.radians(elevation_deg)
    cx, cy, cz = centre
    return (
        cx + distance_mm * math.cos(el) * math.sin(az),
        cy + distance_mm * math.sin(el),
        cz + distance_mm * math.cos(el) * math.cos(az),
    )


def polar_from_position(
    position: Vec3, centre: Vec3 = (0.0, 0.0, 0.0)
) -> tuple[float, float, float]:
    """(azimuth_deg, elevation_deg, distance_mm) of ``position`` about ``centre``.

    The inverse of :func:`position_from_polar`.
    """
    x, y, z = (p - c for p, c in zip(position, centre, strict=True))
    azimuth = math.degrees(math.atan2(x, z))
    elevation = math.degrees(math.atan2(y, math.hypot(x, z)))
    return azimuth, elevation, math.sqrt(x * x + y * y + z * z)


def polar_position(view: View) -> Vec3:
    """Camera position from azimuth, elevation and distance about ``look_at_mm``."""
    assert view.azimuth_deg is not None and view.elevation_deg is not None
    assert view.distance_mm is not None
    return position_from_polar(
        view.azimuth_deg, view.elevation_deg, view.distance_mm, view.look_at_mm
    )


def auto_fov(view: View, board: Board, margin: float = 1.08) -> float:
    """The vertical fov (degrees) at which the whole board fills the frame, with a margin."""
    assert view.position_mm is not None
    pos = np.asarray(view.position_mm, dtype=np.float64)
    fwd = np.asarray(view.look_at_mm, dtype=np.float64) - pos
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, np.asarray(view.up, dtype=np.float64))
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    hw, hh = board.half_extent
    corners = np.array([[sx * hw, sy * hh, 0.0] for sx in (-1, 1) for sy in (-1, 1)])
    rel = corners - pos
    depth = rel @ fwd
    if np.any(depth <= 0):
        raise ValueError(f"view '{view.name}': the board is not in front of the camera")
    aspect = view.width / view.height
    ty = np.max(np.abs(rel @ up) / depth)
    tx = np.max(np.abs(rel @ right) / depth) / aspect
    return math.degrees(2 * math.atan(max(ty, tx) * margin))


#: Relative difference of two floats that is rounding: a number written out and read back,
#: or computed again (no one types 15 digits).
SAME_TO_ROUNDING = 1e-12


def same_to_rounding(a: Any, b: Any) -> bool:
    """Whether two trees of values (dicts, lists, tuples) are equal, floats to rounding."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(same_to_rounding(a[k], b[k]) for k in a)
    if isinstance(a, list | tuple) and isinstance(b, list | tuple):
        return len(a) == len(b) and all(map(same_to_rounding, a, b))
    if isinstance(a, float) and isinstance(b, float):
        return math.isclose(a, b, rel_tol=SAME_TO_ROUNDING)
    return bool(a == b)


def fov_is_auto(view: View, board: Board) -> bool:
    """Whether a resolved view's fov is the one ``"auto"`` gives it on ``board``.

    To rounding (:data:`SAME_TO_ROUNDING`): a number that close is ``"auto"``'s, copied from
    a resolved design, so a copy written with ``"auto"`` frames an edited board anew.
    """
    try:
        return math.isclose(view.fov, auto_fov(view, board), rel_tol=SAME_TO_ROUNDING)
    except ValueError:  # the board is not in front of the camera
        return False


def resolve_view(view: View, board: Board) -> View:
    """Fill in the position from polar coordinates and a numeric fov from ``"auto"``."""
    if view.position_mm is None:
        far = max(abs(c) for c in polar_position(view))
        if not far <= MAX_MM:  # else View's position_mm bound names a key the file lacks
            raise ValueError(
                f"view '{view.name}': azimuth_deg, elevation_deg and distance_mm about "
                f"look_at_mm put the camera {far:g} mm from the origin along an axis; "
                f"coordinates are at most {MAX_MM:g} mm"
            )
        view = replace(
            view,
            position_mm=polar_position(view),
            azimuth_deg=None,
            elevation_deg=None,
            distance_mm=None,
        )
    assert view.position_mm is not None
    if view.position_mm[2] <= 0:
        raise ValueError(
            f"view '{view.name}': the camera must be in front of the board (z > 0), "
            f"got z = {view.position_mm[2]:g}"
        )
    fwd = np.subtract(view.look_at_mm, view.position_mm)
    if np.linalg.norm(fwd) == 0:
        raise ValueError(f"view '{view.name}': look_at_mm equals position_mm")
    if np.linalg.norm(np.cross(fwd, view.up)) < 1e-9 * np.linalg.norm(fwd):
        raise ValueError(f"view '{view.name}': up is parallel to the viewing direction")
    if view.fov_deg == "auto":
        fov = auto_fov(view, board)
        if not 0 < fov < MAX_FOV_DEG:
            raise ValueError(f"view '{view.name}': the board cannot fit in the frame")
        view = replace(view, fov_deg=fov)
    return view


#: Range of intensity / (4 d^2), d the light's distance to the board's centre (mm): the
#: scale of every render (SPEC section 4). Dimmer renders underflow float32 (and the
#: optimizer's exposure sum R^2) to zero; brighter ones overflow it.
RADIANCE_SCALE = (1e-14, 1e10)


def light_problem(intensity: float, position: Vec3) -> str | None:
    """Why a light of ``intensity`` at ``position`` cannot be rendered in float32, or None."""
    dist2 = math.fsum(c * c for c in position)
    scale = intensity / (4 * dist2) if dist2 > 0 else math.inf
    lo, hi = RADIANCE_SCALE
    if lo <= scale <= hi:
        return None
    fixes = []
    if 0 < dist2 < math.inf:
        fixes.append(
            f"at this distance an intensity between {lo * 4 * dist2:.3g} and {hi * 4 * dist2:.3g}"
        )
    near, far = math.sqrt(intensity / (4 * hi)), math.sqrt(intensity / (4 * lo))
    if 0 < near and far < math.inf:
        fixes.append(f"for this intensity a distance between {near:.3g} and {far:.3g} mm")
    return (
        f"intensity {intensity:g} at {math.sqrt(dist2):g} mm from the board's centre makes "
        f"renders of about intensity / (4 distance^2) = {scale:.3g}, outside the {lo:g} to "
        f"{hi:g} that float32 renders hold; use "
        + (" or ".join(fixes) or "a finite intensity and light position")
    )


def design_from_mapping(
    data: dict[str, Any], source: str, base_dir: Path, require_views: bool = True
) -> Design:
    """Build a resolved :class:`Design` from parsed TOML; stage tables are left for the pipeline.

    Args:
        data: The tables as ``tomllib`` reads them (``board``, ``light``, ``scratch``,
            ``views``: SPEC section 5, lengths in mm, angles in degrees); a dict built in
            code works alike.
        source: What ``data`` came from, named in every message (a file path, or
            ``"<notebook>"``).
        base_dir: The folder that relative ``target`` paths are read from.
        require_views: Refuse a design without ``[[views]]``.

    Raises:
        ConfigError: Naming ``source`` and the key on any mistake (an unknown key, a
            value out of range, a light or view that cannot work).
    """
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: expected tables (a mapping), got {type(data).__name__}")
    design_data = {k: v for k, v in data.items() if k not in STAGE_TABLES}
    if "design" in design_data and isinstance(design_data["design"], dict):
        raise ConfigError(
            f"{source}: put board, light, scratch and views at the top level, not under [design]"
        )
    reject_unknown_keys(data, [f.name for f in fields(_DesignTables)] + list(STAGE_TABLES), source)
    tables = parse_table(_DesignTables, design_data, source)
    if tables.light is None:
        raise ConfigError(f"{source}: light: missing required table [light]")
    side = min(tables.board.width_mm, tables.board.height_mm)
    for key in ("width_mm", "depth_mm"):
        if getattr(tables.scratch, key) > side:
            raise ConfigError(
                f"{source}: scratch.{key}: expected at most the board's {side:g} mm side, "
                f"got {getattr(tables.scratch, key):g}"
            )
    lights = [("light", tables.light.position_mm)] + [
        (f"views[{i}].light_position_mm", v.light_position_mm)
        for i, v in enumerate(tables.views)
        if v.light_position_mm is not None
    ]
    for key, position in lights:
        if (why := light_problem(tables.light.intensity, position)) is not None:
            raise ConfigError(f"{source}: {key}: {why}")
    if require_views and not tables.views:
        raise ConfigError(f"{source}: views: at least one [[views]] table is required")
    names: set[str] = set()
    resolved = []
    for i, view in enumerate(tables.views):
        # Names that differ only in case name the same files on Windows and macOS disks.
        if view.name.casefold() in names:
            raise ConfigError(
                f"{source}: views[{i}].name: duplicate view name '{view.name}' "
                "(names that differ only in case count as the same)"
            )
        names.add(view.name.casefold())
        try:
            resolved.append(resolve_view(view, tables.board))
        except ValueError as exc:
            raise ConfigError(f"{source}: views[{i}]: {exc}") from None
    return Design(
        board=tables.board,
        light=tables.light,
        scratch=tables.scratch,
        views=tuple(resolved),
        base_dir=base_dir,
        source=source,
    )


def load_design(path: str | Path, require_views: bool = True) -> Design:
    """Load a design file (or the design part of a pipeline file).

    Args:
        path: The TOML file; its folder is the base of relative ``target`` paths.
        require_views: Refuse a design without ``[[views]]``.

    Raises:
        ConfigError: Naming the file and the key on any mistake.
    """
    file = Path(path)
    return design_from_mapping(load_toml(file), str(file), file.resolve().parent, require_views)


#: Design fields that no step depends on: the tool's count (the design stage's; the
#: layout is ``scratches.csv``), a view's name (its key), target picture and its
#: inversion (its ``targets/<view>.npy`` counts) and polar position (resolved into
#: ``position_mm``).
NOT_IN_RUN = frozenset(
    {"count", "name", "target", "invert", "azimuth_deg", "elevation_deg", "distance_mm"}
)


def design_fields(design: Design) -> dict[str, Any]:
    """The design an optimize run's steps depend on, by table as ``design.toml`` holds it.

    Optimize's checkpoints record it (a resume names what changed) and the job's design
    digest hashes it (a rerun that changes nothing here leaves the layout current).

    The renderer's board (size, roughness, f0), light and views (camera, resolution,
    light), the layout's bounds (the board's margin, the tool's lengths) and the tool's
    dent (the scratches' width and depth where ``scratches.csv`` gives none), and the
    views' order (the order of the loss's terms and of ``log.csv``'s columns).
    """

    def table(obj: Any) -> dict[str, Any]:
        return {f.name: getattr(obj, f.name) for f in fields(obj) if f.name not in NOT_IN_RUN}

    return {
        "board": table(design.board),
        "light": table(design.light),
        "scratch": table(design.scratch),
        "views": {v.name: table(v) for v in design.views},
        "view_order": [v.name for v in design.views],
    }
