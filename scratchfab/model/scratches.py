"""Scratch layouts: the CSV file of SPEC section 5 as numpy arrays in mm."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from scratchfab.errors import ConfigError
from scratchfab.fileio import read_input, write_text
from scratchfab.model.design import Board, ScratchTool, dent_problem

REQUIRED_COLUMNS = ("x0", "y0", "x1", "y1")
OPTIONAL_COLUMNS = ("width", "depth")
#: How far beyond the board a scratch file's end may lie (rounding in the file), in mm.
ON_BOARD_TOLERANCE_MM = 1e-6


@dataclass(frozen=True, eq=False)
class ScratchSet:
    """N straight scratches on the board.

    Attributes:
        p0: (N, 2) float64 start points in mm.
        p1: (N, 2) float64 end points in mm.
        width: (N,) full dent widths 2w in mm.
        depth: (N,) dent depths d in mm.
    """

    p0: np.ndarray
    p1: np.ndarray
    width: np.ndarray
    depth: np.ndarray

    def __post_init__(self) -> None:
        for name in ("p0", "p1", "width", "depth"):
            # float64 arrays as they are (no copy); lists and other dtypes converted
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=np.float64))
        n = len(self.p0)
        if self.p0.shape != (n, 2) or self.p1.shape != (n, 2):
            raise ValueError(
                f"p0 and p1 must both be (N, 2), got shapes {self.p0.shape} and {self.p1.shape}"
            )
        if self.width.shape != (n,) or self.depth.shape != (n,):
            raise ValueError(
                f"width and depth must be ({n},), got shapes {self.width.shape} and "
                f"{self.depth.shape} (ScratchSet.from_arrays broadcasts one value)"
            )

    def __len__(self) -> int:
        return len(self.p0)

    @classmethod
    def from_arrays(
        cls,
        p0: np.ndarray,
        p1: np.ndarray,
        width: float | np.ndarray,
        depth: float | np.ndarray,
    ) -> ScratchSet:
        """Build a set from end points in mm, broadcasting scalar width and depth.

        Args:
            p0: (N, 2) start points x, y in mm (board frame, SPEC section 2); one point
                (2,) stands for N = 1.
            p1: (N, 2) end points, as ``p0``.
            width: Full dent width 2w in mm, one for all or (N,).
            depth: Dent depth d in mm, one for all or (N,).

        Raises:
            ValueError: Arrays of other shapes (a (2, N) array of x and y rows among them).
        """
        ends = []
        for name, value in (("p0", p0), ("p1", p1)):
            arr = np.asarray(value, dtype=np.float64)
            if arr.shape == (2,):
                arr = arr.reshape(1, 2)
            if arr.ndim != 2 or arr.shape[1] != 2:
                raise ValueError(f"{name}: expected (N, 2) points x, y, got shape {arr.shape}")
            ends.append(arr.copy())
        if len(ends[0]) != len(ends[1]):
            raise ValueError(
                f"p0 and p1 must both be (N, 2): {len(ends[0])} and {len(ends[1])} points"
            )
        n = len(ends[0])
        sizes = []
        for name, size in (("width", width), ("depth", depth)):
            values = np.asarray(size, dtype=np.float64)
            if values.shape not in ((), (1,), (n,)):
                raise ValueError(f"{name}: expected one value or ({n},), got shape {values.shape}")
            sizes.append(np.broadcast_to(values, (n,)).copy())
        return cls(ends[0], ends[1], sizes[0], sizes[1])

    @property
    def lengths(self) -> np.ndarray:
        """Scratch lengths L in mm."""
        return np.linalg.norm(self.p1 - self.p0, axis=1)

    def subset(self, index: np.ndarray) -> ScratchSet:
        """The scratches selected by an index or mask."""
        return ScratchSet(self.p0[index], self.p1[index], self.width[index], self.depth[index])

    def to_csv(self, tool: ScratchTool | None = None) -> str:
        """CSV text; width/depth columns are written unless they all equal ``tool``'s."""
        uniform = tool is not None and bool(
            np.all(self.width == tool.width_mm) and np.all(self.depth == tool.depth_mm)
        )
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(REQUIRED_COLUMNS if uniform else REQUIRED_COLUMNS + OPTIONAL_COLUMNS)
        for i in range(len(self)):
            row = [*self.p0[i], *self.p1[i]]
            if not uniform:
                row += [self.width[i], self.depth[i]]
            writer.writerow([repr(float(v)) for v in row])
        return buf.getvalue()

    def save(self, path: str | Path, tool: ScratchTool | None = None) -> None:
        """Write the CSV atomically."""
        write_text(path, self.to_csv(tool))


