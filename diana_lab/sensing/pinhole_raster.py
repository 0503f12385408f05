"""The near field of a depth camera's frame, rasterised: terrain cells to the pixels they cover, exactly.

Why it exists: a camera on a rover looks down at the ground just ahead: most of its rays hit within a few metres,
and ray marching them one by one cost most of the frame (each walks from the sensor to its hit, with a
hard-to-predict branch at every cell). Turned around,
the same tests cost less: every terrain cell near the sensor is projected into the image once, and only the pixels
inside its projection test it, with the ray marcher's own arithmetic. The rays that hit nothing there are then
marched from where they leave that region, as before (:func:`diana_lab.sensing.heightfield_kernels.cast_terrain`).

Exact, not approximate: the result is bit for bit the ray marcher's (tested on random poses, worlds with rocks,
maps' edges), because

* a cell is tested on a ray with the marcher's test (:func:`~diana_lab.sensing.heightfield_kernels._crossing`, the
  same plane coefficients and the ray's interval over the cell from the same edge crossings), so a hit has the
  same value, and the nearest of a ray's hits is kept;
* the region is a box of cells that holds the sensor: a convex set, so a ray's segment up to a hit inside it lies
  inside it, and every cell it crosses there has been tested; a ray with no hit in the box is marched from the
  box's edge on;
* the pixels tested are a superset of those whose rays can hit the cell: the bounding box of the projection of the
  cell's four corners (a cell's two triangles lie in their convex hull, whose image is the hull of theirs),
  widened by :data:`MARGIN` pixels (the float32 rays differ from the ideal pinhole by ~1e-5 pixels). Corners
  behind the camera are clipped at a plane ``EPS`` in front of it; no hit is nearer than that, since the raster
  is skipped when terrain around the sensor comes within :data:`DELTA` of its height.

Which cells: the box around the sector the camera sees (optical axis azimuth plus or minus the widest ray angle)
out to :data:`REACH_M`, visited in square rings outward from the sensor's cell, so a pixel whose ray already hit
nearer than a cell's nearest point skips that cell's test. The reach was chosen on timings
(docs/implementation_notes.md).
"""

from __future__ import annotations

import math

import numpy as np

from diana_lab.sensing.heightfield_kernels import _crossing, _guess, _jit, _pose32, _rotate32, _u

__all__ = ["DELTA", "MARGIN", "REACH_CELLS", "REACH_M", "raster_near"]

REACH_M = 4.0  # how far ahead the rasterised box reaches (timed: docs/implementation_notes.md)
REACH_CELLS = 40  # ... and at most this many cells of the narrowest: fine DEMs want a shorter reach
DELTA = 1e-3  # m: no raster when terrain within one cell of the sensor comes this close to its height
MARGIN = 0.01  # pixels added around a cell's projected bounding box


