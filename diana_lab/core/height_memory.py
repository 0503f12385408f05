"""A world-frame 2.5-D height map fused over one episode, read back as rover-centred windows.

Why it exists: a policy that sees only its current frame cannot get out of dead ends (an A* oracle that knows only
what lies round the rover now gets stuck where the same oracle with a map of what it has seen does not:
docs/reference_policy.md). The ``elevation_map`` encoding with ``memory: true`` gives the policy that map.

Numpy only: the training encoder (:mod:`diana_lab.sensing.encoders`) and the onboard runtime
(:mod:`diana_lab.deploy.encoding`) share this class, so the map a policy was trained on and the map it
drives with are built by the same code.

The map is a square of ``2 * radius`` centred on the first pose of the episode (no world bounds needed, so
it works the same on a rover). Each update writes, for every cell the frame hit, the highest point of that
frame: the latest frame wins, so a spurious return (dust) is overwritten when the cell is seen again,
instead of sticking as a maximum would. Points outside the square are dropped; window cells outside it
are unknown. With ``mean=True`` a second layer, :attr:`HeightMemory.mean_height`, holds each cell's mean of every
return it has had this episode (the relief check's input, :mod:`diana_lab.shield.relief`): pooled over the frames, not
the latest frame's, since the mean averages noise out where the highest return is biased up by it.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["HeightMemory", "window_offsets"]


def window_offsets(cell_size: float, rows: int, cols: int, extent_forward: float, extent_side: float) -> np.ndarray:
    """``(rows * cols, 2)`` centres of the window's cells in the heading-aligned frame (x forward, y left),
    row-major: row 0 lies ``extent_forward`` ahead of the rover, column 0 ``extent_side`` to its left."""
    ahead = extent_forward - (np.arange(rows) + 0.5) * cell_size
    left = extent_side - (np.arange(cols) + 0.5) * cell_size
    return np.stack(np.meshgrid(ahead, left, indexing="ij"), axis=-1).reshape(-1, 2)


class HeightMemory:
    """``update`` with world-frame points, ``window`` for the grid around a pose; ``reset`` per episode.

    Args:
        cell_size: edge of a map cell and of a window cell (m).
        radius: half-width of the square the map covers around the episode's first pose (m).
        rows, cols: the window's shape; row 0 lies ``extent_forward`` ahead of the rover, column 0
            ``extent_side`` to its left (the layout of the ``elevation_map`` encoding).
        extent_forward, extent_side: see ``rows, cols``.
    """

    def __init__(
        self,
        cell_size: float,
        radius: float,
        rows: int,
        cols: int,
        extent_forward: float,
        extent_side: float,
        mean: bool = False,
    ) -> None:
        if not cell_size > 0 or not radius > 0:
            raise ValueError(f"HeightMemory: expected a positive cell_size and radius, got {cell_size}, {radius}")
        self.cell_size, self.radius = float(cell_size), float(radius)
        self.n = max(1, math.ceil(2.0 * radius / cell_size))
        self.height = np.full(self.n * self.n, np.nan, dtype=np.float32)  # world z; NaN = never seen
        self.origin: np.ndarray | None = None  # world xy of the map's corner (set by the first update)
        self.last_world: np.ndarray | None = None  # the world points of the latest fuse()
        self._top = np.full(self.n * self.n, -np.inf, dtype=np.float32)  # scratch, back to -inf after use
        # with ``mean``: also each cell's mean of every return it has had this episode (what the shield's relief
        # check judges: the highest return is biased up by range noise, and pooling the frames averages it out);
        # None without
        self.mean_height: np.ndarray | None = np.full(self.n * self.n, np.nan, dtype=np.float32) if mean else None
        self._sum = np.zeros(self.n * self.n if mean else 0)
        self._count = np.zeros(self.n * self.n if mean else 0, dtype=np.int64)
        self._offsets = window_offsets(cell_size, rows, cols, extent_forward, extent_side)
        self.shape = (rows, cols)

    def reset(self) -> None:
        """Forget everything: a new episode (a new goal on a rover) starts with an empty map."""
        self.height.fill(np.nan)
        if self.mean_height is not None:
            self.mean_height.fill(np.nan)
            self._sum.fill(0.0)
            self._count.fill(0)
        self.origin = None

    def _cells(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Flat cell index of world points (meaningful only where they lie on the map) and whether they do."""
        inv, n = 1.0 / self.cell_size, self.n
        fx = np.floor((x - self.origin[0]) * inv)  # whole numbers as floats: one conversion to int at the end
        fy = np.floor((y - self.origin[1]) * inv)
        inside = (fx >= 0) & (fx < n) & (fy >= 0) & (fy < n)
        return (fy * n + fx).astype(np.int64), inside

    def update(self, points: np.ndarray, centre: np.ndarray) -> None:
        """Fuse one frame: ``points`` ``(N, 3)`` in the world frame; ``centre`` the rover's world xy (it
        centres the map on the first update of an episode)."""
        if self.origin is None:
            self.origin = np.asarray(centre, dtype=np.float64)[:2] - self.radius
        if len(points) == 0:
            return
        cell, inside = self._cells(points[:, 0], points[:, 1])
        z = points[:, 2]
        if not inside.all():  # usually all are: the map reaches far beyond the sensor
            keep = np.flatnonzero(inside)
            cell, z = cell.take(keep), z.take(keep)
        np.maximum.at(self._top, cell, z.astype(np.float32, copy=False))  # this frame's highest point per cell
        # repeated cells all copy the same maximum, so no np.unique (a third of the update's time)
        self.height[cell] = self._top[cell]
        self._top[cell] = -np.inf
        if self.mean_height is not None and len(cell):
            lo = int(cell.min())  # counted over the span of cells the frame hit, not the whole map
            total = np.bincount(cell - lo, weights=z)
            hits = np.bincount(cell - lo)
            seen = np.flatnonzero(hits)
            total, hits, seen = total[seen], hits[seen], seen + lo
            self._sum[seen] += total
            self._count[seen] += hits
            self.mean_height[seen] = self._sum[seen] / self._count[seen]

    def heights_at(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The map's heights at world points ``x, y`` (same shape) and whether each point's cell was hit.

        Bilinear between the centres of the four surrounding cells when all are known, else the height of the
        point's own cell; NaN where that cell is unknown (or off the map)."""
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        if self.origin is None:
            return np.full(x.shape, np.nan), np.zeros(x.shape, dtype=bool)
        n, size, flat = self.n, self.cell_size, self.height  # flat [iy * n + ix], float32
        # per axis, in whole numbers held as floats (few array operations: this runs on every shield decision;
        # each costs ~1 us whatever its size)
        fx, fy = (x - self.origin[0]) / size, (y - self.origin[1]) / size  # in cells
        ix, iy = np.floor(fx), np.floor(fy)
        ux, uy = fx - 0.5, fy - 0.5  # cell-centre coordinates
        jx, jy = np.floor(ux), np.floor(uy)
        tx, ty = ux - jx, uy - jy
        last, corner_last = n - 1, max(n - 2, 0)
        # clamped onto the map (fmax: NaN -> 0); a point is on it where clamping left it alone
        cx, cy = np.fmin(np.fmax(ix, 0), last), np.fmin(np.fmax(iy, 0), last)
        kx, ky = np.fmin(np.fmax(jx, 0), corner_last), np.fmin(np.fmax(jy, 0), corner_last)
        inside = (cx == ix) & (cy == iy)
        own_cell, corner = cy * n + cx, ky * n + kx
        step = min(1, n - 1)  # the next cell right (and a row up: step * n); none on a 1-cell map
        # one gather, widening only the cells read: the point's own cell and the four around it
        cells = np.stack([own_cell, corner, corner + step, corner + step * n, corner + step * n + step])
        h = flat.take(cells.astype(np.int64)).astype(np.float64)
        own = np.where(inside, h[0], np.nan)
        sx = 1 - tx
        bilinear = (1 - ty) * (sx * h[1] + tx * h[2]) + ty * (sx * h[3] + tx * h[4])
        known = np.isfinite(own)
        # bilinear where all four centres around lie on the map and are known (and the point's own cell is)
        use = (kx == jx) & (ky == jy) & np.isfinite(bilinear) & known if n > 1 else np.zeros(x.shape, dtype=bool)
        return np.where(use, bilinear, own), known

    def peaks_at(self, x: np.ndarray, y: np.ndarray, min_known: int = 7, rank: int = 0) -> np.ndarray:
        """How far the cell under each world point stands above its 8 neighbours (m; same shape): above their
        median (``rank`` 0) or above the ``rank``-th highest of them (1..8), counting only the known ones.

        Raw cells, not :meth:`heights_at`'s bilinear heights, which smear a rock one or two cells wide over the
        ground around it. 0 where the point's cell is unknown, on the map's edge, or has fewer than
        ``min_known`` known neighbours: a cell beside unseen ground (a shadow) has no ground to be judged
        against. A slope has neighbours on both sides of the cell's height; a ridge has two along it at its own
        height (so ``rank`` 2 never flags one, while the median may); a rock has none."""
        if not (1 <= int(min_known) <= 8 and 0 <= int(rank) <= 8):
            raise ValueError(
                f"HeightMemory.peaks_at: expected min_known in 1..8 and rank in 0..8, got {min_known}, {rank}"
            )
        x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        if self.origin is None or self.n < 3:
            return np.zeros(x.shape)
        n = self.n
        ix = np.floor((x - self.origin[0]) / self.cell_size)
        iy = np.floor((y - self.origin[1]) / self.cell_size)
        inner = (ix >= 1) & (ix <= n - 2) & (iy >= 1) & (iy <= n - 2)
        cell = (np.where(inner, iy, 1) * n + np.where(inner, ix, 1)).astype(np.int64).ravel()
        around = cell[None, :] + np.array([-n - 1, -n, -n + 1, -1, 1, n - 1, n, n + 1])[:, None]  # (8, K)
        ring = np.sort(self.height.take(around).astype(np.float64), axis=0)  # NaN (unknown) sorts last
        known = np.isfinite(ring).sum(axis=0)
        cols = np.arange(ring.shape[1])
        if rank == 0:  # the median of the known (garbage where none is: not judged below)
            reference = 0.5 * (ring[np.maximum(known - 1, 0) // 2, cols] + ring[known // 2, cols])
        else:  # the rank-th highest known (ascending order, NaN last); fewer known than rank: not judged below
            reference = ring[np.maximum(known - rank, 0), cols]
        own = self.height.take(cell).astype(np.float64)
        with np.errstate(invalid="ignore"):
            peak = own - reference
        judged = inner.ravel() & np.isfinite(own) & (known >= max(int(min_known), int(rank), 1))
        return np.where(judged, peak, 0.0).reshape(x.shape)

    def roughness_near(self, x: float, y: float, reach: int, min_blocks: int = 20) -> float:
        """How rough the mapped ground is around world ``(x, y)`` (m), judged on blocks of 2 x 2 cells (their
        known cells' mean height): the median, over the blocks within ``reach`` blocks of the point's cell (a
        square), of how far a block lies from the mean of its 4 neighbours.

        That residual is 0 on any plane, so slopes do not count; the median ignores the few blocks a rock covers,
        so a rock on smooth ground leaves the ground smooth; and the blocks' means damp the range noise each cell's
        highest return carries (on the validation worlds with ``sensor.noise=realistic``, single cells read the
        craters' median 2.2 -> 4.8 mm and blocks 2.8 -> 3.6 mm, the yard's staying above 5 mm either way). NaN
        where fewer than ``min_blocks`` blocks have themselves and their 4 neighbours known, or off the map."""
        if reach < 1 or min_blocks < 1:
            raise ValueError(
                f"HeightMemory.roughness_near: expected reach >= 1 and min_blocks >= 1, got {reach}, {min_blocks}"
            )
        if self.origin is None:
            return math.nan
        n = self.n
        ix = math.floor((x - self.origin[0]) / self.cell_size)
        iy = math.floor((y - self.origin[1]) / self.cell_size)
        if not (0 <= ix < n and 0 <= iy < n):
            return math.nan
        span = 2 * reach + 2  # cells either side: the reach in blocks, and a block of neighbours beyond it
        win = self.height.reshape(n, n)[max(iy - span, 0) : iy + span, max(ix - span, 0) : ix + span]
        rows, cols = win.shape[0] // 2, win.shape[1] // 2
        if rows < 3 or cols < 3:
            return math.nan
        cells = win[: 2 * rows, : 2 * cols].astype(np.float64)
        known = np.isfinite(cells)
        z, k = np.where(known, cells, 0.0), known.view(np.int8)
        # the four cells of each block by strided views (faster than a 4-D reshape and sum; four float32 heights
        # add up exactly in float64 unless their sizes differ over 10^8-fold, so the order of the sum rarely matters)
        total = z[0::2, 0::2] + z[0::2, 1::2] + z[1::2, 0::2] + z[1::2, 1::2]
        count = k[0::2, 0::2] + k[0::2, 1::2] + k[1::2, 0::2] + k[1::2, 1::2]
        with np.errstate(invalid="ignore"):
            block = total / count  # NaN where none of the four is known
            residual = np.abs(
                block[1:-1, 1:-1] - 0.25 * (block[:-2, 1:-1] + block[2:, 1:-1] + block[1:-1, :-2] + block[1:-1, 2:])
            )
        judged = residual[np.isfinite(residual)]
        return float(np.median(judged)) if len(judged) >= min_blocks else math.nan

    @staticmethod
    def to_world(levelled: np.ndarray, position: np.ndarray, yaw: float) -> np.ndarray:
        """Points in the heading-aligned, gravity-up frame at the rover base -> the world frame (same dtype).

        The rounding is spelt out, whatever types the caller's position holds (a simulator's float64 array, a
        rover's tuple of Python floats): the turn in the points' precision, the shift in float64, then one
        rounding back; the batched env's compiled encoder does the same, so all three place a return in the same
        cell."""
        c, s = math.cos(yaw), math.sin(yaw)
        dtype = levelled.dtype
        c, s = dtype.type(c), dtype.type(s)
        x, y, z = (np.float64(v) for v in (position[0], position[1], position[2]))
        world = np.empty_like(levelled)
        world[:, 0] = (c * levelled[:, 0] - s * levelled[:, 1]).astype(np.float64) + x
        world[:, 1] = (s * levelled[:, 0] + c * levelled[:, 1]).astype(np.float64) + y
        world[:, 2] = levelled[:, 2].astype(np.float64) + z
        return world

    def fuse(self, levelled: np.ndarray, position: np.ndarray, yaw: float) -> np.ndarray:
        """One frame of an ``elevation_map`` encoder: ``levelled`` points ``(N, 3)`` in the heading-aligned,
        gravity-up frame at the rover base, the base's world ``position`` (x, y, z) and ``yaw``. Updates the
        map and returns the window around the rover, flat, heights relative to the base, ``-inf`` unknown."""
        xy = np.array([position[0], position[1]], dtype=np.float64)
        self.last_world = self.to_world(levelled, position, yaw)  # the onboard slope shield maps these too
        self.update(self.last_world, xy)
        top = self.window(xy, yaw, float(position[2])).reshape(-1)
        top[np.isnan(top)] = -np.inf
        return top

    def window(self, xy: np.ndarray, yaw: float, base_z: float) -> np.ndarray:
        """``(rows, cols)`` heights relative to ``base_z`` around world ``xy``, heading ``yaw``; NaN unknown."""
        rows, cols = self.shape
        if self.origin is None:
            return np.full((rows, cols), np.nan, dtype=np.float32)
        c, s = math.cos(yaw), math.sin(yaw)
        dx, dy = self._offsets[:, 0], self._offsets[:, 1]
        cell, inside = self._cells(xy[0] + c * dx - s * dy, xy[1] + s * dx + c * dy)
        out = np.full(rows * cols, np.nan, dtype=np.float32)
        out[inside] = self.height[cell[inside]] - np.float32(base_z)
        return out.reshape(rows, cols)
