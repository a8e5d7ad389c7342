"""Compiled loops (numba) behind :mod:`scenelabel.query.baked` and the dense-grid encoding
(:func:`scenelabel.fields.encodings.trilinear_from_grid`), one point or one ray at a time, no
allocation inside the loops. Imported on first use (importing numba takes a while).

A lattice is read through ``frame`` = (corner x, y, z, 1 / spacing): vertex ``[i, j, k]`` sits at
``corner + spacing * (i, j, k)``. Arithmetic is float64 whatever the lattice's dtype.

Points land anywhere in a lattice of megabytes, so reading their cells' corners waits on memory:
:func:`points_kernel` asks for the corners of the point PREFETCH_AHEAD rows on while it blends the
current one (:func:`prefetch`, LLVM's prefetch intrinsic), which keeps several reads in flight.
"""

from __future__ import annotations

import math

import numpy as np
from llvmlite import ir
from numba import njit
from numba.core import cgutils, types
from numba.extending import intrinsic

from scenelabel.maps.raycast_kernels import MIN_ROWS_PER_THREAD, in_threads  # noqa: F401 (the split over threads, shared)
from scenelabel.render.constants import OPACITY_EPS

PREFETCH_AHEAD = 16
""":func:`points_kernel` prefetches the lattice corners of the point this many rows ahead."""


@intrinsic
def prefetch(typingctx, array, flat_index):  # pragma: no cover - compiled
    """Hint the CPU to fetch the cache line of ``array[flat_index]`` (a C-contiguous 1-D array; no
    bounds check, none needed: a prefetch never faults) for reading; nothing else happens."""

    def codegen(context, builder, signature, args):
        array_type = signature.args[0]
        data = context.make_array(array_type)(context, builder, args[0])
        pointer = cgutils.get_item_pointer(context, builder, array_type, data, [args[1]], wraparound=False)
        byte_pointer = ir.IntType(8).as_pointer()
        i32 = ir.IntType(32)
        function = builder.module.declare_intrinsic(
            "llvm.prefetch", [byte_pointer], ir.FunctionType(ir.VoidType(), [byte_pointer, i32, i32, i32])
        )
        # read (0), high temporal locality (3), data cache (1)
        flags = [ir.Constant(i32, 0), ir.Constant(i32, 3), ir.Constant(i32, 1)]
        builder.call(function, [builder.bitcast(pointer, byte_pointer), *flags])
        return context.get_dummy_value()

    return types.void(array, flat_index), codegen


@njit(cache=True, nogil=True)
def cell_weights(shape, frame, px, py, pz, ijk, w):  # pragma: no cover - compiled
    """World point -> the first vertex ijk[:3] of its lattice cell and the cell's 8 trilinear
    weights w[:8] (corner order: bit 2 +x, bit 1 +y, bit 0 +z). False when the point lies outside
    a lattice of ``shape`` vertices per axis (or is NaN); the last vertex belongs to the last cell."""
    x = (px - frame[0]) * frame[3]
    y = (py - frame[1]) * frame[3]
    z = (pz - frame[2]) * frame[3]
    if not (0.0 <= x <= shape[0] - 1 and 0.0 <= y <= shape[1] - 1 and 0.0 <= z <= shape[2] - 1):
        return False
    i, j, k = min(int(x), shape[0] - 2), min(int(y), shape[1] - 2), min(int(z), shape[2] - 2)
    ijk[0], ijk[1], ijk[2] = i, j, k
    fx, fy, fz = x - i, y - j, z - k
    gx, gy, gz = 1.0 - fx, 1.0 - fy, 1.0 - fz
    w[0], w[1], w[2], w[3] = gx * gy * gz, gx * gy * fz, gx * fy * gz, gx * fy * fz
    w[4], w[5], w[6], w[7] = fx * gy * gz, fx * gy * fz, fx * fy * gz, fx * fy * fz
    return True


