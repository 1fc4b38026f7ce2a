"""An independent numpy transcription of RMPflow's reference implementation (rmp.py, rmp_leaf.py).

Used as the oracle: rmpfusion's trees with unit weights and the rmpflow_* leaves must reproduce it.
"""

import numpy as np
from numpy.linalg import norm


def collision_avoidance(x, x_dot, epsilon=0.2, alpha=1e-5, eta=0.0):
    x, x_dot = float(np.squeeze(x)), float(np.squeeze(x_dot))
    if x < 0:
        w, grad_w = 1e10, 0.0
    else:
        w, grad_w = 1.0 / x**4, -4.0 / x**5
    u = epsilon + np.minimum(0, x_dot) * x_dot
    g = w * u
    grad_u = 2 * np.minimum(0, x_dot)
    grad_Phi = alpha * w * grad_w
    xi = 0.5 * x_dot**2 * u * grad_w
    M = np.clip(g + 0.5 * x_dot * w * grad_u, -1e5, 1e5)
    f = np.clip(-grad_Phi - xi - eta * g * x_dot, -1e10, 1e10)
    return np.array([f]), np.array([[M]])


def goal_attractor(x, x_dot, w_u=10, w_l=1, sigma=1, alpha=1, eta=2, gain=1, tol=0.005):
    x_norm = norm(x)
    beta = np.exp(-(x_norm**2) / 2 / (sigma**2))
    w = (w_u - w_l) * beta + w_l
    s = (1 - np.exp(-2 * alpha * x_norm)) / (1 + np.exp(-2 * alpha * x_norm))
    G = np.eye(len(x)) * w
    grad_Phi = s / x_norm * w * x * gain if x_norm > tol else np.zeros_like(x)
    grad_w = -beta * (w_u - w_l) / sigma**2 * x
    xi = -0.5 * (norm(x_dot) ** 2 * grad_w - 2 * np.dot(np.outer(x_dot, x_dot), grad_w))
    return -grad_Phi - eta * w * x_dot - xi, G


def damper(x, x_dot, w=1, eta=1):
    return -eta * w * x_dot, w * np.eye(len(x))


def sphere_map(c, R):
    """(psi, J, J_dot) of RMPflow's normalised distance to a sphere, as in its CollisionAvoidance node."""
    psi = lambda y: np.array([norm(y - c) / R - 1])
    J = lambda y: ((y - c) / norm(y - c) / R)[None, :]
    J_dot = lambda y, yd: (
        yd @ (-1 / norm(y - c) ** 3 * np.outer(y - c, y - c) + 1 / norm(y - c) * np.eye(len(y))) / R
    )[None, :]
    return psi, J, J_dot


def offset_map(goal):
    n = len(goal)
    return (lambda y: y - goal), (lambda y: np.eye(n)), (lambda y, yd: np.zeros((n, n)))


def rmpflow_root(q, qd, children):
    """pushforward, pullback (f = Σ Jᵀ(f_i − M_i J̇ q̇), M = Σ JᵀM_iJ) and resolve (pinv) for a depth-1 tree."""
    f = np.zeros(len(q))
    M = np.zeros((len(q), len(q)))
    for (psi, J, J_dot), leaf in children:
        x, Jx = psi(q), J(q)
        fi, Mi = leaf(x, Jx @ qd)
        f += Jx.T @ (fi - Mi @ J_dot(q, qd) @ qd)
        M += Jx.T @ Mi @ Jx
    return np.linalg.pinv(M) @ f, f, M
