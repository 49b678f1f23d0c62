"""Per-landmark EKF: against filterpy, the textbook version, closed forms, Monte Carlo, properties."""

from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import multivariate_normal

from fastslam_edu.core.ekf import (
    gaussian_log_likelihood,
    initialise_landmark,
    initialise_landmark_kernel,
    Innovation,
    innovation_statistics_kernel,
    update_landmark_kernel,
    innovation_statistics,
    update_landmark,
    update_landmark_textbook,
)

# -- random EKF cases ------------------------------------------------------------------------


def random_cases(rng: np.random.Generator, n: int, behind: bool = False):
    """n random (mu, Sigma, x, z, R): landmark 0.3–10 m away, Σ SPD, z drawn near h(x, μ).

    behind=True puts the predicted bearing within 0.05 rad of ±π and the measured
    bearing on the other side of ±π, so that the raw bearing residual is ≈ ±2π.
    """
    x = np.column_stack(
        (rng.uniform(-10, 10, n), rng.uniform(-10, 10, n), rng.uniform(-np.pi, np.pi, n))
    )
    dist = rng.uniform(0.3, 10.0, n)
    if behind:
        sign = rng.choice([-1.0, 1.0], n)
        bearing = sign * (np.pi - rng.uniform(0.001, 0.05, n))
    else:
        bearing = rng.uniform(-np.pi, np.pi, n)
    a = x[:, 2] + bearing
    mu = x[:, :2] + dist[:, None] * np.column_stack((np.cos(a), np.sin(a)))
    A = rng.normal(0.0, 0.4, (n, 2, 2))
    Sigma = A @ A.transpose(0, 2, 1) + 0.01 * np.eye(2)
    sr, sp = rng.uniform(0.01, 0.3, n), rng.uniform(0.005, 0.1, n)
    R = np.zeros((n, 2, 2))
    R[:, 0, 0], R[:, 1, 1] = sr**2, sp**2
    r_meas = dist + rng.normal(0.0, 0.2, n)
    if behind:  # measured bearing on the far side of ±π from the predicted one
        phi_meas = -sign * (np.pi - rng.uniform(0.001, 0.05, n))
    else:
        phi_meas = bearing + rng.normal(0.0, 0.1, n)
    z = np.column_stack((np.abs(r_meas), phi_meas))
    return mu, Sigma, x, z, R


def h_by_hand(m, pose):
    """h(x, m) for filterpy: column vectors, written out independently of the package."""
    dx, dy = m[0, 0] - pose[0], m[1, 0] - pose[1]
    return np.array([[math.hypot(dx, dy)], [math.atan2(dy, dx) - pose[2]]])


def H_by_hand(m, pose):
    dx, dy = m[0, 0] - pose[0], m[1, 0] - pose[1]
    q = dx * dx + dy * dy
    r = math.sqrt(q)
    return np.array([[dx / r, dy / r], [-dy / q, dx / q]])


def residual_by_hand(a, b):
    """z ⊖ ẑ with the bearing wrapped to [−π, π) by modular arithmetic (independent wrap)."""
    d = a - b
    d[1, 0] = (d[1, 0] + np.pi) % (2 * np.pi) - np.pi
    return d


def filterpy_update(mu, Sigma, x, z, R):
    ekf = ExtendedKalmanFilter(dim_x=2, dim_z=2)
    ekf.x = mu.reshape(2, 1).copy()
    ekf.P = Sigma.copy()
    ekf.R = R.copy()
    ekf.F = np.eye(2)
    ekf.Q = np.zeros((2, 2))
    ekf.update(
        z.reshape(2, 1),
        HJacobian=H_by_hand,
        Hx=h_by_hand,
        args=(x,),
        hx_args=(x,),
        residual=residual_by_hand,
    )
    return ekf.x.ravel(), ekf.P, ekf.log_likelihood, ekf.y.ravel()


@pytest.fixture(scope="module")
def cases():
    rng = np.random.default_rng(20240601)
    ordinary = random_cases(rng, 250)
    behind = random_cases(rng, 60, behind=True)
    return tuple(np.concatenate(pair) for pair in zip(ordinary, behind)), 250


# -- against filterpy ------------------------------------------------------------------------