@njit(cache=True, nogil=True)
def blend_scalar(grid, ijk, w):  # pragma: no cover - compiled
    """The cell's 8 corners of grid [nx, ny, nz] blended by w (see :func:`cell_weights`)."""
    i, j, k = ijk[0], ijk[1], ijk[2]
    return (
        w[0] * grid[i, j, k] + w[1] * grid[i, j, k + 1] + w[2] * grid[i, j + 1, k] + w[3] * grid[i, j + 1, k + 1]
        + w[4] * grid[i + 1, j, k] + w[5] * grid[i + 1, j, k + 1] + w[6] * grid[i + 1, j + 1, k]
        + w[7] * grid[i + 1, j + 1, k + 1]
    )


@njit(cache=True, nogil=True)
def blend_channels(grid, ijk, w, out):  # pragma: no cover - compiled
    """out[c] = the cell's 8 corners of grid [nx, ny, nz, F] channel c blended by w, every c."""
    i, j, k = ijk[0], ijk[1], ijk[2]
    for c in range(grid.shape[3]):
        out[c] = (
            w[0] * grid[i, j, k, c] + w[1] * grid[i, j, k + 1, c] + w[2] * grid[i, j + 1, k, c]
            + w[3] * grid[i, j + 1, k + 1, c] + w[4] * grid[i + 1, j, k, c] + w[5] * grid[i + 1, j, k + 1, c]
            + w[6] * grid[i + 1, j + 1, k, c] + w[7] * grid[i + 1, j + 1, k + 1, c]
        )


@njit(cache=True, nogil=True)
def softmax_into(logits, probs):  # pragma: no cover - compiled
    """probs = softmax(logits), shifted by the maximum (no overflow); probs may be logits."""
    top = logits[0]
    for c in range(1, logits.shape[0]):
        top = max(top, logits[c])
    total = 0.0
    for c in range(logits.shape[0]):
        probs[c] = math.exp(logits[c] - top)
        total += probs[c]
    for c in range(logits.shape[0]):
        probs[c] /= total


@njit(cache=True, nogil=True)
def normalise_into(weights, probs):  # pragma: no cover - compiled
    """probs = weights / Σ weights (non-negative weights; probs may be weights); the uniform law
    when they sum to 0."""
    total = 0.0
    for c in range(weights.shape[0]):
        total += weights[c]
    for c in range(weights.shape[0]):
        probs[c] = weights[c] / total if total > 0.0 else 1.0 / weights.shape[0]


@njit(cache=True, nogil=True)
def trilinear_kernel(values, frame, points, out):  # pragma: no cover - compiled
    """out [N, F] = values [nx, ny, nz, F] trilinear at world points [N, 3]; 0 outside."""
    ijk, w = np.empty(3, np.int64), np.empty(8)
    for n in range(points.shape[0]):
        if cell_weights(values.shape, frame, points[n, 0], points[n, 1], points[n, 2], ijk, w):
            blend_channels(values, ijk, w, out[n])
        else:
            out[n, :] = 0.0


@njit(cache=True, nogil=True)
def scatter_kernel(grad_out, frame, points, grad):  # pragma: no cover - compiled
    """The adjoint of :func:`trilinear_kernel`: grad [nx, ny, nz, F] += each point's 8 trilinear
    weights times grad_out [N, F] at its cell's corners (points outside add nothing). Serial:
    points of one cell write the same vertices."""
    ijk, w = np.empty(3, np.int64), np.empty(8)
    for n in range(points.shape[0]):
        if cell_weights(grad.shape, frame, points[n, 0], points[n, 1], points[n, 2], ijk, w):
            i, j, k = ijk[0], ijk[1], ijk[2]
            for c in range(grad.shape[3]):
                g = grad_out[n, c]
                grad[i, j, k, c] += w[0] * g
                grad[i, j, k + 1, c] += w[1] * g
                grad[i, j + 1, k, c] += w[2] * g
                grad[i, j + 1, k + 1, c] += w[3] * g
                grad[i + 1, j, k, c] += w[4] * g
                grad[i + 1, j, k + 1, c] += w[5] * g
                grad[i + 1, j + 1, k, c] += w[6] * g
                grad[i + 1, j + 1, k + 1, c] += w[7] * g


