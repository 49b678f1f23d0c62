"""The likelihood of one sighting given one landmark of one particle, with the drift of the particle's pose since
the landmark was last seen, and the likelihood :math:`p_0` of a landmark never seen before (Montemerlo et al. 2003;
*Probabilistic Robotics* §13.8). See :mod:`fastslam_edu.landmark.association`.
"""

from __future__ import annotations

import math

from numba import njit

from fastslam_edu.core.ekf import LOG_2PI, innovation_statistics_kernel, range_and_jacobian


# ---------------------------------------------------------------- one particle, one sighting


@njit(cache=True, _nrt=False)
def new_landmark_loglik(R, d0_sq):
    """:math:`\\log p_0`: a fresh landmark's Gaussian (:math:`Q = 2R`) at squared Mahalanobis distance ``d0_sq``."""
    det_2r = 4.0 * (R[0, 0] * R[1, 1] - 0.25 * (R[0, 1] + R[1, 0]) ** 2)
    return -0.5 * d0_sq - LOG_2PI - 0.5 * math.log(det_2r)


@njit(cache=True, _nrt=False)
def pose_jacobian(pose, mx, my):
    """:math:`H_x = \\partial h/\\partial x` (2, 3) of the range and bearing of a landmark at ``(mx, my)``, as
    ``(j0, j1, j2, k0, k1, k2)``: the range row, then the bearing row. A landmark moving by :math:`\\delta` and the
    robot moving by :math:`-\\delta` look the same, so the position columns are :math:`-H` of
    :func:`fastslam_edu.core.ekf.range_and_jacobian`; turning the robot by :math:`\\delta\\theta` turns the
    bearing by :math:`-\\delta\\theta`."""
    _, h00, h01, h10, h11 = range_and_jacobian(pose, (mx, my))
    return -h00, -h01, 0.0, -h10, -h11, -1.0


@njit(cache=True, _nrt=False)
def pose_term(pose, mx, my, cloud, v_xy, v_theta):
    """:math:`H_x P H_x^\\top` (``a, b, d``: entries 00, 01, 11) for a landmark at ``(mx, my)``: the pose
    covariance :math:`P` = ``cloud`` (3, 3) of the particle set plus the drift
    :math:`\\mathrm{diag}(v_{xy}, v_{xy}, v_\\theta)` (:func:`drift_variances`; :func:`drift_covariance` as numbers,
    without an array) carried into measurement space."""
    j0, j1, j2, k0, k1, k2 = pose_jacobian(pose, mx, my)
    drift = (v_xy, v_xy, v_theta)
    a = b = d = 0.0
    for u, cu, ku in ((0, j0, k0), (1, j1, k1), (2, j2, k2)):
        for v, cv, kv in ((0, j0, k0), (1, j1, k1), (2, j2, k2)):
            c = cloud[u, v] + drift[u] if u == v else cloud[u, v]
            a += cu * c * cv
            b += cu * c * kv
            d += ku * c * kv
    return a, b, d


@njit(cache=True, inline="always")
def drift_variances(unseen_s, rules):
    """The variances the pose drifts by over ``unseen_s`` seconds, at most ``rules.drift_cap_s``:
    :math:`(\\sigma_{xy}^2, \\sigma_\\theta^2)\\,\\min(\\Delta t, T)` [m² per axis, rad²]."""
    unseen_s = min(unseen_s, rules.drift_cap_s)
    return rules.drift_xy ** 2 * unseen_s, rules.drift_theta ** 2 * unseen_s


@njit(cache=True, _nrt=False)
def drift_covariance(cloud, unseen_s, rules, out):
    """:math:`P`, written into ``out`` (3, 3): ``cloud`` (3, 3) plus the drift of the pose over ``unseen_s`` seconds,
    :math:`\\mathrm{diag}(\\sigma_{xy}^2, \\sigma_{xy}^2, \\sigma_\\theta^2)\\,\\min(\\Delta t, T)`
    (:func:`drift_variances`)."""
    for u in range(3):
        for v in range(3):
            out[u, v] = cloud[u, v]
    v_xy, v_theta = drift_variances(unseen_s, rules)
    out[0, 0] += v_xy
    out[1, 1] += v_xy
    out[2, 2] += v_theta