def test_matches_filterpy_ekf(cases):
    (mu, Sigma, x, z, R), n_ordinary = cases
    mu_new, Sigma_new, loglik = update_landmark(mu, Sigma, x, z, R)  # all cases in one call
    ref = [filterpy_update(*(a[i] for a in (mu, Sigma, x, z, R))) for i in range(len(mu))]
    ref_mu = np.array([r[0] for r in ref])
    ref_P = np.array([r[1] for r in ref])
    ref_ll = np.array([r[2] for r in ref])
    ref_y = np.array([r[3] for r in ref])

    # the ±π cases really cross: raw bearing difference ≈ ±2π, the wrapped one is small
    b = slice(n_ordinary, None)
    phi_hat = np.arctan2(mu[b, 1] - x[b, 1], mu[b, 0] - x[b, 0]) - x[b, 2]
    phi_hat = (phi_hat + np.pi) % (2 * np.pi) - np.pi
    assert np.all(np.abs(z[b, 1] - phi_hat) > 6.0)
    assert np.all(np.abs(ref_y[b, 1]) < 0.2)

    d_mu = np.abs(mu_new - ref_mu).max()
    d_P = np.abs(Sigma_new - ref_P).max()
    d_ll = np.abs(loglik - ref_ll).max()
    print(f"max |Δμ'| = {d_mu:.2e} m, max |ΔΣ'| = {d_P:.2e} m², max |Δ log w| = {d_ll:.2e}")
    assert d_mu < 1e-9
    assert d_P < 1e-9
    assert d_ll < 1e-9


def test_without_wrapping_the_crossing_cases_go_wrong(cases):
    """The ±π cases are sensitive: filterpy with a plain subtraction lands far from us."""
    (mu, Sigma, x, z, R), n_ordinary = cases
    i = n_ordinary  # first ±π case
    mu_new, _, _ = update_landmark(mu[i], Sigma[i], x[i], z[i], R[i])
    ekf = ExtendedKalmanFilter(dim_x=2, dim_z=2)
    ekf.x, ekf.P, ekf.R = mu[i].reshape(2, 1).copy(), Sigma[i].copy(), R[i].copy()
    ekf.update(z[i].reshape(2, 1), H_by_hand, h_by_hand, args=(x[i],), hx_args=(x[i],))
    assert np.abs(ekf.x.ravel() - mu_new).max() > 0.1


# -- textbook one-at-a-time version ------------------------------------------------------------


def test_batched_equals_textbook(cases):
    (mu, Sigma, x, z, R), _ = cases
    mu_new, Sigma_new, loglik = update_landmark(mu, Sigma, x, z, R)
    for i in range(len(mu)):
        m1, S1, l1 = update_landmark_textbook(mu[i], Sigma[i], x[i], z[i], R[i])
        np.testing.assert_allclose(mu_new[i], m1, rtol=0, atol=1e-12)
        np.testing.assert_allclose(Sigma_new[i], S1, rtol=0, atol=1e-12)
        assert abs(loglik[i] - l1) < 1e-12


def test_batched_over_particles_and_measurements():
    """(M, n) batch with the pose broadcast over measurements equals element by element."""
    rng = np.random.default_rng(5)
    M, n = 6, 4
    mu, Sigma, x, z, R = random_cases(rng, M * n)
    mu, Sigma, z = mu.reshape(M, n, 2), Sigma.reshape(M, n, 2, 2), z.reshape(M, n, 2)
    pose = x[:M]
    out = update_landmark(mu, Sigma, pose[:, None, :], z, R[0])
    assert out[0].shape == (M, n, 2) and out[1].shape == (M, n, 2, 2) and out[2].shape == (M, n)
    for i in range(M):
        for k in range(n):
            m1, S1, l1 = update_landmark_textbook(mu[i, k], Sigma[i, k], pose[i], z[i, k], R[0])
            np.testing.assert_allclose(out[0][i, k], m1, rtol=0, atol=1e-12)
            np.testing.assert_allclose(out[1][i, k], S1, rtol=0, atol=1e-12)
            assert abs(out[2][i, k] - l1) < 1e-12 * max(1.0, abs(l1))