@njit(cache=True, nogil=True)
def first_argmax(values):  # pragma: no cover - compiled
    """The index of the largest value, the first of equal ones (a NaN counts as the largest), as
    numpy's argmax."""
    top, best = 0, values[0]
    if best != best:
        return 0
    for c in range(1, values.shape[0]):
        v = values[c]
        if v != v:
            return c
        if v > best:
            top, best = c, v
    return top


@njit(cache=True, nogil=True)
def points_kernel(
    density, class_values, frame, aabb, points, scores, density_out, probs, inside, top
):  # pragma: no cover - compiled
    """Per world point [N, 3]: inside[n], the point lies in the box aabb [2, 3] (faces included);
    density_out[n], the trilinear density clamped at 0; probs[n, C], the trilinear class values
    normalised (probabilities, any positive scale), or their softmax with ``scores`` (logits);
    top[n], the first argmax of probs[n]. 0 and zero probs outside aabb; 0 and the uniform law
    inside it but outside the lattice. The 8 corners are read through flat offsets (the lattices
    are C-contiguous), blended in the order of :func:`blend_scalar` / :func:`blend_channels`; the
    corners of point n + PREFETCH_AHEAD are prefetched meanwhile."""
    ijk, w = np.empty(3, np.int64), np.empty(8)
    n_classes = class_values.shape[3]
    nx, ny, nz = density.shape
    flat_density, flat_classes = density.reshape(-1), class_values.reshape(-1)
    for n in range(points.shape[0]):
        ahead = n + PREFETCH_AHEAD
        if ahead < points.shape[0]:  # the corners of a later point, fetched while this one is blended
            x = (points[ahead, 0] - frame[0]) * frame[3]
            y = (points[ahead, 1] - frame[1]) * frame[3]
            z = (points[ahead, 2] - frame[2]) * frame[3]
            if 0.0 <= x <= nx - 1 and 0.0 <= y <= ny - 1 and 0.0 <= z <= nz - 1:
                u0 = (min(int(x), nx - 2) * ny + min(int(y), ny - 2)) * nz + min(int(z), nz - 2)
                for u in (u0, u0 + nz, u0 + ny * nz, u0 + ny * nz + nz):  # the 4 runs of 2 vertices along z
                    prefetch(flat_density, u)
                    prefetch(flat_classes, u * n_classes)
                    prefetch(flat_classes, (u + 2) * n_classes - 1)
        px, py, pz = points[n, 0], points[n, 1], points[n, 2]
        inside[n] = aabb[0, 0] <= px <= aabb[1, 0] and aabb[0, 1] <= py <= aabb[1, 1] and aabb[0, 2] <= pz <= aabb[1, 2]
        if not inside[n]:
            density_out[n] = 0.0
            probs[n, :] = 0.0
        elif cell_weights(density.shape, frame, px, py, pz, ijk, w):
            v0 = (ijk[0] * ny + ijk[1]) * nz + ijk[2]  # corner order: bit 2 +x, bit 1 +y, bit 0 +z
            v2 = v0 + nz
            v4 = v0 + ny * nz
            v6 = v4 + nz
            density_out[n] = max(
                w[0] * flat_density[v0] + w[1] * flat_density[v0 + 1] + w[2] * flat_density[v2]
                + w[3] * flat_density[v2 + 1] + w[4] * flat_density[v4] + w[5] * flat_density[v4 + 1]
                + w[6] * flat_density[v6] + w[7] * flat_density[v6 + 1],
                0.0,
            )
            c0, c1, c2, c3 = v0 * n_classes, (v0 + 1) * n_classes, v2 * n_classes, (v2 + 1) * n_classes
            c4, c5, c6, c7 = v4 * n_classes, (v4 + 1) * n_classes, v6 * n_classes, (v6 + 1) * n_classes
            total = 0.0  # their sum, as normalise_into adds them
            for c in range(n_classes):
                value = (
                    w[0] * flat_classes[c0 + c] + w[1] * flat_classes[c1 + c] + w[2] * flat_classes[c2 + c]
                    + w[3] * flat_classes[c3 + c] + w[4] * flat_classes[c4 + c] + w[5] * flat_classes[c5 + c]
                    + w[6] * flat_classes[c6 + c] + w[7] * flat_classes[c7 + c]
                )
                probs[n, c] = value
                total += value
            if scores:
                softmax_into(probs[n], probs[n])
            elif total > 0.0:  # a convex blend of probability vectors: normalising undoes the lattice's rounding
                for c in range(n_classes):  # (normalise_into, with the sum taken in the blend: faster)
                    probs[n, c] = probs[n, c] / total
            else:
                probs[n, :] = 1.0 / n_classes
        else:
            density_out[n] = 0.0
            probs[n, :] = 1.0 / n_classes
        top[n] = first_argmax(probs[n])