@njit(cache=True, _nrt=False)
def innovation_with_pose(pose, z, R, mu, sigma, P, rules, v_xy, v_theta):
    """The innovation of one sighting and landmark with the pose covariance ``P`` (3, 3) added (and the drift
    ``v_xy``, ``v_theta`` of :func:`pose_term`): ``(nu0, nu1, q00, q01, q11)``, :math:`\\nu` and
    :math:`Q + H_x P H_x^\\top` (its range variance scaled by ``rules.range_scale`` squared)."""
    nu0, nu1, h00, h01, h10, h11, q00, q01, q11, d2, ll = innovation_statistics_kernel(pose, z, R, mu, sigma)
    a, b, d = pose_term(pose, mu[0], mu[1], P, v_xy, v_theta)
    return nu0, nu1, q00 + a - (1.0 - rules.range_scale ** 2) * R[0, 0], q01 + b, q11 + d


#: The factor by which :func:`outside_gate` widens its bounds, so that round-off never rules out a pair the gate
#: itself would keep.
RANGE_GATE_MARGIN = 1.0 + 1e-6


@njit(cache=True, _nrt=False)
def outside_range_bound(nu_r, R, sigma, cloud, v_xy, rules):
    """:func:`outside_gate`'s test on the range alone, whatever the bearing: True when the range innovation
    ``nu_r`` = :math:`\\nu_r = r - \\hat r` [m] is too large for the landmark of covariance ``sigma`` (2, 2).

    For any 2×2 covariance :math:`Q`, :math:`\\nu^\\top Q^{-1} \\nu \\ge \\nu_r^2 / Q_{rr}` (the squared distance
    of one component alone is never larger). The range row of :math:`H` is a unit vector, so
    :math:`(H\\Sigma H^\\top)_{rr} \\le \\operatorname{tr}\\Sigma`, and that of :math:`H_x` has a unit :math:`(x, y)`
    part and no :math:`\\theta` part, so :math:`(H_x P H_x^\\top)_{rr} \\le P_{xx} + P_{yy}` (``cloud`` (3, 3) plus
    the drift ``v_xy`` of :func:`drift_covariance`). Hence :math:`d^2 > d_0^2` whenever
    :math:`\\nu_r^2 > d_0^2\\,(\\operatorname{tr}\\Sigma + s^2 R_{rr} + P_{xx} + P_{yy})`, with a margin of
    :data:`RANGE_GATE_MARGIN` for round-off."""
    bound = (sigma[0, 0] + sigma[1, 1] + rules.range_scale ** 2 * R[0, 0] + cloud[0, 0] + cloud[1, 1]
             + 2.0 * v_xy)
    return nu_r * nu_r > RANGE_GATE_MARGIN * rules.new_chi2 * bound


@njit(cache=True, _nrt=False)
def outside_bearing_bound(dx, dy, r, direction, R, sigma, cloud, v_xy, v_theta, rules):
    """:func:`outside_gate`'s test on the bearing alone, whatever the range, without the arctangent of
    :math:`\\hat\\phi`: True when the sighting's ``direction`` (2,) is too far from that of the landmark,
    ``(dx, dy)`` = :math:`\\delta` [m] away at range ``r`` = :math:`\\hat r` (False when :math:`\\hat r = 0`).

    :math:`d^2 \\ge \\nu_\\phi^2 / Q_{\\phi\\phi}`. The bearing row of :math:`H` has norm :math:`1/\\hat r`, so
    :math:`(H\\Sigma H^\\top)_{\\phi\\phi} \\le \\operatorname{tr}\\Sigma/\\hat r^2`; that of :math:`H_x` is
    :math:`(w, -1)` with :math:`|w| = 1/\\hat r`, and a variance of a sum is at most the square of the sum of the
    standard deviations: :math:`(H_x P H_x^\\top)_{\\phi\\phi} \\le (\\sqrt{P_{xx} + P_{yy}}/\\hat r +
    \\sqrt{P_{\\theta\\theta}})^2` (``cloud`` (3, 3) plus the drift ``v_xy``, ``v_theta``). With :math:`B` the sum
    of the bounds and :math:`R_{\\phi\\phi}`, the pair is outside when :math:`|\\nu_\\phi| > \\nu_{\\max} =
    \\sqrt{d_0^2 B}`. The unit vectors to the landmark and along the sighting give :math:`\\cos\\nu_\\phi` (their dot
    product) and :math:`|\\sin\\nu_\\phi|` (their cross product); :math:`|\\nu_\\phi| \\ge |\\sin\\nu_\\phi|`, and
    :math:`|\\nu_\\phi| > \\pi/2` when :math:`\\cos\\nu_\\phi < 0`: either shows :math:`|\\nu_\\phi| > \\nu_{\\max}`
    (margin :data:`RANGE_GATE_MARGIN`)."""
    if r == 0.0:
        return False
    pose_part = math.sqrt(cloud[0, 0] + cloud[1, 1] + 2.0 * v_xy) / r + math.sqrt(cloud[2, 2] + v_theta)
    bound = (sigma[0, 0] + sigma[1, 1]) / (r * r) + R[1, 1] + pose_part * pose_part
    nu_max = math.sqrt(RANGE_GATE_MARGIN * rules.new_chi2 * bound)
    cos_nu = (dx * direction[0] + dy * direction[1]) / r
    sin_nu = abs(dy * direction[0] - dx * direction[1]) / r
    return sin_nu > nu_max or (cos_nu < 0.0 and nu_max < 0.5 * math.pi)