def test_the_compiled_kernels_one_landmark_at_a_time(cases):
    """innovation_statistics_kernel's Q and d² against Q = H Σ Hᵀ + R written out; update_landmark_kernel against
    update_landmark_textbook; beyond the gate, μ and Σ are left exactly as they were; initialise_landmark_kernel
    against initialise_landmark (the inverse model, numpy)."""
    (mu, Sigma, x, z, R), _ = cases
    Sigma = 0.5 * (Sigma + Sigma.transpose(0, 2, 1))  # the filter stores exactly symmetric Σ
    for i in range(len(mu)):
        innovation = innovation_statistics_kernel(x[i], z[i], R[i], mu[i], Sigma[i])
        assert isinstance(innovation, Innovation) and len(innovation) == 11
        nu0, nu1, q00, q01, q11 = innovation.nu0, innovation.nu1, innovation.q00, innovation.q01, innovation.q11
        d2, loglik = innovation.d2, innovation.loglik
        np.testing.assert_allclose([[innovation.h00, innovation.h01], [innovation.h10, innovation.h11]],
                                   H_by_hand(mu[i][:, None], x[i]), rtol=1e-12, atol=1e-15)
        H = H_by_hand(mu[i][:, None], x[i])
        Q = H @ Sigma[i] @ H.T + R[i]  # written out independently
        np.testing.assert_allclose([[q00, q01], [q01, q11]], Q, rtol=1e-12, atol=1e-15)
        nu = np.array([nu0, nu1])
        assert math.isclose(d2, nu @ np.linalg.solve(Q, nu), rel_tol=1e-9)
        mu_book, Sigma_book, loglik_book = update_landmark_textbook(mu[i], Sigma[i], x[i], z[i], R[i])
        m, S = mu[i].copy(), Sigma[i].copy()
        assert update_landmark_kernel(x[i], z[i], R[i], m, S, math.inf) == (d2, loglik)
        np.testing.assert_allclose(m, mu_book, rtol=0, atol=1e-12)
        np.testing.assert_allclose(S, Sigma_book, rtol=0, atol=1e-12)
        assert abs(loglik - loglik_book) < 1e-12 * max(1.0, abs(loglik_book))
        m, S = mu[i].copy(), Sigma[i].copy()
        update_landmark_kernel(x[i], z[i], R[i], m, S, 0.99 * d2)  # an outlier: left alone, bitwise
        np.testing.assert_array_equal(m, mu[i])
        np.testing.assert_array_equal(S, Sigma[i])
        m, S = np.empty(2), np.empty((2, 2))
        initialise_landmark_kernel(x[i], z[i], R[i], m, S)
        m_ref, S_ref = initialise_landmark(x[i], z[i], R[i])
        np.testing.assert_allclose(m, m_ref, rtol=0, atol=1e-12)
        np.testing.assert_allclose(S, S_ref, rtol=1e-12, atol=1e-18)


def test_checked_update_symmetrises_a_slightly_asymmetric_sigma():
    """update_landmark accepts Σ asymmetric at rounding level and updates its symmetric part."""
    mu, Sigma, x, z, R = random_cases(np.random.default_rng(3), 1)
    skew = Sigma.copy()
    skew[0, 0, 1] += 1e-12
    sym = 0.5 * (skew + skew.transpose(0, 2, 1))
    for a, b in zip(update_landmark(mu, skew, x, z, R), update_landmark(mu, sym, x, z, R)):
        np.testing.assert_array_equal(a, b)


def test_information_form(cases):
    """Closed form independent of the gain: Σ'⁻¹ = Σ⁻¹ + Hᵀ R⁻¹ H (H at the prior mean)."""
    (mu, Sigma, x, z, R), _ = cases
    _, Sigma_new, _ = update_landmark(mu, Sigma, x, z, R)
    H = np.array([H_by_hand(mu[i].reshape(2, 1), x[i]) for i in range(len(mu))])
    info = np.linalg.inv(Sigma) + H.transpose(0, 2, 1) @ np.linalg.inv(R) @ H
    np.testing.assert_allclose(np.linalg.inv(info), Sigma_new, rtol=1e-8, atol=1e-12)


