"""Compiled twins (numba) of the `fu2018` and `elastic` steps: the same arithmetic in the same order.

Imported only when a model is built with ``kernel="compiled"`` (`load`), so `import prsm_sim`
does not pull numba in. Every function here mirrors a method of the reference path, named in its
docstring; the reference path stays the specification and tests/test_kernels.py holds the two
together (1e-12). Constants travel in two float arrays built by the models (`Fu2018._kernel_k`,
`Elastic._kernel_e`), not as globals: a global would be frozen into the on-disk cache.

Conventions: the `Forces` of an evaluation is a tuple of 29 floats in `Forces` field order; the
solver memory is 6 floats (j00, j01, j10, j11, sign, age) with sign 0 meaning empty (the reference
path's ``()``); flank signs are ±1.0.

Few, large functions with one signature each keep the first compile (a fresh clone, no cache)
short: numba compiles per function and signature.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# layout of the fu2018 constant array (`Fu2018._kernel_k`)
K_COULOMB, K_MU, K_MU_N, K_EPS_V2, K_EPS_W2, K_C_NT, K_MU_PIN_R, K_K_DRAG, K_MU_RR_R, K_NR, K_A, K_R_G = range(12)
(K_MP, K_I_S, K_I_C, K_MR_P, K_MR_KMIG, K_MR_A, K_J_SPIN, K_TAN_GEAR, K_G, K_S_1G, K_SPAN, K_ZBAR,
 K_NUT_SLIDES) = range(12, 25)
(K_H, K_H_MIN, K_H_ZONE, K_SLIP_TOL, K_EPS_V, K_KSS, K_KSC, K_KCC, K_JAC_REFRESH, K_SLIP_ZONE, K_BAL_TOL,
 K_BAL_FLOOR, K_P) = range(25, 38)
K_SIZE = 38

# layout of the elastic constant array (`Elastic._kernel_e`)
(E_P, E_M, E_MU, E_ZETA, E_SUBSTEPS, E_HS, E_BREAKAWAY, E_ETA_SF, E_ETA_SB, E_W_STICK, E_CZS, E_SIN_BETA, E_MU_C,
 E_ETA_RF, E_ETA_RB, E_D_MU, E_P_SB_VS, E_CLEARANCE, E_PRELOAD, E_LAW_A, E_LAW_B, E_EA, E_X_BEARING, E_C_HOUSING,
 E_D0, E_V0, E_M00, E_M01, E_M11, E_IMPACT_TOL, E_IMPACT_FLOOR, E_IMPACT_ITER) = range(32)
E_SIZE = 32

_NAN29 = (math.nan,) * 29


# -- fu2018 -------------------------------------------------------------------------------------
@njit(cache=True)
def solve(w_s, w_c, tau, load, sign, pin_abs, gear_sign, forces, stick_on, st0, st1, st2, st3, K, S):
    """`Fu2018._solve`: equations 1–7 eliminated to a 2×2 system; 29 floats (`Forces` order). Without
    `forces` only the accelerations are meaningful (the rest is NaN)."""
    row = S[0] if sign > 0.0 else S[1]
    g00, g01, g10, g11, g20, g21 = row[0], row[1], row[2], row[3], row[4], row[5]
    nsx, nsy, nsz, psx, psy, rsx, rsy = row[6], row[7], row[8], row[9], row[10], row[11], row[12]
    nnx, nny, nnz, rnx, rny = row[13], row[14], row[15], row[16], row[17]
    h00, h01, h10, h11, h20, h21 = row[18], row[19], row[20], row[21], row[22], row[23]
    mu, mu_n, eps_v2, eps_w2, c_nt = K[K_MU], K[K_MU_N], K[K_EPS_V2], K[K_EPS_W2], K[K_C_NT]
    mu_pin_r, k_drag, mu_rr_r, nr, a, r_g = K[K_MU_PIN_R], K[K_K_DRAG], K[K_MU_RR_R], K[K_NR], K[K_A], K[K_R_G]
    mp, i_s, i_c, mr_p, mr_kmig, mr_a = K[K_MP], K[K_I_S], K[K_I_C], K[K_MR_P], K[K_MR_KMIG], K[K_MR_A]
    j_spin, tan_gear, g, s_1g, span, zbar = K[K_J_SPIN], K[K_TAN_GEAR], K[K_G], K[K_S_1G], K[K_SPAN], K[K_ZBAR]
    vx = g00 * w_s + g01 * w_c
    vy = g10 * w_s + g11 * w_c
    vz = g20 * w_s + g21 * w_c
    f0x = f0y = f0z = 0.0
    if stick_on:
        esx, esy, esz = nsx + st0, nsy + st1, nsz + st2
    elif K[K_COULOMB] != 0.0:
        k = mu / math.sqrt(vx * vx + vy * vy + vz * vz + eps_v2)
        esx, esy, esz = nsx - k * vx, nsy - k * vy, nsz - k * vz
    else:
        esx, esy, esz = nsx, nsy, nsz
        f0x, f0y, f0z = -c_nt * vx, -c_nt * vy, -c_nt * vz
    if K[K_NUT_SLIDES] != 0.0:
        wx = h00 * w_s + h01 * w_c
        wy = h10 * w_s + h11 * w_c
        wz = h20 * w_s + h21 * w_c
    else:
        wx = wy = wz = 0.0
    if mu_n != 0.0 and not stick_on:
        kn = mu_n / math.sqrt(wx * wx + wy * wy + wz * wz + eps_v2)
        enx, eny, enz = nnx - kn * wx, nny - kn * wy, nnz - kn * wz
    else:
        enx, eny, enz = nnx, nny, nnz
    spin_n = rnx * eny - rny * enx
    mom_s = psx * esy - psy * esx
    mom_f0 = psx * f0y - psy * f0x
    spin_s = rsx * esy - rsy * esx
    spin_f0 = rsx * f0y - rsy * f0x
    s_c = w_c / math.sqrt(w_c * w_c + eps_w2) if not stick_on else st3
    m_pin = mu_pin_r * pin_abs * s_c
    m_drag = -k_drag * w_c
    mu_rr = mu_rr_r * s_c * s_1g
    alpha_n = mp / (nr * enz)
    beta_n = load / (nr * enz)
    alpha_s = -i_s / (nr * mom_s)
    beta_s = (tau - nr * mom_f0) / (nr * mom_s)
    rhs7 = -nr * m_pin + m_drag
    a11 = -mr_p - esz * alpha_s - enz * alpha_n
    a12 = mr_kmig
    b1 = f0z + esz * beta_s + enz * beta_n
    cs = r_g * esy - spin_s
    cn = r_g * eny - (spin_n - mu_rr)
    a21 = cs * alpha_s + cn * alpha_n
    a22 = j_spin
    b2 = spin_f0 + m_pin - r_g * f0y - r_g * rhs7 / (nr * a) - cs * beta_s - cn * beta_n
    det = a11 * a22 - a12 * a21
    acc_s = (b1 * a22 - a12 * b2) / det
    acc_c = (a11 * b2 - a21 * b1) / det
    if not forces:
        return (acc_s, acc_c) + _NAN29[2:]
    n_s = alpha_s * acc_s + beta_s
    n_n = alpha_n * acc_s + beta_n
    f_pt = (rhs7 - i_c * acc_c) / (nr * a)
    f_gt = mr_a * acc_c - esy * n_s - eny * n_n - f_pt - f0y
    tan_g = tan_gear * gear_sign
    f_pr = -mr_a * w_c * w_c - f0x - esx * n_s - enx * n_n + tan_g * f_gt
    fx, fy, fz = n_s * (esx - nsx) + f0x, n_s * (esy - nsy) + f0y, n_s * (esz - nsz) + f0z
    fnx, fny, fnz = n_n * (enx - nnx), n_n * (eny - nny), n_n * (enz - nnz)
    m_rr = -n_n * mu_rr
    sx, sy, sz = n_s * esx + f0x, n_s * esy + f0y, n_s * esz + f0z
    nx_, ny_, nz_ = n_n * enx, n_n * eny, n_n * enz
    m_x = rsy * sz - zbar * sy + rny * nz_ - zbar * ny_
    m_y = zbar * sx - rsx * sz + zbar * nx_ - rnx * nz_
    dx, dy = -2.0 * m_y / span, 2.0 * m_x / span
    diss = nr * (-(fx * vx + fy * vy + fz * vz) - (fnx * wx + fny * wy + fnz * wz) - m_pin * (-g * w_c)
                 - m_rr * ((1.0 - g) * w_c)) - m_drag * w_c
    return (acc_s, acc_c, diss, n_s, n_n, fx, fy, fz, vx, vy, vz, m_rr, f_gt, -tan_g * f_gt, f_pr, f_pt,
            m_pin, fnx, fny, fnz, math.sqrt(wx * wx + wy * wy + wz * wz), m_y,
            0.5 * (f_pr + dx), 0.5 * (f_pt + dy), 0.5 * (f_pr - dx), 0.5 * (f_pt - dy),
            m_drag, nr * n_n * enz, sign)


@njit(cache=True)
def solve_forces(w_s, w_c, tau, load, sign, pin_abs, gear_sign, K, S):
    """`Fu2018.solve_forces` while sliding: the other flank pair if a normal force comes out in tension."""
    f = solve(w_s, w_c, tau, load, sign, pin_abs, gear_sign, True, False, 0.0, 0.0, 0.0, 0.0, K, S)
    if f[3] < 0.0 or f[4] < 0.0:
        g = solve(w_s, w_c, tau, load, -sign, pin_abs, gear_sign, True, False, 0.0, 0.0, 0.0, 0.0, K, S)
        if g[3] >= 0.0 and g[4] >= 0.0:
            f = g
    return f


@njit(cache=True)
def _pin_sum(f):
    """`Forces.pin_force_sum_n`."""
    return math.sqrt(f[22] * f[22] + f[23] * f[23]) + math.sqrt(f[24] * f[24] + f[25] * f[25])


@njit(cache=True)
def _stick(tau, load, sign, pin_abs, gear_sign, K, S):
    """`Fu2018._stick`: (found, forces, r)."""
    mu, mu_pin_r, mu_rr_r, nr, a, r_g, s_1g = K[K_MU], K[K_MU_PIN_R], K[K_MU_RR_R], K[K_NR], K[K_A], K[K_R_G], \
        K[K_S_1G]
    cands = np.empty(5)
    for sg in (sign, -sign):
        row = S[0] if sg > 0.0 else S[1]
        g00, g01, g10, g11, g20, g21 = row[0], row[1], row[2], row[3], row[4], row[5]
        nsx, nsy, nsz, psx, psy, rsx, rsy = row[6], row[7], row[8], row[9], row[10], row[11], row[12]
        nnx, nny, nnz, rnx, rny = row[13], row[14], row[15], row[16], row[17]
        n_n = load / (nr * nnz)
        spin_n = rnx * nny - rny * nnx
        k = r_g - rsx
        a00, a01, a02 = nr * (psx * nsy - psy * nsx), nr * (psx * g10 - psy * g00), nr * (psx * g11 - psy * g01)
        a10, a11, a12 = nsz, g20, g21
        a20, a21, a22 = k * nsy + rsy * nsx, k * g10 + rsy * g00, k * g11 + rsy * g01
        # `_solve3` (Cramer) for the two right-hand sides
        c00, c01, c02 = a11 * a22 - a12 * a21, a12 * a20 - a10 * a22, a10 * a21 - a11 * a20
        det = a00 * c00 + a01 * c01 + a02 * c02
        if det == 0.0 or not math.isfinite(det):
            continue
        b0, b1, b2 = tau, -nnz * n_n, -(r_g * nny - spin_n) * n_n
        x00 = (b0 * c00 + b1 * (a02 * a21 - a01 * a22) + b2 * (a01 * a12 - a02 * a11)) / det
        x01 = (b0 * c01 + b1 * (a00 * a22 - a02 * a20) + b2 * (a02 * a10 - a00 * a12)) / det
        x02 = (b0 * c02 + b1 * (a01 * a20 - a00 * a21) + b2 * (a00 * a11 - a01 * a10)) / det
        b0, b1, b2 = 0.0, 0.0, mu_pin_r * pin_abs * (1.0 + r_g / a) - mu_rr_r * s_1g * n_n
        x10 = (b0 * c00 + b1 * (a02 * a21 - a01 * a22) + b2 * (a01 * a12 - a02 * a11)) / det
        x11 = (b0 * c01 + b1 * (a00 * a22 - a02 * a20) + b2 * (a02 * a10 - a00 * a12)) / det
        x12 = (b0 * c02 + b1 * (a01 * a20 - a00 * a21) + b2 * (a00 * a11 - a01 * a10)) / det
        q00, q01, q02 = g00 * x01 + g01 * x02, g10 * x01 + g11 * x02, g20 * x01 + g21 * x02
        q10, q11_, q12 = g00 * x11 + g01 * x12, g10 * x11 + g11 * x12, g20 * x11 + g21 * x12
        mu2 = mu * mu
        d01 = q00 * q10 + q01 * q11_ + q02 * q12
        q11 = q10 * q10 + q11_ * q11_ + q12 * q12
        qa = q11 - mu2 * x10 * x10
        qb = 2.0 * (d01 - mu2 * x00 * x10)
        cands[0], cands[1], cands[2] = -1.0, 1.0, 0.0
        nc = 3
        if q11 > 0.0:
            cands[nc] = max(-1.0, min(1.0, -d01 / q11))
            nc += 1
        if qa > 0.0:
            cands[nc] = max(-1.0, min(1.0, -qb / (2.0 * qa)))
            nc += 1
        best = math.inf
        sig = n_s = qq0 = qq1 = qq2 = 0.0
        for i in range(nc):
            s_ = cands[i]
            n_ = x00 + s_ * x10
            if n_ > 0.0:
                t0, t1, t2 = q00 + s_ * q10, q01 + s_ * q11_, q02 + s_ * q12
                r_ = (t0 * t0 + t1 * t1 + t2 * t2) / (n_ * n_)
                if r_ < best:
                    best, sig, n_s, qq0, qq1, qq2 = r_, s_, n_, t0, t1, t2
        if best == math.inf:
            continue
        f = solve(0.0, 0.0, tau, load, sg, pin_abs, gear_sign, True, True, qq0 / n_s, qq1 / n_s, qq2 / n_s, sig,
                  K, S)
        if f[3] >= 0.0 and f[4] >= 0.0 and math.isfinite(f[3]):
            mag = math.sqrt(qq0 * qq0 + qq1 * qq1 + qq2 * qq2) / n_s
            return True, f, (mag / mu if mu > 0 else (0.0 if mag == 0.0 else math.inf))
    return False, _NAN29, math.inf


@njit(cache=True)
def stick_forces(tau, load, sign, pin_abs, gear_sign, K, S):
    """`Fu2018.stick_forces`: (found, forces, r)."""
    ok, f, r = _stick(tau, load, sign, pin_abs, gear_sign, K, S)
    if ok:
        ps = _pin_sum(f)
        if abs(ps - pin_abs) > 0.01 * ps:
            ok, f, r = _stick(tau, load, f[28], ps, gear_sign, K, S)
    return ok, f, r


@njit(cache=True)
def rosenbrock(ws, wc, flank_sign, pin_abs, gear_force, mem, tau, load, h, K, S):
    """`Fu2018._rosenbrock`: (ω_S, ω_C, end forces, start forces, memory)."""
    gsign = 1.0 if gear_force >= 0.0 else -1.0
    f0 = solve_forces(ws, wc, tau, load, flank_sign, pin_abs, gsign, K, S)
    ps = _pin_sum(f0)
    if abs(ps - pin_abs) > 1e-2 * ps:
        pin_abs = ps
        f0 = solve_forces(ws, wc, tau, load, f0[28], pin_abs, gsign, K, S)
    sign = f0[28]
    fs, fc = f0[0], f0[1]
    if mem[4] != 0.0 and mem[4] == sign and mem[5] < K[K_JAC_REFRESH]:
        j00, j01, j10, j11 = mem[0], mem[1], mem[2], mem[3]
        age = mem[5] + 1
    else:
        ds = 1e-6 * max(1.0, abs(ws))
        dc = 1e-6 * max(1.0, abs(wc))
        a = solve(ws + ds, wc, tau, load, sign, pin_abs, gsign, False, False, 0.0, 0.0, 0.0, 0.0, K, S)
        b = solve(ws, wc + dc, tau, load, sign, pin_abs, gsign, False, False, 0.0, 0.0, 0.0, 0.0, K, S)
        j00, j10 = (a[0] - fs) / ds, (a[1] - fc) / ds
        j01, j11 = (b[0] - fs) / dc, (b[1] - fc) / dc
        age = 0.0
    gh = (1.0 + 1.0 / math.sqrt(2.0)) * h
    w00, w01, w10, w11 = 1.0 - gh * j00, -gh * j01, -gh * j10, 1.0 - gh * j11
    det = w00 * w11 - w01 * w10
    k1s = (w11 * fs - w01 * fc) / det
    k1c = (w00 * fc - w10 * fs) / det
    f2 = solve(ws + h * k1s, wc + h * k1c, tau, load, sign, pin_abs, gsign, False, False, 0.0, 0.0, 0.0, 0.0, K, S)
    r_s, r_c = f2[0] - 2.0 * k1s, f2[1] - 2.0 * k1c
    k2s = (w11 * r_s - w01 * r_c) / det
    k2c = (w00 * r_c - w10 * r_s) / det
    ws1 = ws + h * (1.5 * k1s + 0.5 * k2s)
    wc1 = wc + h * (1.5 * k1c + 0.5 * k2c)
    f1 = solve_forces(ws1, wc1, tau, load, sign, pin_abs, gsign, K, S)
    return ws1, wc1, f1, f0, (j00, j01, j10, j11, sign, age)


@njit(cache=True)
def _stored(ws, wc, K):
    return 0.5 * (K[K_KSS] * ws * ws + 2.0 * K[K_KSC] * ws * wc + K[K_KCC] * wc * wc)


@njit(cache=True)
def _books_open(ws, wc, ws1, wc1, f0, f1, h, tau, load, K):
    """`Fu2018._books_open`."""
    dth = 0.5 * h * (ws + ws1)
    w_in, w_out = tau * dth, load * K[K_P] * dth
    d_e = _stored(ws1, wc1, K) - _stored(ws, wc, K)
    diss = 0.5 * h * (f0[2] + f1[2])
    return abs(w_in - w_out - d_e - diss) > (K[K_BAL_TOL] * (abs(w_in) + abs(w_out) + abs(d_e) + abs(diss))
                                             + K[K_BAL_FLOOR])


_NO_MEM = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)


@njit(cache=True)
def step(ws, wc, sign, pin_abs, gear, mem, tau, load, K, S):
    """`Fu2018._step`: (ω_S, ω_C, Δθ_S, Δθ_C, dissipated J, end forces, sign, pin force, gear force, memory)."""
    h = K[K_H]
    zone2 = (K[K_SLIP_ZONE] * K[K_EPS_V]) ** 2
    if ws != 0.0 or wc != 0.0:
        ws1, wc1, f1, f0, m1 = rosenbrock(ws, wc, sign, pin_abs, gear, mem, tau, load, h, K, S)
        if not (ws * ws1 < 0.0 or wc * wc1 < 0.0 or f1[28] != f0[28] or f0[28] != sign
                or f0[8] * f0[8] + f0[9] * f0[9] + f0[10] * f0[10] < zone2
                or f1[8] * f1[8] + f1[9] * f1[9] + f1[10] * f1[10] < zone2
                or ws * (ws + h * f0[0]) < 0.0 or wc * (wc + h * f0[1]) < 0.0
                or _books_open(ws, wc, ws1, wc1, f0, f1, h, tau, load, K)):
            return (ws1, wc1, 0.5 * h * (ws + ws1), 0.5 * h * (wc + wc1), 0.5 * h * (f0[2] + f1[2]), f1, f1[28],
                    _pin_sum(f1), f1[12], m1)
    left = h
    hs = h
    dth_s = dth_c = diss = 0.0
    f_end = _NAN29
    wsa = wca = wsb = wcb = 0.0
    fa1 = fa0 = fb1 = fb0 = _NAN29
    ma = mb = _NO_MEM
    h_min, h_zone, slip_tol, eps_v = K[K_H_MIN], K[K_H_ZONE], K[K_SLIP_TOL], K[K_EPS_V]
    while left > 1e-9 * h:
        if ws == 0.0 and wc == 0.0:
            ok, st, r = stick_forces(tau, load, sign, pin_abs, 1.0 if gear >= 0.0 else -1.0, K, S)
            if ok and r <= 1.0:
                f_end, sign, gear, pin_abs = st, st[28], st[12], _pin_sum(st)
                break
        hs = min(hs, left)
        ws1, wc1, f1, f0, m1 = rosenbrock(ws, wc, sign, pin_abs, gear, mem if hs == h else _NO_MEM, tau, load,
                                          hs, K, S)
        # sub-steps to take: the full one, or its two halves (a, b)
        two = False
        if hs > h_min and (ws * ws1 < 0.0 or wc * wc1 < 0.0 or f1[28] != f0[28] or f0[28] != sign
                           or ws * (ws + hs * f0[0]) < 0.0 or wc * (wc + hs * f0[1]) < 0.0
                           or _books_open(ws, wc, ws1, wc1, f0, f1, hs, tau, load, K)
                           or (hs > h_zone
                               and (f0[8] * f0[8] + f0[9] * f0[9] + f0[10] * f0[10] < zone2
                                    or f1[8] * f1[8] + f1[9] * f1[9] + f1[10] * f1[10] < zone2))):
            wsa, wca, fa1, fa0, ma = rosenbrock(ws, wc, sign, pin_abs, gear, _NO_MEM, tau, load, 0.5 * hs, K, S)
            wsb, wcb, fb1, fb0, mb = rosenbrock(wsa, wca, fa1[28], _pin_sum(fa1), fa1[12], _NO_MEM, tau, load,
                                                0.5 * hs, K, S)
            err = math.sqrt((fb1[8] - f1[8]) ** 2 + (fb1[9] - f1[9]) ** 2 + (fb1[10] - f1[10]) ** 2)
            if err > slip_tol + 1e-6 * math.sqrt(fb1[8] ** 2 + fb1[9] ** 2 + fb1[10] ** 2):
                hs *= 0.5
                continue
            two = True
        grow = True
        for k in range(2 if two else 1):
            if not two:
                w0s, w0c, hk, w1s, w1c, g1, g0, mk = ws, wc, hs, ws1, wc1, f1, f0, m1
            elif k == 0:
                w0s, w0c, hk, w1s, w1c, g1, g0, mk = ws, wc, 0.5 * hs, wsa, wca, fa1, fa0, ma
            else:
                w0s, w0c, hk, w1s, w1c, g1, g0, mk = wsa, wca, 0.5 * hs, wsb, wcb, fb1, fb0, mb
            dth_s += 0.5 * hk * (w0s + w1s)
            dth_c += 0.5 * hk * (w0c + w1c)
            diss += 0.5 * hk * (g0[2] + g1[2])
            left -= hk
            ws, wc, sign, pin_abs, gear, mem, f_end = w1s, w1c, g1[28], _pin_sum(g1), g1[12], mk, g1
            v2 = g1[8] * g1[8] + g1[9] * g1[9] + g1[10] * g1[10]
            if w0s * w1s < 0.0 or w0c * w1c < 0.0 or v2 < zone2:
                ok, st, r = stick_forces(tau, load, sign, pin_abs, 1.0 if gear >= 0.0 else -1.0, K, S)
                if ok and r < 1.0 and (w0s * w1s < 0.0 or w0c * w1c < 0.0 or
                                       v2 <= (2.0 * eps_v * (1.0 + r / math.sqrt(1.0 - r * r))) ** 2):
                    diss += _stored(ws, wc, K)
                    ws = wc = 0.0
                    f_end, sign, gear, pin_abs, mem = st, st[28], st[12], _pin_sum(st), _NO_MEM
                    grow = False
                    break
        if grow and hs < h:
            hs *= 2.0
    return ws, wc, dth_s, dth_c, diss, f_end, sign, pin_abs, gear, mem


@njit(cache=True)
def fu2018_run(ws, wc, th_s, th_c, sign, pin_abs, gear, mem, tau_a, load_a, K, S, rows, comp):
    """`Fu2018.run`'s loop: fills rows (n × 8: ω_S, ω_C, θ_S, θ_C, Δθ_S, dissipated, slip, nut force) and
    comp (n × 26, `Forces.compact`); returns the final (ω_S, ω_C, θ_S, θ_C, W_in, W_out, dissipated, sign,
    pin force, gear force, memory)."""
    p = K[K_P]
    w_in = w_out = diss = 0.0
    for i in range(tau_a.shape[0]):
        tau, load = tau_a[i], load_a[i]
        ws, wc, dth, dthc, d, f1, sign, pin_abs, gear, mem = step(ws, wc, sign, pin_abs, gear, mem, tau, load, K, S)
        th_s += dth
        th_c += dthc
        w_in += tau * dth
        w_out += load * p * dth
        diss += d
        rows[i, 0], rows[i, 1], rows[i, 2], rows[i, 3], rows[i, 4], rows[i, 5] = ws, wc, th_s, th_c, dth, d
        rows[i, 6] = math.sqrt(f1[8] ** 2 + f1[9] ** 2 + f1[10] ** 2)
        rows[i, 7] = f1[27]
        for j in range(26):
            comp[i, j] = f1[3 + j]
    return ws, wc, th_s, th_c, w_in, w_out, diss, sign, pin_abs, gear, mem


# -- elastic --------------------------------------------------------------------------------------
@njit(cache=True)
def _power_root(d, a, b):
    """`elastic.power_law_root`: s = F^(1/3) with a s² + b s³ = d (its stopping rule: a relative step
    ≤ 1e-9, `elastic.ROOT_STEP_TOL`, leaves an error below rounding)."""
    if d <= 0.0:
        return 0.0
    if a == 0.0:
        return (d / b) ** (1.0 / 3.0)
    s = math.sqrt(d / a) if b == 0.0 or a * a * a >= d * b * b else (d / b) ** (1.0 / 3.0)
    for _ in range(60):
        r = a * s * s + b * s * s * s - d
        s_new = s - r / (2.0 * a * s + 3.0 * b * s * s)
        if abs(s_new - s) <= 1e-9 * s:
            return s_new
        s = s_new
    return s


@njit(cache=True)
def _stiffness_at_root(s, a, b):
    return 1.0 / ((2.0 / 3.0) * a / max(s, 1e-100) + b)


@njit(cache=True)
def _complementary_at_root(s, a, b):
    f = s * s * s
    return 0.6 * a * (s * s * s * s * s) + 0.5 * b * f * f


@njit(cache=True)
def law_evaluate(delta, x_n, extra, E):
    """`AxialLaw.evaluate`: (F, K, V, lost motion)."""
    ell = x_n - E[E_X_BEARING]
    c_ext = max(abs(ell), 1e-6) / E[E_EA] + E[E_C_HOUSING]
    a, b = E[E_LAW_A], E[E_LAW_B]
    if E[E_PRELOAD] > 0:
        d0 = E[E_D0]
        x = delta / 2.0
        for _ in range(60):
            ra, rb = _power_root(d0 + x, a, b), _power_root(d0 - x, a, b)
            qa, qb = ra * ra * ra, rb * rb * rb
            ka = _stiffness_at_root(ra, a, b) if qa > 0 else 0.0
            kb = _stiffness_at_root(rb, a, b) if qb > 0 else 0.0
            f = qa - qb
            r = x + f * c_ext - delta
            dx = -r / (1.0 + (ka + kb) * c_ext)
            x += dx
            if abs(dx) <= 1e-15 * max(abs(x), d0):
                break
        ra, rb = _power_root(d0 + x, a, b), _power_root(d0 - x, a, b)
        qa, qb = ra * ra * ra, rb * rb * rb
        ka = _stiffness_at_root(ra, a, b) if qa > 0 else 0.0
        kb = _stiffness_at_root(rb, a, b) if qb > 0 else 0.0
        f = qa - qb
        k_pair = ka + kb
        k = k_pair / (1.0 + k_pair * c_ext)
        va = qa * (d0 + x) - _complementary_at_root(ra, a, b)
        vb = (qb * (d0 - x) - _complementary_at_root(rb, a, b)) if qb > 0 else 0.0
        return f, k, va + vb - 2 * E[E_V0] + 0.5 * f * f * c_ext, 0.0
    half = 0.5 * (E[E_CLEARANCE] + extra)
    mag = abs(delta) - half
    if mag <= 0.0:
        return 0.0, 0.0, 0.0, delta
    bb = b + c_ext
    r = _power_root(mag, a, bb)
    f = r * r * r
    k = _stiffness_at_root(r, a, bb)
    v = f * mag - _complementary_at_root(r, a, bb)
    sgn = 1.0 if delta > 0 else -1.0
    return sgn * f, k, v, sgn * half


@njit(cache=True)
def _nut_side_force(force_n, x_n, E):
    s = 1.0 if x_n - E[E_X_BEARING] >= 0 else -1.0
    return 0.5 * force_n * force_n * (s / E[E_EA])


@njit(cache=True)
def _el_force(th_s, w_s, x_n, v_n, extra, E):
    """`Elastic._force`: (F + c δ̇, F, K, V, lost, δ, c)."""
    p = E[E_P]
    delta = p * th_s - x_n
    f, k, v, lost = law_evaluate(delta, x_n, extra, E)
    c = 2.0 * E[E_ZETA] * math.sqrt(k * E[E_MU]) if k > 0 else 0.0
    rate = p * w_s - v_n
    return f + c * rate, f, k, v, lost, delta, c


@njit(cache=True)
def _sliding_eff(czs, sb, mu):
    return 1.0 / (1.0 + mu / (sb * (czs - mu * sb))), 1.0 - mu / (sb * (czs + mu * sb))


@njit(cache=True)
def _excess(direction, thread_force_n, g, E):
    """`Elastic._excess`."""
    mu = E[E_MU_C] + E[E_D_MU] * g
    eta_f, eta_b = _sliding_eff(E[E_CZS], E[E_SIN_BETA], mu)
    t = abs(E[E_P] * thread_force_n)
    return t * (1.0 / eta_f - 1.0 / E[E_ETA_RF]) if direction * thread_force_n >= 0.0 else t * (E[E_ETA_RB] - eta_b)


@njit(cache=True)
def _stribeck_torque(ws, thread_force_n, E):
    """`Elastic._stribeck_torque`."""
    if E[E_BREAKAWAY] == 0.0 or ws == 0.0:
        return 0.0
    r = ws * E[E_P_SB_VS]
    g = math.exp(-r * r)
    if g < 1e-12:
        return 0.0
    ex = _excess(ws, thread_force_n, g, E)
    return ex if ws > 0.0 else -ex


@njit(cache=True)
def _rest_torque(torque_nm, thread_force_n, E):
    """`Elastic._rest_torque`."""
    d = torque_nm - E[E_P] * thread_force_n
    if E[E_BREAKAWAY] == 0.0 or d == 0.0:
        return torque_nm
    ex0 = _excess(d, thread_force_n, 1.0, E)
    return torque_nm - math.copysign(min(abs(d), ex0), d)


@njit(cache=True)
def _holds(torque_nm, thread_force_n, E):
    """`Elastic._holds`."""
    eta_f, eta_b = E[E_ETA_SF], E[E_ETA_SB]
    t = E[E_P] * thread_force_n
    if t >= 0:
        lo, hi = t * eta_b, t / eta_f
    else:
        lo, hi = t / eta_f, t * eta_b
    return lo <= torque_nm <= hi


@njit(cache=True)
def _core_kinetic(ws, wc, E):
    return 0.5 * (E[E_M00] * ws * ws + 2 * E[E_M01] * ws * wc + E[E_M11] * wc * wc)


@njit(cache=True)
def elastic_advance(th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, extra, torque_nm, load_n, E, K, S):
    """`Elastic._advance`'s sub-step loop: (θ_S, ω_S, θ_C, ω_C, x_N, v_N, sign, pin force, gear force,
    memory, acceleration, dissipated J, load work J, end forces (29), F, K, V, lost, δ, thread force,
    stored energy at the start and at the end (`Elastic.total_stored_energy_j`))."""
    hs, m, p = E[E_HS], E[E_M], E[E_P]
    breakaway = E[E_BREAKAWAY] != 0.0
    n_iter = int(E[E_IMPACT_ITER])
    diss = 0.0
    f_th, f_el0, k, v_el0, lost, delta, c0 = _el_force(th_s, ws, x_n, v_n, extra, E)
    e_start = _core_kinetic(ws, wc, E) + 0.5 * m * v_n ** 2.0 + v_el0
    w_out = 0.0
    f1 = _NAN29
    for _ in range(int(E[E_SUBSTEPS])):
        a_n = (f_th - load_n + _nut_side_force(f_el0, x_n, E)) / m
        x_mid = x_n + 0.5 * hs * v_n + 0.125 * hs * hs * a_n
        _, f_el, k_mid, _, _, _, c = _el_force(th_s + 0.5 * hs * ws + 0.125 * hs * hs * acc, ws + 0.5 * hs * acc,
                                               x_mid, v_n + 0.5 * hs * a_n, extra, E)
        rate = p * (ws + 0.5 * hs * acc) - (v_n + 0.5 * hs * a_n)
        f_str = _stribeck_torque(ws, f_el + c * rate, E)
        have = False
        # the best attempt (`best` of the reference path)
        b_err = b_f_el = b_c = b_rate = b_ws1 = b_wc1 = b_dth_s = b_dth_c = b_d_core = 0.0
        b_sign1 = b_pin1 = b_gear1 = b_v1 = b_dx = b_d_delta = b_f_el1 = b_k1 = b_v_el1 = b_lost1 = 0.0
        b_delta1 = b_c1 = b_f_mid = 0.0
        b_stuck = False
        b_f1 = _NAN29
        b_mem1 = _NO_MEM
        for attempt in range(n_iter + 1):
            f_mid = f_el + c * rate
            stuck = breakaway and ws == 0.0 and wc == 0.0 and _holds(torque_nm, f_mid, E)
            if stuck:
                ff = solve_forces(0.0, 0.0, torque_nm, f_mid, sign, pin_abs, 1.0 if gear >= 0 else -1.0, K, S)
                ws1, wc1, dth_s, dth_c, d_core = 0.0, 0.0, 0.0, 0.0, 0.0
                sign1, pin1, gear1, mem1 = sign, pin_abs, gear, mem
            else:
                if ws == 0.0 and wc == 0.0:
                    f_str = torque_nm - _rest_torque(torque_nm, f_mid, E)
                ws1, wc1, dth_s, dth_c, d_core, ff, sign1, pin1, gear1, mem1 = step(
                    ws, wc, sign, pin_abs, gear, mem, torque_nm - f_str, f_mid, K, S)
            nsf = _nut_side_force(f_el, x_mid, E)
            v1 = v_n + hs * (f_mid - load_n + nsf) / m
            dx = 0.5 * hs * (v_n + v1)
            d_delta = p * dth_s - dx
            _, f_el1, k1, v_el1, lost1, delta1, c1 = _el_force(th_s + dth_s, ws1, x_n + dx, v1, extra, E)
            err = f_el * d_delta + nsf * dx - (v_el1 - v_el0)
            if not have or abs(err) < abs(b_err):
                have = True
                b_err, b_f_el, b_c, b_rate, b_stuck, b_f1, b_ws1, b_wc1 = err, f_el, c, rate, stuck, ff, ws1, wc1
                b_dth_s, b_dth_c, b_d_core, b_sign1, b_pin1, b_gear1, b_mem1 = dth_s, dth_c, d_core, sign1, pin1, \
                    gear1, mem1
                b_v1, b_dx, b_d_delta, b_f_el1, b_k1, b_v_el1, b_lost1 = v1, dx, d_delta, f_el1, k1, v_el1, lost1
                b_delta1, b_c1, b_f_mid = delta1, c1, f_mid
            if (attempt == n_iter or abs(d_delta) < 1e-15
                    or abs(err) <= E[E_IMPACT_TOL] * abs(torque_nm * dth_s)
                    + E[E_IMPACT_FLOOR] * (abs(v_el1) + abs(v_el0))):
                break
            f_el = (v_el1 - v_el0 - nsf * dx) / d_delta
            rate = d_delta / hs
            kk = max(k_mid, k1)
            c = 2.0 * E[E_ZETA] * math.sqrt(kk * E[E_MU]) if kk > 0 else 0.0
        f_el, c, rate, stuck, f1, ws1, wc1 = b_f_el, b_c, b_rate, b_stuck, b_f1, b_ws1, b_wc1
        dth_s, dth_c, d_core, sign1, pin1, gear1, mem1 = b_dth_s, b_dth_c, b_d_core, b_sign1, b_pin1, b_gear1, b_mem1
        v1, dx, d_delta, f_el1, k1, v_el1, lost1 = b_v1, b_dx, b_d_delta, b_f_el1, b_k1, b_v_el1, b_lost1
        delta1, c1, f_mid = b_delta1, b_c1, b_f_mid
        diss += d_core + c * rate * d_delta + f_str * dth_s
        sign, pin_abs, gear, mem = sign1, pin1, gear1, mem1
        acc = (ws1 - ws) / hs
        th_s += dth_s
        th_c += dth_c
        if breakaway and not stuck and abs(ws1) < E[E_W_STICK]:
            holds = _holds(torque_nm, f_mid, E)
            if not holds:  # `Elastic._core_holds`
                ok, _st, r = stick_forces(_rest_torque(torque_nm, f_mid, E), f_mid, sign, pin_abs,
                                          1.0 if gear >= 0.0 else -1.0, K, S)
                holds = ok and r <= 1.0
            if holds:
                diss += _core_kinetic(ws1, wc1, E)
                ws1 = wc1 = acc = 0.0
                _, f_el1, k1, v_el1, lost1, delta1, c1 = _el_force(th_s, 0.0, x_n + dx, v1, extra, E)
        x_n += dx
        v_n = v1
        w_out += load_n * dx
        ws, wc = ws1, wc1
        f_el0, k, v_el0, lost, delta = f_el1, k1, v_el1, lost1, delta1
        f_th = f_el1 + c1 * (p * ws - v_n)
    # V at the end state is the last sub-step's (recomputed at the end state where the screw stuck)
    e_end = _core_kinetic(ws, wc, E) + 0.5 * m * v_n ** 2.0 + v_el0
    return (th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, diss, w_out, f1, f_el0, k, v_el0, lost,
            delta, f_th, e_start, e_end)


@njit(cache=True)
def elastic_run(th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, extra, ledger, tau_a, load_a, E, K, S,
                cols, comp):
    """`Model.run` over `Elastic._advance` and `Elastic._finish`: the loop and the ledger. Fills cols (n × 19:
    θ_S, ω_S, θ_C, ω_C, x_N, v_N, thread force, slip, W_in, W_out, dissipated, stored, flow, residual,
    then the chain's F, K, V, lost, δ) and comp (n × 26); `ledger` (W_in, W_out, dissipated, flow, residual)
    is updated in place. Returns the final (θ_S, ω_S, θ_C, ω_C, x_N, v_N, sign, pin, gear, memory, acc)."""
    for i in range(tau_a.shape[0]):
        tau, load = tau_a[i], load_a[i]
        th0 = th_s
        (th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, diss, w_out, f1, f_el, k, v_el, lost, delta,
         f_th, e0, e1) = elastic_advance(th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc, extra, tau, load,
                                         E, K, S)
        w_in = tau * (th_s - th0)
        ledger[0] += w_in
        ledger[1] += w_out
        ledger[2] += diss
        ledger[3] = ledger[3] + abs(w_in)
        ledger[4] = ledger[4] + (w_in - w_out - diss - (e1 - e0))
        cols[i, 0], cols[i, 1], cols[i, 2], cols[i, 3], cols[i, 4], cols[i, 5] = th_s, ws, th_c, wc, x_n, v_n
        cols[i, 6], cols[i, 7] = f_th, math.sqrt(f1[8] ** 2 + f1[9] ** 2 + f1[10] ** 2)
        cols[i, 8], cols[i, 9], cols[i, 10], cols[i, 11], cols[i, 12], cols[i, 13] = w_in, w_out, diss, e1, \
            ledger[3], ledger[4]
        cols[i, 14], cols[i, 15], cols[i, 16], cols[i, 17], cols[i, 18] = f_el, k, v_el, lost, delta
        for j in range(26):
            comp[i, j] = f1[3 + j]
    return th_s, ws, th_c, wc, x_n, v_n, sign, pin_abs, gear, mem, acc

