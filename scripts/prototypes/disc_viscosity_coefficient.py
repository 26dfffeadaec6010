"""The disc viscosity's coefficient (docs/method.md §D, "Disc viscosity"): the viscous
acceleration of Monaghan's linear term applied to every pair, Pi_ab = -alpha c mu_ab / rho,
mu_ab = h v_ab.r_ab/(r^2 + eps h^2), for a shear wave v_y = sin(kx), as nu = coef alpha c h:
by quadrature over the M4 kernel (support 2h; the continuum limit, 1/10 in 3D and 1/8 in 2D
at eps = 0) and as the sum over a square/cubic lattice at hfact 1.0 ... 2.0. Needs numpy.
    python3 scripts/prototypes/disc_viscosity_coefficient.py"""
import numpy as np


def grad_factor(q, h, dim):
    """(dW/dr)/r of the M4 kernel with support 2h."""
    sigma = {1: 2 / 3, 2: 10 / (7 * np.pi), 3: 1 / np.pi}[dim] / h**dim
    dw = np.where(q < 1, -3 * q + 2.25 * q * q, np.where(q < 2, -0.75 * (2 - q) ** 2, 0)) / h
    return sigma * dw / np.maximum(q * h, 1e-300)


def coefficient(points, weight, h, k, dim, eps):
    """nu/(alpha c h) from the pair sum at x_a = 0.3/k over the offsets `points` (b = a - d)."""
    x, y = points[0], points[1]
    r2 = sum(p * p for p in points)
    q = np.sqrt(r2) / h
    keep = (q > 0) & (q < 2)
    xa = 0.3 / k
    vr = (np.sin(k * xa) - np.sin(k * (xa - x))) * y
    mu = h * vr / (r2 + eps * h * h)
    acc = np.sum((mu * grad_factor(q, h, dim) * y)[keep]) * weight
    return acc / (-k * k * np.sin(k * xa)) / h


for dim in (2, 3):
    g = np.linspace(-2, 2, 201)
    g = 0.5 * (g[1:] + g[:-1])
    grid = np.meshgrid(*([g] * dim), indexing="ij")
    for eps in (0.0, 0.01):
        c = coefficient(grid, (4 / 200) ** dim, 1.0, 0.02, dim, eps)
        print(f"{dim}D continuum, eps {eps}: nu = {c:.4f} alpha c h")
    n = 48
    for hfact in (1.0, 1.2, 1.5, 2.0):
        dx = 1 / n
        reach = int(np.ceil(2 * hfact)) + 1
        axis = np.arange(-reach, reach + 1) * dx
        lattice = np.meshgrid(*([axis] * dim), indexing="ij")
        c = coefficient(lattice, dx**dim, hfact * dx, 2 * np.pi, dim, 0.01)
        print(f"{dim}D lattice n = {n}, hfact {hfact}: nu = {c:.4f} alpha c h")
