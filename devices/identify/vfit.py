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
# the LAPACK routines scipy.linalg.cho_factor / cho_solve use for float64 (see _lstsq_scaled)
_POTRF, _POTRS = scipy.linalg.get_lapack_funcs(("potrf", "potrs"), (np.zeros((1, 1)),))


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
    n_lower = int(np.count_nonzero(~real_mask & (poles.imag < 0)))
    if n_lower != upper.size:  # unpaired complex values: take both as real parts (cannot happen for eig of real A)
        reals = np.sort(np.concatenate([reals, poles[~real_mask].real]))
        upper = np.zeros(0, dtype=complex)
    return reals, upper[np.argsort(upper.imag)]


def join_poles(reals: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """Inverse of :func:`split_poles`: reals, then (p, conj p) pairs."""
    nr = reals.size
    out = np.empty(nr + 2 * upper.size, dtype=complex)
    out[:nr] = reals
    out[nr::2] = upper
    out[nr + 1 :: 2] = np.conj(upper)
    return out


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
    nr, nc = reals.size, upper.size
    n = nr + 2 * nc
    A = np.zeros((n, n))
    b = np.zeros(n)
    c = np.asarray(coef, dtype=float).copy()
    if nr:
        i = np.arange(nr)
        A[i, i] = reals
        b[:nr] = 1.0
    if nc:  # one 2x2 block [[re, im], [-im, re]] per pair
        i = nr + 2 * np.arange(nc)
        A[i, i] = upper.real
        A[i, i + 1] = upper.imag
        A[i + 1, i] = -upper.imag
        A[i + 1, i + 1] = upper.real
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

    Called a few thousand times per identification on small matrices, so it
    calls the ufuncs and LAPACK routines behind ``np.linalg.norm`` and
    ``scipy.linalg.cho_factor``/``cho_solve`` directly (same operations, same
    results, without their argument checking).
    """
    norms = np.sqrt(np.add.reduce(M * M, axis=0))  # np.linalg.norm(M, axis=0) of a real M
    norms[norms == 0] = 1.0
    Ms = M / norms
    G = Ms.T @ Ms
    G.ravel()[:: G.shape[0] + 1] += 1e-13  # G is a fresh C-contiguous array: ravel() is a view
    c, info = _POTRF(G, lower=False, overwrite_a=False, clean=False)
    if info == 0:
        x, info = _POTRS(c, Ms.T @ rhs, lower=False, overwrite_b=False)
        if info != 0:
            raise ValueError(f"illegal value in {-info}th argument of internal potrs")
    elif info > 0:  # not positive definite (what cho_factor raises LinAlgError for)
        x, *_ = np.linalg.lstsq(Ms, rhs, rcond=None)
    else:
        raise ValueError(f'LAPACK reported an illegal value in {-info}-th argument on entry to "POTRF".')
    return x / norms


def _stabilize(poles: np.ndarray) -> np.ndarray:
    """Flip right-half-plane poles to the left; push poles off the imaginary axis."""
    poles = np.asarray(poles, dtype=complex).copy()
    re = poles.real
    flip = re > 0
    if flip.any():
        poles[flip] = -re[flip] + 1j * poles.imag[flip]
    tiny = np.abs(poles.real) < 1e-9 * np.maximum(np.abs(poles), 1.0)
    if tiny.any():
        poles[tiny] = -1e-9 * np.maximum(np.abs(poles[tiny]), 1.0) + 1j * poles.imag[tiny]
    return poles


def initial_poles(order: int, w_lo: float, w_hi: float) -> np.ndarray:
    """Starting poles: lightly damped pairs log-spaced over the band, plus one real pole if odd."""
    n_pairs = order // 2
    pairs = np.geomspace(max(w_lo, 1e-3), w_hi, n_pairs) if n_pairs else np.zeros(0)
    upper = -pairs / 100.0 + 1j * pairs
    reals = np.array([-np.sqrt(max(w_lo, 1e-3) * w_hi)]) if order % 2 else np.zeros(0)
    return join_poles(reals, upper)


class _Data:
    """The least-squares pieces of one VF problem that do not change with the poles: ``w``, ``w H``, the
    relaxation row's scale and the right-hand sides (built once per :func:`vector_fit`, not per iteration)."""

    def __init__(self, s, H, w):
        self.s = s
        self.m = m = s.size
        self.w = w
        self.wH = wH = w * H
        self.neg_wH = -wH
        self.scale = np.linalg.norm(wH) / m
        self.rhs_fit = np.concatenate([wH.real, wH.imag])
        self.rhs_relax = np.concatenate([np.zeros(2 * m), [self.scale * m]])

    def relax_matrix(self, n: int, direct: bool) -> np.ndarray:
        """The relocation system's real matrix for ``n`` poles with its pole-independent columns filled:
        rows (Re, Im, relaxation row), columns (w phi_i, [w], -w H phi_i, -w H)."""
        m = self.m
        R = np.empty((2 * m + 1, 2 * n + 2 if direct else 2 * n + 1))
        if direct:
            R[:m, n] = self.w
            R[m : 2 * m, n] = 0.0
        R[:m, -1] = self.neg_wH.real
        R[m : 2 * m, -1] = self.neg_wH.imag
        return R


def _relocate(d: _Data, reals: np.ndarray, upper: np.ndarray, direct: bool, R: np.ndarray):
    """:func:`relocate_poles` on split poles, reusing ``R`` (from ``d.relax_matrix``); returns the new poles
    split (:func:`split_poles`)."""
    Phi = _basis(d.s, reals, upper)
    m, n = Phi.shape
    off = n + 1 if direct else n
    P = d.w[:, None] * Phi
    R[:m, :n] = P.real
    R[m : 2 * m, :n] = P.imag
    Q = -d.wH[:, None] * Phi
    R[:m, off : off + n] = Q.real
    R[m : 2 * m, off : off + n] = Q.imag
    # relaxation (non-triviality) row, weighted like the data
    extra = np.zeros(R.shape[1])
    extra[-(n + 1) : -1] = np.add.reduce(Phi.real, axis=0)
    extra[-1] = m
    R[2 * m] = d.scale * extra
    x = _lstsq_scaled(R, d.rhs_relax)
    ct, dt = x[-(n + 1) : -1], x[-1]
    if abs(dt) < 1e-8:  # relaxation degenerated: fall back to sigma's constant fixed at 1
        dt = 1.0
        ct = _lstsq_scaled(np.ascontiguousarray(R[: 2 * m, :-1]), d.rhs_fit)[-n:]
    A, b, c = _realization(reals, upper, ct)
    new = np.linalg.eigvals(A - np.outer(b, c) / dt)
    return split_poles(_stabilize(new))


def _resplit(reals: np.ndarray, upper: np.ndarray, joined: np.ndarray):
    """``split_poles(joined)`` for ``joined = join_poles(reals, upper)`` with ``(reals, upper)`` from
    :func:`split_poles`: that is ``(reals, upper)`` itself unless two pairs have equal imaginary parts."""
    if upper.size < 2 or np.all(upper.imag[1:] > upper.imag[:-1]):
        return reals, upper
    return split_poles(joined)


def relocate_poles(s, H, w, poles, direct: bool = True) -> np.ndarray:
    """One relaxed pole-relocation step; returns the new (stable) poles.

    Solves ``w (sum c_i phi_i + d) - w H (sum ct_i phi_i + dt) = 0`` in least
    squares with the relaxation row ``Re sum_k (sum ct_i phi_i(s_k) + dt) = m``,
    then takes the zeros of sigma = sum ct_i phi_i + dt as the new poles.
    """
    d = _Data(s, H, w)
    reals, upper = split_poles(poles)
    r2, u2 = _relocate(d, reals, upper, direct, d.relax_matrix(reals.size + 2 * upper.size, direct))
    return join_poles(r2, u2)


def _fit_residues(d: _Data, reals: np.ndarray, upper: np.ndarray, direct: bool,
                  Phi: np.ndarray | None = None) -> PoleResidue:
    """:func:`fit_residues` on split poles (``Phi``: their :func:`_basis`, if already made)."""
    if Phi is None:
        Phi = _basis(d.s, reals, upper)
    m, n = Phi.shape
    P = d.w[:, None] * Phi
    M = np.empty((2 * m, n + 1 if direct else n))
    M[:m, :n] = P.real
    M[m:, :n] = P.imag
    if direct:
        M[:m, n] = d.w
        M[m:, n] = 0.0
    x = _lstsq_scaled(M, d.rhs_fit)
    coef = x[:n]
    dd = float(x[-1]) if direct else 0.0
    res = np.concatenate([coef[: reals.size].astype(complex),
                          np.column_stack([coef[reals.size :: 2] + 1j * coef[reals.size + 1 :: 2],
                                           coef[reals.size :: 2] - 1j * coef[reals.size + 1 :: 2]]).ravel()])
    return PoleResidue(join_poles(reals, upper), res, dd)


def fit_residues(s, H, w, poles, direct: bool = True) -> PoleResidue:
    """Residues (and direct term) for fixed poles by weighted linear least squares."""
    reals, upper = split_poles(poles)
    return _fit_residues(_Data(s, H, w), reals, upper, direct)


def _iterate(s, H, w, order: int, n_iter: int, direct: bool, poles0, tol: float):
    """The pole relocation of :func:`vector_fit`; returns (data, reals, upper) of the final poles."""
    s = np.asarray(s, dtype=complex)
    if poles0 is None:
        w_abs = np.abs(s.imag)
        poles = initial_poles(order, w_abs.min(), w_abs.max())
    else:
        poles = np.asarray(poles0, complex)
    d = _Data(s, H, w)
    reals, upper = split_poles(poles)
    R = d.relax_matrix(reals.size + 2 * upper.size, direct)
    for _ in range(n_iter):
        r2, u2 = _relocate(d, reals, upper, direct, R)
        new = join_poles(r2, u2)
        moved = np.max(np.abs(np.sort_complex(new) - np.sort_complex(poles)) / np.maximum(np.abs(new), 1.0)) \
            if new.size == poles.size else np.inf
        poles = new
        reals, upper = _resplit(r2, u2, new)
        if moved < tol:
            break
    return d, reals, upper


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
    d, reals, upper = _iterate(s, H, w, order, n_iter, direct, poles0, tol)
    return _fit_residues(d, reals, upper, direct)


def vector_fit_both(s, H, w, order: int, n_iter: int = 20, poles0=None,
                    tol: float = 1e-10) -> tuple[PoleResidue, PoleResidue]:
    """``vector_fit(..., direct=False)`` and the residues with a direct term on its poles: the same as
    ``pr = vector_fit(s, H, w, order, n_iter, False, poles0, tol)`` and
    ``fit_residues(s, H, w, pr.poles, direct=True)``, with the basis made once."""
    d, reals, upper = _iterate(s, H, w, order, n_iter, False, poles0, tol)
    Phi = _basis(d.s, reals, upper)
    pr = _fit_residues(d, reals, upper, False, Phi)
    r, u = _resplit(reals, upper, pr.poles)
    if r is not reals:  # (equal imaginary parts of two pairs) fit_residues re-splits the joined poles
        return pr, _fit_residues(d, r, u, True)
    return pr, _fit_residues(d, reals, upper, True, Phi)


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