@njit(cache=True, _nrt=False)
def outside_gate(pose, z, direction, R, mu, sigma, cloud, unseen_s, rules):
    """True when sighting ``z`` (2,), seen along ``direction`` = :math:`(\\cos\\alpha, \\sin\\alpha)`,
    :math:`\\alpha = \\phi + \\theta` its bearing in the world frame, cannot fall within the gate :math:`d_0^2`
    (``rules.new_chi2``) of the landmark at ``mu`` (2,), ``sigma`` (2, 2): a test on its range alone
    (:func:`outside_range_bound`), then on its bearing alone (:func:`outside_bearing_bound`), a few multiplications
    instead of :func:`association_loglik`'s innovation. Both bounds share :math:`\\delta = \\mu - (x, y)`,
    :math:`\\hat r = |\\delta|` [m] and the drift :math:`(v_{xy}, v_\\theta)` of :func:`drift_variances`, computed
    once here. The pairs it rules out are pairs the gate rules out (margin :data:`RANGE_GATE_MARGIN` for round-off).
    """
    dx, dy = mu[0] - pose[0], mu[1] - pose[1]
    r = math.sqrt(dx * dx + dy * dy)
    v_xy, v_theta = drift_variances(unseen_s, rules)
    return (outside_range_bound(z[0] - r, R, sigma, cloud, v_xy, rules)
            or outside_bearing_bound(dx, dy, r, direction, R, sigma, cloud, v_xy, v_theta, rules))


@njit(cache=True, _nrt=False)
def association_loglik(pose, z, R, mu, sigma, cloud, unseen_s, rules):
    """What the association decides by, for one landmark: ``(loglik, d2)`` of the sighting with
    :math:`Q + H_x P H_x^\\top`, the pose uncertainty added to the innovation covariance.

    :math:`P` is ``cloud`` (the particle set's covariance, scaled; zeros: table 13.1's) plus the drift
    the particle's pose may have made relative to the landmark since it was last seen, ``unseen_s``
    seconds ago (:func:`drift_covariance`: ``rules.drift_xy``, ``rules.drift_theta`` per √s, for at most
    ``rules.drift_cap_s``).
    """
    v_xy, v_theta = drift_variances(unseen_s, rules)
    nu0, nu1, q00, q01, q11 = innovation_with_pose(pose, z, R, mu, sigma, cloud, rules, v_xy, v_theta)
    det_q = q00 * q11 - q01 * q01
    d2 = (q11 * nu0 * nu0 - 2.0 * q01 * nu0 * nu1 + q00 * nu1 * nu1) / det_q
    return -0.5 * d2 - LOG_2PI - 0.5 * math.log(det_q), d2


__all__ = ["new_landmark_loglik", "pose_jacobian", "pose_term", "drift_variances", "drift_covariance",
           "innovation_with_pose", "RANGE_GATE_MARGIN", "outside_gate", "outside_range_bound", "outside_bearing_bound",
           "association_loglik"]