# -- log-likelihood ------------------------------------------------------------------------


def test_gaussian_log_likelihood_matches_scipy():
    rng = np.random.default_rng(11)
    A = rng.normal(size=(3, 50, 2, 2))
    Q = A @ np.swapaxes(A, -1, -2) + 0.05 * np.eye(2)
    nu = rng.normal(size=(3, 50, 2))
    ll = gaussian_log_likelihood(nu, Q)
    assert ll.shape == (3, 50)
    ref = np.array(
        [[multivariate_normal.logpdf(nu[i, j], cov=Q[i, j]) for j in range(50)] for i in range(3)]
    )
    np.testing.assert_allclose(ll, ref, rtol=0, atol=1e-10)


def test_weight_is_the_marginal_likelihood_of_z():
    """FastSLAM's weight ∫ N(z; h(x, m), R) N(m; μ, Σ) dm ≈ N(ν; 0, Q) (Monte Carlo, small Σ)."""
    rng = np.random.default_rng(12)
    x = np.array([1.0, -2.0, 0.7])
    mu = np.array([4.0, 1.0])
    Sigma = np.array([[0.004, 0.001], [0.001, 0.002]])
    R = np.diag([0.05**2, 0.03**2])
    z = np.array([4.3, 0.05])
    _, _, loglik = update_landmark(mu, Sigma, x, z, R)
    m = rng.multivariate_normal(mu, Sigma, 200_000)
    dx, dy = m[:, 0] - x[0], m[:, 1] - x[1]
    nu = np.column_stack((z[0] - np.hypot(dx, dy), z[1] - (np.arctan2(dy, dx) - x[2])))
    dens = multivariate_normal(cov=R).pdf(nu)
    estimate = dens.mean()
    stderr = dens.std() / np.sqrt(len(dens))
    # 5 standard errors of Monte Carlo, plus 2 % for the linearisation of h over Σ
    assert abs(estimate - np.exp(loglik)) < 5 * stderr + 0.02 * estimate


# -- initialisation --------------------------------------------------------------------------