@_jit()
def raster_near(directions, origin, rotation, cam, proj, reach, xs, ys, hs, cell_max):  # pragma: no cover (numba)
    """Nearest terrain hit of every pixel ray within the near box, and the box.

    ``directions (N, 3)`` float32 rover-frame rays of a :class:`~diana_lab.sensing.pinhole.Pinhole` (``proj``
    its ``params``, ``cam`` its ``mount_rotation``), posed by ``rotation``/``origin`` exactly as
    :func:`~diana_lab.sensing.heightfield_kernels.cast_terrain` poses them. Returns
    ``best (N,)`` float64, the hit distance (``inf``: none in the box) and ``box (4,)`` int64, the cell index
    ranges ``ix_lo, ix_hi, iy_lo, iy_hi`` rasterised (empty, ``ix_lo > ix_hi``, when the raster was skipped:
    sensor off the map or as low as the terrain around it).
    """
    n = directions.shape[0]
    best = np.full(n, np.inf)
    box = np.array([0, -1, 0, -1], dtype=np.int64)
    r00, r01, r02, r10, r11, r12, r20, r21, r22, ox, oy, oz = _pose32(origin, rotation)
    nx, ny = xs.shape[0], ys.shape[0]
    ncx, ncy = nx - 1, ny - 1
    x_lo, x_hi, y_lo, y_hi = xs[0], xs[_u(ncx)], ys[0], ys[_u(ncy)]
    if not (x_lo < ox < x_hi and y_lo < oy < y_hi):
        return best, box
    width, height, tan_h, tan_v = int(proj[0]), int(proj[1]), proj[2], proj[3]
    per_mx, per_my = ncx / (x_hi - x_lo), ncy / (y_hi - y_lo)
    ixs = _guess(ox, x_lo, per_mx, 0, ncx - 1)
    while ixs > 0 and xs[_u(ixs)] > ox:
        ixs -= 1
    while ixs < ncx - 1 and xs[_u(ixs + 1)] < ox:
        ixs += 1
    iys = _guess(oy, y_lo, per_my, 0, ncy - 1)
    while iys > 0 and ys[_u(iys)] > oy:
        iys -= 1
    while iys < ncy - 1 and ys[_u(iys + 1)] < oy:
        iys += 1
    top = -np.inf  # the highest corner within one cell of the sensor: no hit is nearer than DELTA below it
    for jy in range(max(iys - 1, 0), min(iys + 1, ncy - 1) + 1):
        for jx in range(max(ixs - 1, 0), min(ixs + 1, ncx - 1) + 1):
            top = max(top, cell_max[_u(jy * ncx + jx)])
    if top >= oz - DELTA:
        return best, box
    eps = 0.5 * DELTA / math.sqrt(1.0 + tan_h * tan_h + tan_v * tan_v)  # < DELTA x cos(widest ray angle)
    # the camera's axes in the world: C = R M, column j = sensor axis j
    c00 = r00 * cam[0, 0] + r01 * cam[1, 0] + r02 * cam[2, 0]
    c10 = r10 * cam[0, 0] + r11 * cam[1, 0] + r12 * cam[2, 0]
    c20 = r20 * cam[0, 0] + r21 * cam[1, 0] + r22 * cam[2, 0]
    c01 = r00 * cam[0, 1] + r01 * cam[1, 1] + r02 * cam[2, 1]
    c11 = r10 * cam[0, 1] + r11 * cam[1, 1] + r12 * cam[2, 1]
    c21 = r20 * cam[0, 1] + r21 * cam[1, 1] + r22 * cam[2, 1]
    c02 = r00 * cam[0, 2] + r01 * cam[1, 2] + r02 * cam[2, 2]
    c12 = r10 * cam[0, 2] + r11 * cam[1, 2] + r12 * cam[2, 2]
    c22 = r20 * cam[0, 2] + r21 * cam[1, 2] + r22 * cam[2, 2]
    # the box: the sensor and the sector it sees (axis azimuth +- the widest ray angle, a little more) to `reach`
    psi = math.atan2(c10, c00)
    alpha = math.atan(math.sqrt(tan_h * tan_h + tan_v * tan_v)) + 0.1
    bx0, bx1, by0, by1 = ox, ox, oy, oy
    for m in range(-4, 5):  # the sector's two edges and the axis directions inside it
        a = m * 0.5 * math.pi
        if m == -4:
            a = psi - alpha
        elif m == 4:
            a = psi + alpha
        elif not (psi - alpha < a < psi + alpha):
            continue
        px, py = ox + reach * math.cos(a), oy + reach * math.sin(a)
        bx0, bx1, by0, by1 = min(bx0, px), max(bx1, px), min(by0, py), max(by1, py)
    ix_lo = max(min(_guess(bx0, x_lo, per_mx, 0, ncx - 1), ixs), 0)
    ix_hi = min(max(_guess(bx1, x_lo, per_mx, 0, ncx - 1), ixs), ncx - 1)
    iy_lo = max(min(_guess(by0, y_lo, per_my, 0, ncy - 1), iys), 0)
    iy_hi = min(max(_guess(by1, y_lo, per_my, 0, ncy - 1), iys), ncy - 1)
    box[0], box[1], box[2], box[3] = ix_lo, ix_hi, iy_lo, iy_hi
    # the rays, posed (the marcher's very values) and the inverses its edge crossings use
    ray = np.empty((n, 5))
    for i in range(n):
        ex, ey, ez = np.float64(directions[i, 0]), np.float64(directions[i, 1]), np.float64(directions[i, 2])
        dx, dy, dz = _rotate32(ex, ey, ez, r00, r01, r02, r10, r11, r12, r20, r21, r22)
        ray[i, 0], ray[i, 1], ray[i, 2] = dx, dy, dz
        ray[i, 3] = 1.0 / dx if dx != 0.0 else 0.0
        ray[i, 4] = 1.0 / dy if dy != 0.0 else 0.0
    # the box's vertices in the camera frame (x, y, z) and, in front of the EPS plane, in the image (col, row)
    nvx, nvy = ix_hi - ix_lo + 2, iy_hi - iy_lo + 2
    vert = np.empty((nvy * nvx, 5))
    half_w, half_h = 0.5 * width, 0.5 * height
    for vy in range(nvy):
        for vx in range(nvx):
            k = vy * nvx + vx
            px, py = xs[_u(ix_lo + vx)] - ox, ys[_u(iy_lo + vy)] - oy
            pz = hs[_u((iy_lo + vy) * nx + ix_lo + vx)] - oz
            qx = c00 * px + c10 * py + c20 * pz
            qy = c01 * px + c11 * py + c21 * pz
            qz = c02 * px + c12 * py + c22 * pz
            vert[k, 0], vert[k, 1], vert[k, 2] = qx, qy, qz
            if qx > eps:
                inv = 1.0 / qx
                vert[k, 3] = (-qy * inv / tan_h + 1.0) * half_w - 0.5
                vert[k, 4] = (-qz * inv / tan_v + 1.0) * half_h - 0.5
    quad = np.empty(4, dtype=np.int64)
    rings = max(ixs - ix_lo, ix_hi - ixs, iys - iy_lo, iy_hi - iys)
    for ring in range(rings + 1):  # square rings of cells around the sensor's, outward
        for iy in range(max(iys - ring, iy_lo), min(iys + ring, iy_hi) + 1):
            whole_row = iy == iys - ring or iy == iys + ring
            ix = ixs - ring
            while ix <= ixs + ring:
                if ix_lo <= ix <= ix_hi:
                    k00 = (iy - iy_lo) * nvx + (ix - ix_lo)
                    quad[0], quad[1], quad[2], quad[3] = k00, k00 + 1, k00 + nvx, k00 + nvx + 1
                    # the cell's image: the bounding box of its corners in front, and of where the segments
                    # between a corner in front and one behind cross the EPS plane
                    n_front = 0
                    c_lo, c_hi, r_lo, r_hi = np.inf, -np.inf, np.inf, -np.inf
                    for a in range(4):
                        ka = quad[a]
                        if vert[ka, 0] > eps:
                            n_front += 1
                            c_lo, c_hi = min(c_lo, vert[ka, 3]), max(c_hi, vert[ka, 3])
                            r_lo, r_hi = min(r_lo, vert[ka, 4]), max(r_hi, vert[ka, 4])
                    if 0 < n_front < 4:
                        for a in range(4):
                            for b in range(a + 1, 4):
                                ka, kb = quad[a], quad[b]
                                if (vert[ka, 0] > eps) != (vert[kb, 0] > eps):
                                    s = (eps - vert[ka, 0]) / (vert[kb, 0] - vert[ka, 0])
                                    qy = vert[ka, 1] + s * (vert[kb, 1] - vert[ka, 1])
                                    qz = vert[ka, 2] + s * (vert[kb, 2] - vert[ka, 2])
                                    cc = (-qy / eps / tan_h + 1.0) * half_w - 0.5
                                    rr = (-qz / eps / tan_v + 1.0) * half_h - 0.5
                                    c_lo, c_hi = min(c_lo, cc), max(c_hi, cc)
                                    r_lo, r_hi = min(r_lo, rr), max(r_hi, rr)
                    if n_front > 0:
                        c_lo, c_hi = max(c_lo - MARGIN, -1.0), min(c_hi + MARGIN, width + 0.0)
                        r_lo, r_hi = max(r_lo - MARGIN, -1.0), min(r_hi + MARGIN, height + 0.0)
                        col0, col1 = max(int(math.ceil(c_lo)), 0), min(int(math.floor(c_hi)), width - 1)
                        row0, row1 = max(int(math.ceil(r_lo)), 0), min(int(math.floor(r_hi)), height - 1)
                        if col0 <= col1 and row0 <= row1:
                            # the marcher's plane coefficients of the cell's triangles (see cast_terrain)
                            kv = iy * nx + ix
                            x0, x1, y0, y1 = xs[_u(ix)], xs[_u(ix + 1)], ys[_u(iy)], ys[_u(iy + 1)]
                            ha, hb = hs[_u(kv)], hs[_u(kv + 1)]
                            hc, hd = hs[_u(kv + nx)], hs[_u(kv + nx + 1)]
                            w, h = x1 - x0, y1 - y0
                            wh = w * h
                            sx, sy = ox - x0, oy - y0
                            p, q = (hb - ha) * h, (hc - ha) * w
                            a_low = (oz - ha) * wh - sx * p - sy * q
                            p2, q2 = (hc - hd) * h, (hb - hd) * w
                            a_up = (oz - hd) * wh + (sx - w) * p2 + (sy - h) * q2
                            g0 = sx * h + sy * w - wh
                            gap_x, gap_y = max(x0 - ox, ox - x1, 0.0), max(y0 - oy, oy - y1, 0.0)
                            # no hit in the cell is nearer (unit rays, to float32 rounding)
                            nearest = math.sqrt(gap_x * gap_x + gap_y * gap_y) * (1.0 - 1e-6)
                            for row in range(row0, row1 + 1):
                                for col in range(col0, col1 + 1):
                                    i = row * width + col
                                    if best[i] <= nearest:
                                        continue
                                    dx, dy, dz = ray[i, 0], ray[i, 1], ray[i, 2]
                                    # the ray's interval over the cell, from the marcher's edge crossings
                                    if dx != 0.0:
                                        ta, tb = (x0 - ox) * ray[i, 3], (x1 - ox) * ray[i, 3]
                                        t_in, t_out = max(0.0, min(ta, tb)), max(ta, tb)
                                    elif x0 <= ox <= x1:
                                        t_in, t_out = 0.0, np.inf
                                    else:
                                        continue
                                    if dy != 0.0:
                                        ta, tb = (y0 - oy) * ray[i, 4], (y1 - oy) * ray[i, 4]
                                        t_in, t_out = max(t_in, min(ta, tb)), min(t_out, max(ta, tb))
                                    elif not (y0 <= oy <= y1):
                                        continue
                                    if t_in > t_out:
                                        continue
                                    b_low = dz * wh - dx * p - dy * q
                                    b_up = dz * wh + dx * p2 + dy * q2
                                    g1 = dx * h + dy * w
                                    hit_low, n_low, d_low = _crossing(a_low, b_low, t_in, t_out, g0, g1, -1.0)
                                    hit_up, n_up, d_up = _crossing(a_up, b_up, t_in, t_out, g0, g1, 1.0)
                                    if hit_low | hit_up:
                                        t_low = n_low / d_low if hit_low else np.inf
                                        t = min(t_low, n_up / d_up if hit_up else np.inf)
                                        if t < best[i]:
                                            best[i] = t
                if whole_row or ix == ixs + ring or ring == 0:
                    ix += 1
                else:  # a side of the ring: from its left cell straight to its right one
                    ix = ixs + ring
    return best, box