@njit(cache=True, nogil=True)
def rays_kernel(
    density, class_values, frame, origins, directions, span, marching, scores, out, probs
):  # pragma: no cover - compiled
    """March each ray over span[r] = (t_min, t_max) in intervals of ``step`` (the last one cut at
    t_max), density at the interval middles, until its transmittance is below ``min_trans``
    (``marching`` = (step, min_trans)), and composite into out[r] = (depth, opacity) and probs[r]
    (see scenelabel.query.baked.composite_baked_rays)."""
    step, min_trans = marching
    ijk, w = np.empty(3, np.int64), np.empty(8)
    n_classes = class_values.shape[3]
    sample = np.empty(n_classes)
    acc = np.empty(n_classes)
    for r in range(origins.shape[0]):
        acc[:] = 0.0
        trans, w_sum, wt_sum = 1.0, 0.0, 0.0
        t_lo, t_hi = span[r, 0], span[r, 1]
        k = 0
        t_start = t_lo
        while t_start < t_hi and trans >= min_trans:
            k += 1
            t_end = min(t_lo + k * step, t_hi)
            t_mid = 0.5 * (t_start + t_end)
            px = origins[r, 0] + t_mid * directions[r, 0]
            py = origins[r, 1] + t_mid * directions[r, 1]
            pz = origins[r, 2] + t_mid * directions[r, 2]
            if cell_weights(density.shape, frame, px, py, pz, ijk, w):
                sigma = blend_scalar(density, ijk, w)
                if sigma > 0.0:
                    alpha = -math.expm1(-sigma * (t_end - t_start))
                    weight = trans * alpha
                    trans *= 1.0 - alpha
                    w_sum += weight
                    wt_sum += weight * t_mid
                    blend_channels(class_values, ijk, w, sample)
                    if not scores:  # eq. 7: this sample's probabilities (the lattice's codes normalised)
                        normalise_into(sample, sample)
                    for c in range(n_classes):
                        acc[c] += weight * sample[c]
            t_start = t_end
        far = max(t_hi, 0.0)
        near = min(t_lo, far)
        out[r, 1] = w_sum
        if w_sum > OPACITY_EPS:
            out[r, 0] = min(max(wt_sum / w_sum, near), far)
            if scores:
                softmax_into(acc, probs[r])
            else:  # Σ w_i p_i / Σ w_i (Σ acc is Σ w_i up to rounding)
                normalise_into(acc, probs[r])
        else:  # no weight: the far end and the uniform law, as rendering.depth_from_weights does
            out[r, 0] = far
            probs[r, :] = 1.0 / n_classes
