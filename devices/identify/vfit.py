"""Vector fitting of a stable rational model in pole-residue form.

Implements relaxed vector fitting (Gustavsen and Semlyen 1999; Gustavsen
2006): Sanathanan-Koerner-style iterations that relocate the poles as the
zeros of a weighting function sigma(s), with unstable poles flipped into the
left half plane after every iteration, the least-squares columns scaled to
unit norm, and the model kept in pole-residue form (never polynomial
coefficients), so high orders stay well conditioned. The final model is
converted to zero-pole-gain form through a state-space realization.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

# relative size of the imaginary part below which an eigenvalue is taken as real
_REAL_TOL = 1e-9


@dataclass(frozen=True)
class PoleResidue:
    """H(s) = sum_i r_i / (s - p_i) + d, with stable poles in conjugate pairs.

    Attributes
    ----------
    poles : ndarray of complex, shape (n,)
        Real poles first, then each complex pair as (p, conj p).
    residues : ndarray of complex, shape (n,)
    d : float
        Direct term (0 for a strictly proper model).
    """

    poles: np.ndarray
    residues: np.ndarray
    d: float

    def __call__(self, s: np.ndarray) -> np.ndarray:
        s = np.asarray(s, dtype=complex)
        return (self.residues / (s[:, None] - self.poles)).sum(axis=1) + self.d


def split_poles(poles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Real poles and the upper member of each complex pair (input need not be exactly paired)."""
    poles = np.asarray(poles, dtype=complex)
    scale = np.maximum(np.abs(poles), 1e-300)
    real_mask = np.abs(poles.imag) <= _REAL_TOL * scale
    reals = np.sort(poles[real_mask].real)
    upper = poles[~real_mask & (poles.imag > 0)]
    n_lower = int(np.sum(~real_mask & (poles.imag < 0)))
    if n_lower != upper.size:  # unpaired complex values: take both as real parts (cannot happen for eig of real A)
        reals = np.sort(np.concatenate([reals, poles[~real_mask].real]))
        upper = np.zeros(0, dtype=complex)
    return reals, upper[np.argsort(upper.imag)]