def load_scratches(
    path: str | Path,
    tool: ScratchTool,
    board: Board | None = None,
    tolerance_mm: float = ON_BOARD_TOLERANCE_MM,
) -> ScratchSet:
    """Read a scratch CSV (SPEC section 5), checking every row.

    Args:
        path: The CSV file.
        tool: Supplies width and depth where the file has no such columns.
        board: When given, every endpoint must lie on the board.
        tolerance_mm: Slack for the on-board check (rounding in the file).

    Raises:
        ConfigError: Naming the file, the row (1 = first data row, as a spreadsheet shows
            it: line number in the file) and what is wrong.
    """
    file = Path(path)
    try:
        text = read_input(file, "a CSV file").decode("utf-8-sig")  # a BOM (Excel's) is dropped
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{file}: cannot read as UTF-8 text ({exc})") from None
    reader = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise ConfigError(
            f"{file}: empty file, expected a header x0,y0,x1,y1[,width,depth]"
        ) from None
    except csv.Error as exc:
        raise ConfigError(f"{file}: line 1: not CSV ({exc})") from None
    missing = [c for c in REQUIRED_COLUMNS if c not in header]
    unknown = [c for c in header if c not in REQUIRED_COLUMNS + OPTIONAL_COLUMNS]
    if missing or unknown:
        raise ConfigError(
            f"{file}: line 1: header must be x0,y0,x1,y1 optionally followed by width,depth; "
            + (f"missing {', '.join(missing)}" if missing else f"unknown column {unknown[0]!r}")
        )
    col = {name: header.index(name) for name in header}
    rows: list[list[float]] = []
    side = None if board is None else min(board.width_mm, board.height_mm)
    for line_no, row in enumerate(_rows(reader, file), start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != len(header):
            raise ConfigError(
                f"{file}: line {line_no}: expected {len(header)} values, got {len(row)}"
            )
        values = []
        for name in REQUIRED_COLUMNS + OPTIONAL_COLUMNS:
            if name not in col:
                values.append(tool.width_mm if name == "width" else tool.depth_mm)
                continue
            cell = row[col[name]].strip()
            try:
                v = float(cell)
            except ValueError:
                raise ConfigError(
                    f"{file}: line {line_no}: column {name}: expected a number, got {cell!r}"
                ) from None
            if not math.isfinite(v):
                raise ConfigError(
                    f"{file}: line {line_no}: column {name}: expected a finite number, got {cell}"
                )
            if name in OPTIONAL_COLUMNS and (v <= 0 or (side is not None and v > side)):
                bound = "" if side is None else f" at most the board's {side:g} mm side"
                raise ConfigError(
                    f"{file}: line {line_no}: column {name}: expected a positive size{bound}, "
                    f"got {v}"
                )
            values.append(v)
        if (why := dent_problem(values[4], values[5])) is not None:
            raise ConfigError(f"{file}: line {line_no}: columns width and depth: {why}")
        x0, y0, x1, y1 = values[:4]
        if x0 == x1 and y0 == y1:
            raise ConfigError(f"{file}: line {line_no}: scratch has zero length")
        if board is not None:
            hw, hh = board.half_extent
            for px, py in ((x0, y0), (x1, y1)):
                if abs(px) > hw + tolerance_mm or abs(py) > hh + tolerance_mm:
                    raise ConfigError(
                        f"{file}: line {line_no}: scratch leaves the board: point ({px:g}, {py:g}) "
                        f"is outside |x| <= {hw:g}, |y| <= {hh:g} mm"
                    )
        rows.append(values)
    data = np.asarray(rows, dtype=np.float64).reshape(-1, 6)
    return ScratchSet(
        data[:, 0:2].copy(), data[:, 2:4].copy(), data[:, 4].copy(), data[:, 5].copy()
    )


def _rows(reader: Iterator[list[str]], file: Path) -> Iterator[list[str]]:
    """The CSV rows after the header; a cell Python's csv cannot read is named by its line."""
    while True:
        try:
            yield next(reader)
        except StopIteration:
            return
        except csv.Error as exc:
            line = getattr(reader, "line_num", "?")
            raise ConfigError(f"{file}: line {line}: not CSV ({exc})") from None
