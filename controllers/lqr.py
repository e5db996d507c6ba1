"""The LQ designs of :class:`~.lqi.LQI`: the gains of the discrete LQR with integral
action (one or more outputs, as many inputs; optionally the move per sample as the input)
and the LQ-optimal preview gains, from ``control.dlqr`` on the sampled linearisation."""

from __future__ import annotations

import control as ct
import numpy as np


def lqi_design(sysd: ct.StateSpace, w, y_scale, dt: float, rate_weight=None, du=None):
    """``Kx`` (inputs x states), ``Ku``, ``Ki`` (inputs x outputs) from ``control.dlqr`` on
    the model with the error integrals appended, the steady-state map ``x_ss = Nx dr``,
    ``u_ss = Nu dr`` (``Nx``: states x outputs, ``Nu``: inputs x outputs; ``y_scale`` one
    per output), and the design's ``(Aa, Ba, R, K, S)``. With ``rate_weight`` the move
    per sample ``v = u - u_prev`` is the input, weighted ``rate_weight (v / du)^2``
    (``du`` the rate limit's move per sample), and the held command a state ``[dx;
    u_prev - u_op; xi]`` weighted ``r_u``: ``u = u_prev - Kx (dx - x_ss) - Ku (u_prev -
    u_op - u_ss) - Ki xi``; else ``Ku`` is None and ``u = u_op + u_ss - Kx (dx - x_ss) -
    Ki xi``."""
    A, B, C, D = sysd.A, sysd.B, sysd.C, sysd.D
    n, (ny, nu), held = A.shape[0], D.shape, rate_weight is not None
    na = n + ny + held
    Aa, Ba, Q = np.eye(na), np.zeros((na, nu)), np.zeros((na, na))
    Aa[:n, :n], Aa[-ny:, :n], Ba[:n], Ba[-ny:] = A, dt * C, B, dt * D
    scales = np.asarray(y_scale, dtype=float)
    Q[:n, :n] = (C.T * (w.q_y / scales**2)) @ C
    Q[-ny:, -ny:] = np.diag(w.q_i / scales**2)
    R = w.r_u / w.u_scale**2 * np.eye(nu)
    if held:  # the held command: a state the move adds to (one input and output)
        Aa[:n, n], Aa[-1, n], Ba[n], Q[n, n] = B[:, 0], dt * D[0, 0], 1.0, R[0, 0]
        R = np.array([[rate_weight / du**2]])
    K, S, _ = ct.dlqr(Aa, Ba, (Q + Q.T) / 2, R)
    M = np.block([[A - np.eye(n), B], [C, D]])
    N = np.linalg.solve(M, np.vstack([np.zeros((n, ny)), np.eye(ny)]))
    Ku = float(K[0, n]) if held else None
    return K[:, :n], Ku, K[:, -ny:], N[:n], N[n:], (Aa, Ba, R, K, S)


def preview_gains(Aa, Ba, R, K, S, samples: int) -> np.ndarray:
    """``G_j = (R + B' S B)^-1 B' (A_cl')^j S``, ``j < samples``: the LQ-optimal answer to
    a known shift ``w_j`` of the target ``j`` samples ahead is ``-sum_j G_j w_j``."""
    Acl = Aa - Ba @ K
    first = np.linalg.solve(R + Ba.T @ S @ Ba, Ba.T)  # 1 x na
    rows, M = [], S
    for _ in range(samples):
        rows.append((first @ M)[0])
        M = Acl.T @ M
    return np.reshape(rows, (samples, Aa.shape[0]))