def join_poles(reals: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Inverse of :func:`split_poles`: reals, then (p, conj p) pairs."""
    pairs = np.column_stack([upper, np.conj(upper)]).ravel() if upper.size else np.zeros(0, complex)
    return np.concatenate([reals.astype(complex), pairs])


def _basis(s: np.ndarray, reals: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Real-coefficient partial-fraction basis, shape (m, nr + 2 nc).

    Columns: 1/(s-a) per real pole; 1/(s-p)+1/(s-p*) and j/(s-p)-j/(s-p*) per pair.
    """
    m = s.size
    cols = np.empty((m, reals.size + 2 * upper.size), dtype=complex)
    if reals.size:
        cols[:, : reals.size] = 1.0 / (s[:, None] - reals[None, :])
    if upper.size:
        a = 1.0 / (s[:, None] - upper[None, :])
        b = 1.0 / (s[:, None] - np.conj(upper)[None, :])
        cols[:, reals.size :: 2] = a + b
        cols[:, reals.size + 1 :: 2] = 1j * (a - b)
    return cols


def _realization(reals: np.ndarray, upper: np.ndarray, coef: np.ndarray):
    """State-space (A, b, c) of sum of basis columns times real ``coef`` (see _basis)."""
    n = reals.size + 2 * upper.size
    A = np.zeros((n, n))
    b = np.zeros(n)
    c = np.asarray(coef, dtype=float).copy()
    for i, a in enumerate(reals):
        A[i, i] = a
        b[i] = 1.0
    for j, p in enumerate(upper):
        i = reals.size + 2 * j
        A[i : i + 2, i : i + 2] = [[p.real, p.imag], [-p.imag, p.real]]
        b[i] = 2.0
    return A, b, c


def _lstsq_scaled(M: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Least squares with every column scaled to unit norm (conditioning).

    Solved through the Cholesky factor of the scaled normal equations with a
    1e-13 ridge (the scaled Gram matrix has a unit diagonal): on a busy
    2-core machine LAPACK's SVD/QR least squares spends most of its time in
    BLAS thread contention, while these small Gram matrices cost little. The
    ridge only matters for columns that are linearly dependent (over-high
    orders on noise-free data), where it picks the small-norm solution.
    """
    norms = np.linalg.norm(M, axis=0)
    norms[norms == 0] = 1.0
    Ms = M / norms
    G = Ms.T @ Ms
    G[np.diag_indices_from(G)] += 1e-13
    try:
        c, low = scipy.linalg.cho_factor(G, check_finite=False)
        x = scipy.linalg.cho_solve((c, low), Ms.T @ rhs, check_finite=False)
    except (np.linalg.LinAlgError, scipy.linalg.LinAlgError):
        x, *_ = np.linalg.lstsq(Ms, rhs, rcond=None)
    return x / norms


def _stabilize(poles: np.ndarray) -> np.ndarray:
    """Flip right-half-plane poles to the left; push poles off the imaginary axis."""
    poles = np.asarray(poles, dtype=complex).copy()
    re = poles.real
    flip = re > 0
    poles[flip] = -re[flip] + 1j * poles.imag[flip]
    tiny = np.abs(poles.real) < 1e-9 * np.maximum(np.abs(poles), 1.0)
    poles[tiny] = -1e-9 * np.maximum(np.abs(poles[tiny]), 1.0) + 1j * poles.imag[tiny]
    return poles


def initial_poles(order: int, w_lo: float, w_hi: float) -> np.ndarray:
    """Starting poles: lightly damped pairs log-spaced over the band, plus one real pole if odd."""
    n_pairs = order // 2
    pairs = np.geomspace(max(w_lo, 1e-3), w_hi, n_pairs) if n_pairs else np.zeros(0)
    upper = -pairs / 100.0 + 1j * pairs
    reals = np.array([-np.sqrt(max(w_lo, 1e-3) * w_hi)]) if order % 2 else np.zeros(0)
    return join_poles(reals, upper)


def relocate_poles(s, H, w, poles, direct: bool = True) -> np.ndarray:
    """One relaxed pole-relocation step; returns the new (stable) poles.

    Solves ``w (sum c_i phi_i + d) - w H (sum ct_i phi_i + dt) = 0`` in least
    squares with the relaxation row ``Re sum_k (sum ct_i phi_i(s_k) + dt) = m``,
    then takes the zeros of sigma = sum ct_i phi_i + dt as the new poles.
    """
    reals, upper = split_poles(poles)
    Phi = _basis(s, reals, upper)
    m, n = Phi.shape
    wH = w * H
    blocks = [w[:, None] * Phi]
    if direct:
        blocks.append(w[:, None].astype(complex))
    blocks += [-wH[:, None] * Phi, -wH[:, None]]
    M = np.hstack(blocks)
    rows = np.vstack([M.real, M.imag])
    rhs = np.zeros(2 * m)
    # relaxation (non-triviality) row, weighted like the data
    scale = np.linalg.norm(wH) / m
    extra = np.zeros(M.shape[1])
    extra[-(n + 1) : -1] = np.sum(Phi.real, axis=0)
    extra[-1] = m
    rows = np.vstack([rows, scale * extra])
    rhs = np.concatenate([rhs, [scale * m]])
    x = _lstsq_scaled(rows, rhs)
    ct, dt = x[-(n + 1) : -1], x[-1]
    if abs(dt) < 1e-8:  # relaxation degenerated: fall back to sigma's constant fixed at 1
        dt = 1.0
        M2 = np.hstack(blocks[:-1])
        ct = _lstsq_scaled(np.vstack([M2.real, M2.imag]), np.concatenate([wH.real, wH.imag]))[-n:]
    A, b, c = _realization(reals, upper, ct)
    new = np.linalg.eigvals(A - np.outer(b, c) / dt)
    r2, u2 = split_poles(_stabilize(new))
    return join_poles(r2, u2)


def fit_residues(s, H, w, poles, direct: bool = True) -> PoleResidue:
    """Residues (and direct term) for fixed poles by weighted linear least squares."""
    reals, upper = split_poles(poles)
    Phi = _basis(s, reals, upper)
    M = w[:, None] * Phi
    if direct:
        M = np.hstack([M, w[:, None].astype(complex)])
    wH = w * H
    x = _lstsq_scaled(np.vstack([M.real, M.imag]), np.concatenate([wH.real, wH.imag]))
    coef = x[: Phi.shape[1]]
    d = float(x[-1]) if direct else 0.0
    res = np.concatenate([coef[: reals.size].astype(complex),
                          np.column_stack([coef[reals.size :: 2] + 1j * coef[reals.size + 1 :: 2],
                                           coef[reals.size :: 2] - 1j * coef[reals.size + 1 :: 2]]).ravel()])
    return PoleResidue(join_poles(reals, upper), res, d)


def vector_fit(s, H, w, order: int, n_iter: int = 20, direct: bool = True, poles0=None,
               tol: float = 1e-10) -> PoleResidue:
    """Fit ``H(s) ~ sum r_i/(s - p_i) + d`` with ``order`` stable poles.

    Parameters
    ----------
    s : ndarray of complex, shape (m,)
        j * omega sample points (rad/s).
    H : ndarray of complex, shape (m,)
        Data.
    w : ndarray of float, shape (m,)
        Weights (e.g. coherence / |H| for relative error).
    order : int
        Number of poles, >= 1.
    n_iter : int
        Maximum pole-relocation iterations (stops early once the poles move
        less than ``tol`` relative).
    direct : bool
        Include the direct term d (relative degree 0) or not (strictly proper).
    poles0 : ndarray, optional
        Starting poles (default :func:`initial_poles` over the data's band).

    Returns
    -------
    PoleResidue
    """
    s = np.asarray(s, dtype=complex)
    w_abs = np.abs(s.imag)
    poles = initial_poles(order, w_abs.min(), w_abs.max()) if poles0 is None else np.asarray(poles0, complex)
    for _ in range(n_iter):
        new = relocate_poles(s, H, w, poles, direct)
        moved = np.max(np.abs(np.sort_complex(new) - np.sort_complex(poles)) / np.maximum(np.abs(new), 1.0)) \
            if new.size == poles.size else np.inf
        poles = new
        if moved < tol:
            break
    return fit_residues(s, H, w, poles, direct)


def to_zpk(pr: PoleResidue, s_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """Zeros, poles and gain of a pole-residue model.

    Zeros are the finite eigenvalues of the Rosenbrock pencil of the
    model's real state-space realization; the gain is matched to the model's
    own response at the points ``s_ref`` (least squares).
    """
    reals, upper = split_poles(pr.poles)
    coef = np.concatenate([pr.residues[: reals.size].real,
                           np.column_stack([pr.residues[reals.size :: 2].real,
                                            pr.residues[reals.size :: 2].imag]).ravel()])
    A, b, c = _realization(reals, upper, coef)
    n = A.shape[0]
    # finite generalized eigenvalues of the Rosenbrock pencil [[A, b], [c, d]] - s [[I, 0], [0, 0]];
    # zeros far beyond the poles and the data (a vanishing d) act as constants in band and are
    # dropped, the gain fit below absorbs them
    big = np.zeros((n + 1, n + 1))
    big[:n, :n], big[:n, n], big[n, :n], big[n, n] = A, b, c, pr.d
    E = np.zeros((n + 1, n + 1))
    E[:n, :n] = np.eye(n)
    ev = scipy.linalg.eigvals(big, E) if n else np.zeros(0, complex)
    s_ref = np.asarray(s_ref, dtype=complex)
    limit = 1e4 * max(np.max(np.abs(pr.poles), initial=0.0), np.max(np.abs(s_ref)), 1.0)
    zeros = ev[np.isfinite(ev) & (np.abs(ev) < limit)]
    zr, zu = split_poles(zeros)
    zeros = join_poles(zr, zu)
    poles = pr.poles
    g = np.prod(s_ref[:, None] - zeros, axis=1) / np.prod(s_ref[:, None] - poles, axis=1)
    h = pr(s_ref)
    k = float(np.real(np.vdot(g, h) / np.vdot(g, g)))
    return zeros, poles, k
