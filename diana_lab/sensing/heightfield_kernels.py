"""The numba kernels of :mod:`diana_lab.sensing.heightfield_cast`: the terrain walk, the obstacle pass and the
rays of a pose (what they do, and why in this shape, is that module's docstring and its ``SPEED`` notes).

Helpers take scalars only: numba does not inline across @njit functions by itself, and passing arrays to even an
inlined helper costs reference counting on every call. No parallel=True: one thread, always. The underscored
helpers are shared with :mod:`diana_lab.sensing.pinhole_raster`, whose near-field raster uses the walk's own tests.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["cast_obstacles", "cast_terrain", "pose_rays"]


def _jit(**options):
    """``numba.njit`` with the compiled code cached on disk: next to this file (``__pycache__``), or in the
    user's cache directory when the package is read-only (numba's own fallback). Where nothing is writable
    numba refuses ``cache=True`` at decoration time; the kernels are then compiled in every process."""

    def wrap(fn):
        try:
            return njit(cache=True, nogil=True, error_model="numpy", **options)(fn)
        except RuntimeError:  # "cannot cache function ...: no locator available"
            return njit(cache=False, nogil=True, error_model="numpy", **options)(fn)

    return wrap


@_jit(inline="always")
def _triangle_t(ox, oy, oz, dx, dy, dz, ax, ay, az, bx, by, bz, cx, cy, cz):  # pragma: no cover (numba)
    """Distance along the ray to triangle ``abc`` (either side), ``inf`` if missed (Moller-Trumbore,
    branch-free: the tests are combined with ``&`` so that they compile to selects)."""
    e1x, e1y, e1z = bx - ax, by - ay, bz - az
    e2x, e2y, e2z = cx - ax, cy - ay, cz - az
    px, py, pz = dy * e2z - dz * e2y, dz * e2x - dx * e2z, dx * e2y - dy * e2x
    det = e1x * px + e1y * py + e1z * pz
    sx, sy, sz = ox - ax, oy - ay, oz - az
    qx, qy, qz = sy * e1z - sz * e1y, sz * e1x - sx * e1z, sx * e1y - sy * e1x
    sign = -1.0 if det < 0.0 else 1.0
    u = (sx * px + sy * py + sz * pz) * sign
    v = (dx * qx + dy * qy + dz * qz) * sign
    w = (e2x * qx + e2y * qy + e2z * qz) * sign  # t * |det|
    adet = det * sign
    hit = (adet != 0.0) & (u >= 0.0) & (v >= 0.0) & (u + v <= adet) & (w > 0.0)
    return w / adet if hit else np.inf


@_jit(inline="always")
def _crossing(a, b, t_in, t_out, g0, g1, side):  # pragma: no cover (numba)
    """Whether a ray ``a + t b`` above a triangle's plane (times the cell's area) crosses it at a ``t`` in
    ``[t_in, t_out]`` on the triangle's ``side`` of the cell's diagonal (-1: ``g0 + t g1 <= 0``, +1: ``>= 0``);
    and that ``t > 0`` as ``n / d``, ``d > 0``. No division: every test is multiplied through by ``|b|``."""
    sign = -1.0 if b < 0.0 else 1.0
    n, d = -a * sign, b * sign
    hit = (d > 0.0) & (n > 0.0) & (n >= t_in * d) & (n <= t_out * d) & ((g0 * d + n * g1) * side >= 0.0)
    return hit, n, d


@_jit(inline="always")
def _slab(o, d, lo, hi, t0, t1):  # pragma: no cover (numba)
    """``[t0, t1]`` narrowed to where ``o + t d`` lies in ``[lo, hi]`` on one axis (empty: ``t0 > t1``)."""
    if d == 0.0:
        if o < lo or o > hi:
            return 1.0, 0.0
        return t0, t1
    ta, tb = (lo - o) / d, (hi - o) / d
    if ta > tb:
        ta, tb = tb, ta
    return max(t0, ta), min(t1, tb)


@_jit(inline="always")
def _guess(p, e_lo, cells_per_m, lo, hi):  # pragma: no cover (numba)
    """First guess of the cell in ``[lo, hi]`` holding coordinate ``p`` on an axis whose edges are (up to
    float32 rounding) ``e_lo + i / cells_per_m``; the caller corrects it against the real edges."""
    g = (p - e_lo) * cells_per_m
    if not g > lo:  # also NaN
        return lo
    return min(int(g), hi)


@_jit(inline="always")
def _u(i):  # pragma: no cover (numba)
    """``i`` as an unsigned index: numba then leaves out the wrap-around of negative indices on every access
    (two or three instructions each, on the walk's every step)."""
    return np.uint64(i)


@_jit(inline="always")
def _pose32(origin, rotation):  # pragma: no cover (numba)
    """A pose's rotation and origin as float32 values (in float64 variables): what the rays carry."""
    f = np.float32
    return (
        np.float64(f(rotation[0, 0])),
        np.float64(f(rotation[0, 1])),
        np.float64(f(rotation[0, 2])),
        np.float64(f(rotation[1, 0])),
        np.float64(f(rotation[1, 1])),
        np.float64(f(rotation[1, 2])),
        np.float64(f(rotation[2, 0])),
        np.float64(f(rotation[2, 1])),
        np.float64(f(rotation[2, 2])),
        np.float64(f(origin[0])),
        np.float64(f(origin[1])),
        np.float64(f(origin[2])),
    )


@_jit(inline="always")
def _rotate32(ex, ey, ez, r00, r01, r02, r10, r11, r12, r20, r21, r22):  # pragma: no cover (numba)
    """``R e`` in float64, rounded to float32 (one rounding: within half an ulp of the exact product)."""
    f = np.float32
    dx = np.float64(f(r00 * ex + r01 * ey + r02 * ez))
    dy = np.float64(f(r10 * ex + r11 * ey + r12 * ez))
    dz = np.float64(f(r20 * ex + r21 * ey + r22 * ez))
    return dx, dy, dz


@_jit()
def pose_rays(directions, origin, rotation, out):  # pragma: no cover (numba)
    """Write the rays of a pose into ``out (N, 6)`` float32 (origin xyz, direction xyz) and return it:
    bit for bit the rays :func:`cast_terrain` and :func:`cast_obstacles` cast for ``(directions, origin,
    rotation)``, for casting the same rays elsewhere (open3d, PyBullet)."""
    r00, r01, r02, r10, r11, r12, r20, r21, r22, pose_x, pose_y, pose_z = _pose32(origin, rotation)
    for i in range(directions.shape[0]):
        ex, ey, ez = np.float64(directions[i, 0]), np.float64(directions[i, 1]), np.float64(directions[i, 2])
        dx, dy, dz = _rotate32(ex, ey, ez, r00, r01, r02, r10, r11, r12, r20, r21, r22)
        out[i, 0], out[i, 1], out[i, 2] = pose_x, pose_y, pose_z
        out[i, 3], out[i, 4], out[i, 5] = dx, dy, dz
    return out


@_jit()
def cast_obstacles(
    rays, origin, rotation, max_range, ob_vertices, ob_triangles, ob_start, ob_box, ob_sphere
):  # pragma: no cover (numba)
    """Nearest obstacle hit of every ray (float64, ``inf`` for none within ``max_range``); the rays as in
    :func:`cast_terrain`."""
    n, n_ob = rays.shape[0], ob_start.shape[0] - 1
    r00 = r01 = r02 = r10 = r11 = r12 = r20 = r21 = r22 = pose_x = pose_y = pose_z = 0.0
    if rotation is not None:  # a pose (None: the rays carry origins and directions); compiled apart
        r00, r01, r02, r10, r11, r12, r20, r21, r22, pose_x, pose_y, pose_z = _pose32(origin, rotation)
    out = np.full(n, np.inf)
    t_lim = max_range * (1.0 + 1e-6) + 1e-6
    near = np.empty(n_ob, dtype=np.int64)  # the obstacles in range of the current ray origin
    n_near, home_x, home_y, home_z = 0, np.nan, np.nan, np.nan
    v = ob_vertices
    for i in range(n):
        if rotation is not None:
            ex, ey, ez = np.float64(rays[i, 0]), np.float64(rays[i, 1]), np.float64(rays[i, 2])
            ox, oy, oz = pose_x, pose_y, pose_z
            dx, dy, dz = _rotate32(ex, ey, ez, r00, r01, r02, r10, r11, r12, r20, r21, r22)
        else:
            ox, oy, oz = np.float64(rays[i, 0]), np.float64(rays[i, 1]), np.float64(rays[i, 2])
            dx, dy, dz = np.float64(rays[i, 3]), np.float64(rays[i, 4]), np.float64(rays[i, 5])
        if not (ox == home_x and oy == home_y and oz == home_z):  # a new sensor position: cull once
            home_x, home_y, home_z, n_near = ox, oy, oz, 0
            for k in range(n_ob):
                cx, cy, cz, r = ob_sphere[k, 0] - ox, ob_sphere[k, 1] - oy, ob_sphere[k, 2] - oz, ob_sphere[k, 3]
                if math.sqrt(cx * cx + cy * cy + cz * cz) - r <= t_lim:
                    near[n_near] = k
                    n_near += 1
        best = np.inf
        for m in range(n_near):
            k = near[m]
            cx, cy, cz, r = ob_sphere[k, 0] - ox, ob_sphere[k, 1] - oy, ob_sphere[k, 2] - oz, ob_sphere[k, 3]
            along = cx * dx + cy * dy + cz * dz
            if along + r < 0.0 or cx * cx + cy * cy + cz * cz - along * along > r * r:
                continue  # the ray's line misses the sphere, or the sphere is behind the origin
            t0, t1 = _slab(ox, dx, ob_box[k, 0], ob_box[k, 3], 0.0, min(t_lim, best))
            t0, t1 = _slab(oy, dy, ob_box[k, 1], ob_box[k, 4], t0, t1)
            t0, t1 = _slab(oz, dz, ob_box[k, 2], ob_box[k, 5], t0, t1)
            if t0 > t1:
                continue
            for j in range(ob_start[k], ob_start[k + 1]):
                a, b, c = ob_triangles[j, 0], ob_triangles[j, 1], ob_triangles[j, 2]
                ax, ay, az, bx, by, bz = v[a, 0], v[a, 1], v[a, 2], v[b, 0], v[b, 1], v[b, 2]
                t = _triangle_t(ox, oy, oz, dx, dy, dz, ax, ay, az, bx, by, bz, v[c, 0], v[c, 1], v[c, 2])
                best = min(best, t)
        out[i] = best
    return out


@_jit()
def cast_terrain(
    rays,
    origin,
    rotation,
    max_range,
    first,
    xs,
    ys,
    hs,
    cell_max,
    block_max,
    block_cols,
    shift,
    z_range,
    lo,
    points,
    mount,
    near_best,
    near_box,
):  # pragma: no cover (numba)
    """Nearest hit of every ray on the terrain, or on an obstacle if ``first[i]`` (obstacle hit distances;
    empty: none) is nearer: ``(N,)`` float32, ``inf`` for no hit within ``max_range``; and how many rows of
    ``points`` were written (0 without it). The rays: ``rays (N,
    6)`` float32 (origin xyz, unit direction xyz), ``origin`` and ``rotation`` None; or a pose, ``rays (N,
    3)`` float32 directions in the body frame rotated by ``rotation (3, 3)`` from ``origin (3,)`` (both
    float64), exactly as :func:`pose_rays` writes them. With ``lo`` (not None), a range (float32) outside
    ``[lo, max_range]`` (compared as float32 values) or no hit comes back as NaN (the sensor's "no return").
    With ``points (N, 3)`` float32 as well (a pose and ``lo`` only) the returns are also written there as the
    sensor's point cloud in the body frame, ``directions[i] * range + mount`` (``mount (3,)`` float32) in
    float32 as numpy computes it, in ray order, each ray to the next free row (a return advances it): the
    frame's cloud without a second pass over the rays. With ``near_best`` (a pose only; None: compiled apart), the
    rays' nearest terrain hits within the cell box ``near_box`` (``ix_lo, ix_hi, iy_lo, iy_hi``) that
    :func:`~diana_lab.sensing.pinhole_raster.raster_near` found (``inf``: none there): a ray with one is done,
    the others are walked from where they leave the box."""
    n = rays.shape[0]
    r00 = r01 = r02 = r10 = r11 = r12 = r20 = r21 = r22 = pose_x = pose_y = pose_z = 0.0
    if rotation is not None:  # a pose (None: the rays carry origins and directions); compiled apart
        r00, r01, r02, r10, r11, r12, r20, r21, r22, pose_x, pose_y, pose_z = _pose32(origin, rotation)
    lo32, hi32 = np.float32(-np.inf), np.float32(max_range)
    if lo is not None:  # None: no window; compiled apart
        lo32 = np.float32(lo)
    out = np.empty(n, dtype=np.float32)
    n_points = 0
    m_x = m_y = m_z = 0.0
    if points is not None:  # None: no cloud; compiled apart
        m_x, m_y, m_z = np.float64(mount[0]), np.float64(mount[1]), np.float64(mount[2])
    has_first = first.shape[0] == n
    t_lim = max_range * (1.0 + 1e-6) + 1e-6  # a hit the caller may keep after rounding to float32 stays
    z_lo, z_hi = z_range[0], z_range[1]
    nx, ny = xs.shape[0], ys.shape[0]
    ncx, ncy = nx - 1, ny - 1
    nbx, nby = block_cols, block_max.shape[0] // block_cols
    x_lo, x_hi, y_lo, y_hi = xs[0], xs[_u(ncx)], ys[0], ys[_u(ncy)]
    per_mx, per_my = ncx / (x_hi - x_lo), ncy / (y_hi - y_lo)  # cells per metre
    # every ray of a frame starts at the sensor: its cell is located once
    home_x, home_y, home_ix, home_iy = np.nan, np.nan, 0, 0
    for i in range(n):
        if rotation is not None:
            ex, ey, ez = np.float64(rays[i, 0]), np.float64(rays[i, 1]), np.float64(rays[i, 2])
            ox, oy, oz = pose_x, pose_y, pose_z
        else:
            ox, oy, oz = np.float64(rays[i, 0]), np.float64(rays[i, 1]), np.float64(rays[i, 2])
            dx, dy, dz = np.float64(rays[i, 3]), np.float64(rays[i, 4]), np.float64(rays[i, 5])
        best = first[i] if has_first else np.inf
        near = np.inf
        if near_best is not None:
            near = near_best[i]
        if near < np.inf:  # the raster found its nearest terrain hit (pinhole_raster): no walk, no world ray
            best = min(best, near)
        else:
            if rotation is not None:
                dx, dy, dz = _rotate32(ex, ey, ez, r00, r01, r02, r10, r11, r12, r20, r21, r22)
            # clip to the map's box, the terrain's height range, the range limit and the obstacle hit
            step_x = 1 if dx > 0.0 else (-1 if dx < 0.0 else 0)
            step_y = 1 if dy > 0.0 else (-1 if dy < 0.0 else 0)
            inv_dx = 1.0 / dx if dx != 0.0 else 0.0
            inv_dy = 1.0 / dy if dy != 0.0 else 0.0
            t0, t1 = 0.0, min(t_lim, best)
            if step_x != 0:
                ta, tb = (x_lo - ox) * inv_dx, (x_hi - ox) * inv_dx
                t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
            elif ox < x_lo or ox > x_hi:
                t1 = -1.0
            if step_y != 0:
                ta, tb = (y_lo - oy) * inv_dy, (y_hi - oy) * inv_dy
                t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
            elif oy < y_lo or oy > y_hi:
                t1 = -1.0
            if dz != 0.0:
                inv_dz = 1.0 / dz
                ta, tb = (z_lo - oz) * inv_dz, (z_hi - oz) * inv_dz
                t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
            elif oz < z_lo or oz > z_hi:
                t1 = -1.0
            if near_best is not None:  # no hit in the rasterised box: the walk starts where the ray leaves it
                t_box = np.inf
                if step_x != 0:
                    t_box = (xs[_u(near_box[1] + 1 if step_x > 0 else near_box[0])] - ox) * inv_dx
                if step_y != 0:
                    t_box = min(t_box, (ys[_u(near_box[3] + 1 if step_y > 0 else near_box[2])] - oy) * inv_dy)
                t0 = max(t0, t_box)
            if t0 <= t1:
                off_x = 1 if step_x > 0 else 0
                off_y = 1 if step_y > 0 else 0
                # the first cell (t0 may sit on the map's edge: clamped into it)
                if t0 == 0.0 and ox == home_x and oy == home_y:
                    ix, iy = home_ix, home_iy
                else:
                    px, py = ox + t0 * dx, oy + t0 * dy
                    ix = _guess(px, x_lo, per_mx, 0, ncx - 1)
                    while ix > 0 and xs[_u(ix)] > px:
                        ix -= 1
                    while ix < ncx - 1 and xs[_u(ix + 1)] < px:
                        ix += 1
                    iy = _guess(py, y_lo, per_my, 0, ncy - 1)
                    while iy > 0 and ys[_u(iy)] > py:
                        iy -= 1
                    while iy < ncy - 1 and ys[_u(iy + 1)] < py:
                        iy += 1
                    if t0 == 0.0:
                        home_x, home_y, home_ix, home_iy = ox, oy, ix, iy
                bx, by = ix >> shift, iy >> shift
                t_enter, z_enter = t0, oz + dz * t0
                # the block DDA: the ray's exits from the current block (its far edges) on either axis
                offb_x = 1 if step_x > 0 else 0
                offb_y = 1 if step_y > 0 else 0
                tbx = (xs[_u(min((bx + offb_x) << shift, ncx))] - ox) * inv_dx if step_x != 0 else np.inf
                tby = (ys[_u(min((by + offb_y) << shift, ncy))] - oy) * inv_dy if step_y != 0 else np.inf
                entered = 0  # how the ray entered the block: 0 first block (ix, iy known), 1 x edge, 2 y edge
                while True:
                    t_exit = min(tbx, tby, t1)
                    z_exit = oz + dz * t_exit
                    if min(z_enter, z_exit) <= block_max[_u(by * nbx + bx)]:
                        # walk this block's cells; test those the ray does not pass above
                        cx0, cy0 = bx << shift, by << shift
                        cx1, cy1 = min(cx0 + (1 << shift), ncx) - 1, min(cy0 + (1 << shift), ncy) - 1
                        if entered == 1:  # through its near x edge: locate the row there (in the block)
                            ix = cx0 if step_x > 0 else cx1
                            py = oy + t_enter * dy
                            iy = _guess(py, y_lo, per_my, cy0, cy1)
                            while iy > cy0 and ys[_u(iy)] > py:
                                iy -= 1
                            while iy < cy1 and ys[_u(iy + 1)] < py:
                                iy += 1
                        elif entered == 2:
                            iy = cy0 if step_y > 0 else cy1
                            px = ox + t_enter * dx
                            ix = _guess(px, x_lo, per_mx, cx0, cx1)
                            while ix > cx0 and xs[_u(ix)] > px:
                                ix -= 1
                            while ix < cx1 and xs[_u(ix + 1)] < px:
                                ix += 1
                        tmax_x = (xs[_u(ix + off_x)] - ox) * inv_dx if step_x != 0 else np.inf
                        tmax_y = (ys[_u(iy + off_y)] - oy) * inv_dy if step_y != 0 else np.inf
                        k = iy * ncx + ix
                        z_prev, t_in = z_enter, t_enter  # the ray's height and t entering the cell
                        hit = False
                        while True:
                            tc = min(tmax_x, tmax_y, t_exit)
                            z_c = oz + dz * tc
                            if min(z_prev, z_c) <= cell_max[_u(k)]:
                                # the cell's triangles (a, b, c) and (d, c, b) of Terrain.mesh, a = (x0, y0),
                                # d = (x1, y1). In [t_in, tc] the ray is over the cell, so it hits a triangle where
                                # it crosses its plane at a t in that interval on the triangle's side of the
                                # diagonal. Heights above the planes times w h are A + t B; the tests multiply
                                # through by |B|, so the branch waits on no division (the division only gives the
                                # distance of a hit).
                                kv = iy * nx + ix
                                x0, x1, y0, y1 = xs[_u(ix)], xs[_u(ix + 1)], ys[_u(iy)], ys[_u(iy + 1)]
                                ha, hb = hs[_u(kv)], hs[_u(kv + 1)]
                                hc, hd = hs[_u(kv + nx)], hs[_u(kv + nx + 1)]
                                w, h = x1 - x0, y1 - y0
                                wh = w * h
                                sx, sy = ox - x0, oy - y0
                                p, q = (hb - ha) * h, (hc - ha) * w
                                a_low, b_low = (oz - ha) * wh - sx * p - sy * q, dz * wh - dx * p - dy * q
                                p, q = (hc - hd) * h, (hb - hd) * w
                                a_up, b_up = (oz - hd) * wh + (sx - w) * p + (sy - h) * q, dz * wh + dx * p + dy * q
                                g0, g1 = sx * h + sy * w - wh, dx * h + dy * w  # diagonal side at t, times w h
                                hit_low, n_low, d_low = _crossing(a_low, b_low, t_in, tc, g0, g1, -1.0)
                                hit_up, n_up, d_up = _crossing(a_up, b_up, t_in, tc, g0, g1, 1.0)
                                if hit_low | hit_up:  # the first cell with a hit holds the nearest one
                                    t_low = n_low / d_low if hit_low else np.inf
                                    best = min(best, t_low, n_up / d_up if hit_up else np.inf)
                                    hit = True
                                    break
                            if tc >= t_exit:
                                break
                            z_prev, t_in = z_c, tc
                            if tmax_x < tmax_y:
                                ix += step_x
                                if ix < cx0 or ix > cx1:
                                    break
                                k += step_x
                                tmax_x = (xs[_u(ix + off_x)] - ox) * inv_dx
                            else:
                                iy += step_y
                                if iy < cy0 or iy > cy1:
                                    break
                                k += step_y * ncx
                                tmax_y = (ys[_u(iy + off_y)] - oy) * inv_dy
                        if hit:
                            break
                    if t_exit >= t1:
                        break
                    # the next block
                    t_enter, z_enter = t_exit, z_exit  # t_exit < t1 here: the nearer of tbx and tby
                    if tbx < tby:
                        bx += step_x
                        if bx < 0 or bx >= nbx:
                            break
                        tbx = (xs[_u(min((bx + offb_x) << shift, ncx))] - ox) * inv_dx
                        entered = 1
                    else:
                        by += step_y
                        if by < 0 or by >= nby:
                            break
                        tby = (ys[_u(min((by + offb_y) << shift, ncy))] - oy) * inv_dy
                        entered = 2
        if lo is None:
            out[i] = best if best <= t_lim else np.inf
        else:
            r = np.float32(best) if best <= t_lim else np.float32(np.inf)
            r = r if r >= lo32 and r <= hi32 else np.float32(np.nan)
            out[i] = r
            if points is not None:
                # float32 product, then float32 sum (each exact in float64 before its one rounding)
                f, rr, j = np.float32, np.float64(r), _u(n_points)
                points[j, 0] = f(np.float64(f(ex * rr)) + m_x)
                points[j, 1] = f(np.float64(f(ey * rr)) + m_y)
                points[j, 2] = f(np.float64(f(ez * rr)) + m_z)
                n_points += not np.isnan(r)
    return out, n_points
