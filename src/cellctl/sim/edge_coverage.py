"""Anti-aliased edges: the fraction of a pixel's response inside a shape, from a signed distance.

A pixel integrates the scene blurred by a Gaussian (``sigma`` px) over its 1 x 1 px footprint.
Near a straight edge with image normal ``m`` and signed distance ``d`` (px) from the pixel centre:

    F(d) = E[ Phi((d - a - b) / sigma) ],   a ~ U(+-|m_u|/2),  b ~ U(+-|m_v|/2),

closed form in the second antiderivative of Phi (:func:`edge_coverage`); F(0) = 1/2, so a
rendered edge's 50 % level lies on the true edge. The signed-distance functions return the
distance in the shape's plane (mm) and its unit gradient, for the renderer's plane-to-pixel Jacobian.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr

F64 = NDArray[np.float64]

_INV_SQRT_2PI = 1.0 / np.sqrt(2.0 * np.pi)
# Below this width a box side is treated as a line (the O(w^2) error is < 1e-7 of the contrast).
_THIN_BOX = 1e-3
# Coverage within this many kernel "radii" of an edge differs from 0 or 1 by less than Phi(-6) = 1e-9.
TAIL_SIGMAS = 6.0


def kernel_reach_px(sigma_px: float) -> float:
    """Distance (px) from an edge beyond which the coverage is 0 or 1 to within 1e-9.

    The Gaussian's tail beyond ``TAIL_SIGMAS`` sigmas plus the pixel box's largest half-extent
    (half its diagonal) bounds the kernel's reach.
    """
    return TAIL_SIGMAS * sigma_px + np.sqrt(0.5) + 1e-3


def _phi_antiderivative_1(x: F64, s: float) -> F64:
    """int Phi(x/s) dx = x Phi(x/s) + s phi(x/s)."""
    z = x / s
    return x * ndtr(z) + s * _INV_SQRT_2PI * np.exp(-0.5 * z * z)


def _phi_antiderivative_2(x: F64, s: float) -> F64:
    """int int Phi(x/s) dx dx = ((x^2 + s^2) Phi(x/s) + x s phi(x/s)) / 2."""
    z = x / s
    return 0.5 * ((x * x + s * s) * ndtr(z) + x * s * _INV_SQRT_2PI * np.exp(-0.5 * z * z))


def edge_coverage(d_px: F64, m_u: F64, m_v: F64, sigma_px: float) -> F64:
    """Fraction of the pixel's response lying inside a shape whose edge is ``d_px`` away.

    Args:
        d_px: signed distance (px) from the pixel centre to the edge, positive when the centre is
            inside the shape.
        m_u, m_v: components of the edge's unit normal in the image (any sign).
        sigma_px: the optics' Gaussian point-spread (px), >= 0.

    Returns:
        Coverage in [0, 1], exact for a straight edge under the model in the module docstring.
    """
    d = np.asarray(d_px, dtype=np.float64)
    s = max(float(sigma_px), 1e-6)
    w1 = np.abs(np.asarray(m_u, dtype=np.float64))
    w2 = np.abs(np.asarray(m_v, dtype=np.float64))
    wide = np.maximum(w1, w2)
    thin = np.minimum(w1, w2)
    out = np.empty(np.broadcast(d, wide).shape, dtype=np.float64)
    d_b, wide_b, thin_b = np.broadcast_arrays(d, wide, thin)
    box = thin_b >= _THIN_BOX
    if np.any(box):
        dd, h1, h2 = d_b[box], 0.5 * wide_b[box], 0.5 * thin_b[box]
        acc = (
            _phi_antiderivative_2(dd + h1 + h2, s)
            - _phi_antiderivative_2(dd - h1 + h2, s)
            - _phi_antiderivative_2(dd + h1 - h2, s)
            + _phi_antiderivative_2(dd - h1 - h2, s)
        )
        out[box] = acc / (4.0 * h1 * h2)
    line = ~box
    if np.any(line):
        dd, h1 = d_b[line], 0.5 * wide_b[line]
        out[line] = (_phi_antiderivative_1(dd + h1, s) - _phi_antiderivative_1(dd - h1, s)) / (2.0 * h1)
    return np.clip(out, 0.0, 1.0)


def rounded_rect_sdf(
    x: F64, y: F64, center: tuple[float, float], half_size: tuple[float, float], radius: float
) -> tuple[F64, F64, F64]:
    """Exact signed distance to an axis-aligned rounded rectangle, and its unit gradient.

    Negative inside. ``radius`` 0 gives a sharp-cornered rectangle (its distance outside a corner
    is the distance to the vertex).

    Returns:
        (distance, grad_x, grad_y), arrays shaped like ``x``.
    """
    px = x - center[0]
    py = y - center[1]
    sx = np.where(px < 0.0, -1.0, 1.0)
    sy = np.where(py < 0.0, -1.0, 1.0)
    qx = np.abs(px) - (half_size[0] - radius)
    qy = np.abs(py) - (half_size[1] - radius)
    corner = (qx > 0.0) & (qy > 0.0)
    qn = np.sqrt(np.maximum(qx, 0.0) ** 2 + np.maximum(qy, 0.0) ** 2)
    qn_safe = np.where(qn > 1e-12, qn, 1.0)
    x_side = qx >= qy
    dist = np.where(corner, qn, np.maximum(qx, qy)) - radius
    gx = np.where(corner, qx / qn_safe, np.where(x_side, 1.0, 0.0)) * sx
    gy = np.where(corner, qy / qn_safe, np.where(x_side, 0.0, 1.0)) * sy
    return dist, gx, gy


def circle_sdf(x: F64, y: F64, cx: F64 | float, cy: F64 | float, radius: float) -> tuple[F64, F64, F64]:
    """Signed distance to a circle (negative inside) and its unit gradient."""
    dx = x - cx
    dy = y - cy
    r = np.hypot(dx, dy)
    r_safe = np.where(r > 1e-12, r, 1.0)
    gx = np.where(r > 1e-12, dx / r_safe, 1.0)
    gy = np.where(r > 1e-12, dy / r_safe, 0.0)
    return r - radius, gx, gy


def coverage_from_sdf(sd_mm: F64, grad_x: F64, grad_y: F64, jac: tuple[F64, F64, F64, F64], sigma_px: float) -> F64:
    """Coverage of pixels by a planar shape given its signed distance in the plane.

    Args:
        sd_mm: signed distance (plane units, negative inside) at each pixel centre's ray hit.
        grad_x, grad_y: the unit gradient of that distance in the plane.
        jac: the plane-from-pixel Jacobian (dX/du, dX/dv, dY/du, dY/dv) at each pixel (mm/px).
        sigma_px: the optics' Gaussian point-spread (px).

    The image-space gradient of the distance is ``J^T g``; its length converts the plane distance
    to pixels and its direction is the edge normal the pixel box is projected onto.
    """
    a, b, c, d = jac
    m_u = a * grad_x + c * grad_y
    m_v = b * grad_x + d * grad_y
    norm = np.hypot(m_u, m_v)
    d_px = -sd_mm / norm
    out = (d_px > 0.0).astype(np.float64)
    near = np.abs(d_px) < kernel_reach_px(sigma_px)
    if np.any(near):
        n = norm[near]
        out[near] = edge_coverage(d_px[near], m_u[near] / n, m_v[near] / n, sigma_px)
    return out