def test_initialise_closed_form():
    rng = np.random.default_rng(13)
    n = 100
    x = np.column_stack((rng.uniform(-5, 5, n), rng.uniform(-5, 5, n), rng.uniform(-4, 4, n)))
    z = np.column_stack((rng.uniform(0.2, 10, n), rng.uniform(-np.pi, np.pi, n)))
    sr, sp = 0.1, 0.05
    mu, Sigma = initialise_landmark(x, z, np.diag([sr**2, sp**2]))
    a = x[:, 2] + z[:, 1]
    c, s, r = np.cos(a), np.sin(a), z[:, 0]
    # σ_r² along the line of sight (c, s), r² σ_φ² across it (−s, c)
    expect = np.empty((n, 2, 2))
    expect[:, 0, 0] = sr**2 * c**2 + r**2 * sp**2 * s**2
    expect[:, 1, 1] = sr**2 * s**2 + r**2 * sp**2 * c**2
    expect[:, 0, 1] = expect[:, 1, 0] = (sr**2 - r**2 * sp**2) * s * c
    np.testing.assert_allclose(Sigma, expect, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(mu, x[:, :2] + r[:, None] * np.column_stack((c, s)), atol=1e-12)


def test_initialise_monte_carlo():
    """Sample z ~ N(z, R), map through h⁻¹: the empirical covariance is ≈ G R Gᵀ."""
    rng = np.random.default_rng(14)
    x = np.array([2.0, -1.0, 2.5])
    z = np.array([5.0, -0.8])
    R = np.array([[0.02**2, 0.3 * 0.02 * 0.01], [0.3 * 0.02 * 0.01, 0.01**2]])
    mu, Sigma = initialise_landmark(x, z, R)
    n = 100_000
    zs = rng.multivariate_normal(z, R, n)
    a = x[2] + zs[:, 1]
    ms = x[:2] + zs[:, [0]] * np.column_stack((np.cos(a), np.sin(a)))
    C = np.cov(ms.T)
    # whiten by Σ: should be the identity up to sampling error (sd ≈ √(2/n) = 0.0045 on the
    # diagonal) and linearisation error (relative ≈ σ_φ² = 1e-4)
    L = np.linalg.cholesky(Sigma)
    W = np.linalg.solve(L, np.linalg.solve(L, C).T)
    assert np.abs(W - np.eye(2)).max() < 0.025
    mean_tol = 5 * np.sqrt(Sigma.diagonal().max() / n) + z[0] * R[1, 1] / 2  # 5 s.e. + bias
    np.testing.assert_allclose(ms.mean(axis=0), mu, atol=mean_tol)


def test_initialise_then_update_with_same_z_keeps_mean():
    """Re-observing exactly h(x, μ) leaves μ and halves Σ (two equal pieces of evidence)."""
    x = np.array([0.5, 0.5, -1.0])
    z = np.array([3.0, 0.4])
    R = np.diag([0.1**2, 0.02**2])
    mu, Sigma = initialise_landmark(x, z, R)
    mu2, Sigma2, _ = update_landmark(mu, Sigma, x, z, R)
    np.testing.assert_allclose(mu2, mu, atol=1e-12)
    np.testing.assert_allclose(Sigma2, Sigma / 2, rtol=1e-10)


# -- properties (hypothesis) ----------------------------------------------------------------


@st.composite
def ekf_inputs(draw):
    f = st.floats(-1.0, 1.0, allow_nan=False)
    x = np.array([draw(st.floats(-10, 10)), draw(st.floats(-10, 10)), draw(st.floats(-4, 4))])
    dist = draw(st.floats(0.1, 10.0))
    bearing = draw(st.floats(-np.pi, np.pi))
    a = x[2] + bearing
    mu = x[:2] + dist * np.array([np.cos(a), np.sin(a)])
    A = np.array([[draw(f), draw(f)], [draw(f), draw(f)]])
    Sigma = A @ A.T + draw(st.floats(1e-4, 1.0)) * np.eye(2)
    R = np.diag([draw(st.floats(1e-3, 0.5)) ** 2, draw(st.floats(1e-3, 0.3)) ** 2])
    z = np.array([dist + draw(st.floats(-0.5, 0.5)), bearing + draw(st.floats(-0.5, 0.5))])
    z[0] = abs(z[0])
    seed = draw(st.integers(0, 2**32 - 1))
    return mu, Sigma, x, z, R, seed


def is_spd(S):
    return np.allclose(S, S.T, rtol=0, atol=0) and np.all(np.linalg.eigvalsh(S) > 0)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(ekf_inputs())
def test_update_keeps_spd_and_never_loses_information(inputs):
    mu, Sigma, x, z, R, _ = inputs
    _, Sigma_new, loglik = update_landmark(mu, Sigma, x, z, R)
    assert is_spd(Sigma_new)
    assert np.linalg.det(Sigma_new) <= np.linalg.det(Sigma) * (1 + 1e-9)
    assert np.isfinite(loglik)


@settings(max_examples=200, deadline=None, derandomize=True)
@given(ekf_inputs())
def test_repeated_updates_keep_spd(inputs):
    mu, Sigma, x, z, R, seed = inputs
    rng = np.random.default_rng(seed)
    m_true = mu.copy()
    dx, dy = m_true - x[:2]
    z_true = np.array([np.hypot(dx, dy), np.arctan2(dy, dx) - x[2]])
    det = np.linalg.det(Sigma)
    for _ in range(10):
        z = z_true + rng.normal(0.0, np.sqrt(np.diag(R)))
        z[0] = abs(z[0])
        mu, Sigma, _ = update_landmark(mu, Sigma, x, z, R)
        assert is_spd(Sigma)
        new_det = np.linalg.det(Sigma)
        assert new_det <= det * (1 + 1e-9)
        det = new_det


# -- bad input ---------------------------------------------------------------------------------


def test_bad_inputs_rejected():
    x = np.array([0.0, 0.0, 0.0])
    mu = np.array([2.0, 1.0])
    z = np.array([2.2, 0.4])
    S = np.eye(2) * 0.1
    R = np.diag([0.01, 0.001])
    with pytest.raises(ValueError, match=r"update_landmark: mu contains a non-finite"):
        update_landmark([np.nan, 1.0], S, x, z, R)
    with pytest.raises(ValueError, match=r"update_landmark: Sigma must be symmetric positive def"):
        update_landmark(mu, np.array([[1.0, 2.0], [2.0, 1.0]]), x, z, R)
    with pytest.raises(ValueError, match=r"positive definite, but at batch index \(1,\)"):
        update_landmark(mu, np.stack((S, -S)), x, z, R)
    with pytest.raises(ValueError, match=r"update_landmark: R must be symmetric"):
        update_landmark(mu, S, x, z, np.diag([0.01, 0.0]))
    with pytest.raises(ValueError, match=r"lies on the robot"):
        update_landmark([0.0, 0.0], S, x, z, R)
    with pytest.raises(ValueError, match=r"initialise_landmark: range r = 0\.0 m"):
        initialise_landmark(x, [0.0, 0.3], R)
    with pytest.raises(ValueError, match=r"initialise_landmark: z contains a non-finite"):
        initialise_landmark(x, [np.inf, 0.3], R)
    with pytest.raises(ValueError, match=r"gaussian_log_likelihood: Q must be symmetric"):
        gaussian_log_likelihood([0.0, 0.0], np.zeros((2, 2)))


# -- added: innovation statistics, correlated noise, refusals -----------------------------------


def test_innovation_statistics_match_filterpy(cases):
    """ν and d² = νᵀQ⁻¹ν against filterpy's residual y and Mahalanobis distance (±π cases included)."""
    (mu, Sigma, x, z, R), _ = cases
    nu, d2 = innovation_statistics(mu, Sigma, x, z, R)
    assert nu.shape == (len(mu), 2) and d2.shape == (len(mu),)
    for i in range(len(mu)):
        ekf = ExtendedKalmanFilter(dim_x=2, dim_z=2)
        ekf.x, ekf.P, ekf.R = mu[i].reshape(2, 1).copy(), Sigma[i].copy(), R[i].copy()
        ekf.update(z[i].reshape(2, 1), H_by_hand, h_by_hand, args=(x[i],), hx_args=(x[i],),
                   residual=residual_by_hand)
        np.testing.assert_allclose(nu[i], ekf.y.ravel(), rtol=0, atol=1e-12)
        assert abs(d2[i] - ekf.mahalanobis**2) <= 1e-9 * max(1.0, d2[i]), i


def test_correlated_measurement_noise_matches_filterpy():
    """R with off-diagonal terms (correlated range and bearing errors): μ', Σ', log w as filterpy."""
    rng = np.random.default_rng(15)
    mu, Sigma, x, z, R = random_cases(rng, 40)
    rho = rng.uniform(-0.8, 0.8, 40)
    R[:, 0, 1] = R[:, 1, 0] = rho * np.sqrt(R[:, 0, 0] * R[:, 1, 1])
    mu_new, Sigma_new, loglik = update_landmark(mu, Sigma, x, z, R)
    for i in range(40):
        ref_mu, ref_P, ref_ll, _ = filterpy_update(mu[i], Sigma[i], x[i], z[i], R[i])
        np.testing.assert_allclose(mu_new[i], ref_mu, rtol=0, atol=1e-9)
        np.testing.assert_allclose(Sigma_new[i], ref_P, rtol=0, atol=1e-9)
        assert abs(loglik[i] - ref_ll) < 1e-9


def test_asymmetric_covariance_is_refused():
    """Σ with A₀₁ ≠ A₁₀ far beyond rounding is no covariance, even with A₀₀ > 0 and det > 0."""
    x, mu, z, R = np.zeros(3), np.array([2.0, 1.0]), np.array([2.2, 0.4]), np.diag([0.01, 0.001])
    with pytest.raises(ValueError, match=r"update_landmark: Sigma must be symmetric positive definite"):
        update_landmark(mu, np.array([[1.0, 0.5], [0.3, 1.0]]), x, z, R)


def test_update_landmark_textbook_refuses_batches():
    """The teaching version takes one landmark; a batch is refused with a pointer to update_landmark."""
    mu, Sigma, x, z, R = random_cases(np.random.default_rng(16), 2)
    with pytest.raises(ValueError, match="one landmark only"):
        update_landmark_textbook(mu, Sigma, x, z, R[0])
