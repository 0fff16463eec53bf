"""The particle field :func:`bmctl.moments.equations.raw_rates` on numpy, vectorised over its quadrature nodes.

:func:`~bmctl.moments.equations.raw_rates` is written once for numpy and casadi, node by node and pair
by pair: on numpy that is about 1500 small array operations per call, whose per-call overhead,
not the arithmetic, is what a batch of a few hundred states costs (the global search calls the field
about 500 times in a row per batch of candidates). :func:`raw_rates_np` evaluates the same field
with the size nodes, the size pairs, the split nodes, the contact bins and the rounding bins as
array axes: every element sees the same floating-point operations in the same order, so the result
is bit-identical (sums over nodes run left to right as Python's ``sum`` does, with
explicit additions; exp and log are numpy's for both). ``tests/moments/test_npfield.py`` checks
the identity bit by bit; a change of :func:`~bmctl.moments.equations.raw_rates` must be made here too.
"""

from __future__ import annotations

import math

import numpy as np

from . import equations as eq
from .numerics import GH_T, GH_W, GL_WH, GL_XH, N_S
from .physics import EXP_RATE, UM

_PAIRS = [(i, j) for i in range(N_S) for j in range(i, N_S)]
_PI = np.array([i for i, _ in _PAIRS])
_PJ = np.array([j for _, j in _PAIRS])
_P2 = np.array([1.0 if i == j else 2.0 for i, j in _PAIRS])
# Q[k] collects p of every pair that contains k, in the order raw_rates adds them (Q[i] then Q[j])
_QSEQ = [[] for _ in range(N_S)]
for _n, (_i, _j) in enumerate(_PAIRS):
    _QSEQ[_i].append(_n)
    _QSEQ[_j].append(_n)
_QIDX = np.array(_QSEQ).T  # (6, N_S)
_HALF = N_S // 2
# the split nodes x and 1 - x of each GL_XH node, as fragment_tables forms them
_FX = [(x, 1 - x) for x in GL_XH]
_FRAG_X = np.array([v for pr in _FX for v in pr])
_FRAG_SQ = np.array([math.sqrt(x) for x in GL_XH for x in (x, 1 - x)])  # math.sqrt(x), math.sqrt(1 - x)
_FRAG_C = np.array([2 * math.sqrt(x * (1 - x)) / math.pi for x in GL_XH for _ in range(2)])


_COLS: dict = {}


def _col(vals, nd: int) -> np.ndarray:
    """Constants along a leading axis, broadcastable against arrays of ``nd`` trailing dimensions."""
    key = (tuple(float(v) for v in vals), nd)
    a = _COLS.get(key)
    if a is None:
        a = _COLS[key] = np.asarray(vals, dtype=float).reshape((-1,) + (1,) * nd)
        a.flags.writeable = False
    return a


def _sum0(A: np.ndarray) -> np.ndarray:
    """sum(A[0], A[1], ...) as Python's ``sum`` forms it (0 + A[0] + A[1] + ..., left to right)."""
    r = A[0] + 0.0
    for k in range(1, A.shape[0]):
        r = r + A[k]
    return r


def _smax(a, lo, eps):
    d = a - lo
    return lo + 0.5 * (d + np.sqrt(d * d + eps * eps))


def _smin(a, hi, eps):
    d = hi - a
    return hi - 0.5 * (d + np.sqrt(d * d + eps * eps))


def _sat(q):
    q2 = q * q
    return q / np.sqrt(np.sqrt(1.0 + q2 * q2))


def usable(*xs) -> bool:
    """True when the fast path applies: plain numbers and float arrays, at least one of them an array."""
    nd = False
    for v in xs:
        if isinstance(v, np.ndarray):
            if v.dtype != np.float64:
                return False
            nd = nd or v.ndim >= 1
        elif not isinstance(v, (float, int, np.floating)):
            return False
    return nd


def _link(beta, rm, v_r, sig_ln, nd: int):
    """``link`` of raw_rates for L slopes at once: beta (L, ...) -> per-node arrays (N_S, L, ...)."""
    k = -beta * sig_ln  # (L, ...)
    half = np.exp(k * _col(GH_T[_HALF + 1:], nd + 1))  # (2, L, ...)
    inv = 1.0 / half
    ev = np.concatenate([inv[::-1], np.ones(half[:1].shape), half])  # (N_S, L, ...)
    W = _col(GH_W, nd + 1)
    a_ = np.log(rm / (1 - rm))
    for _ in range(4):
        ea = np.exp(np.minimum(-a_, 600.0))
        sg = 1.0 / (1.0 + ea * ev)
        wsg = W * sg
        s1 = _sum0(wsg)
        fp = s1 - _sum0(wsg * sg)
        a_ = a_ - (s1 - rm) / (fp + 1e-9)
    ea = np.exp(np.minimum(-a_, 600.0))
    sg = 1.0 / (1.0 + ea * ev)
    nrm = _sum0(W * sg)  # (L, ...)
    rk = _smin(rm * sg / nrm, eq.R_HI, eq.R_EPS)
    Wrk = W * rk
    Er_nodes = _sum0(Wrk)
    var_between = _sum0(Wrk * rk) - Er_nodes * Er_nodes
    v_w = _smax(v_r - var_between, 0.05 * v_r, 1e-8)  # (L, ...)
    omk = 1.0 - rk
    omk2 = omk * omk
    Ef = 1.0 / omk + v_w / (omk2 * omk)
    den = omk2 + v_w
    r_b = (rk * omk2 + v_w) / den
    r2_b = (rk * rk * omk2 + v_w) / den
    one_r = omk * den / (omk2 + 3 * v_w)
    return rk, Er_nodes, v_w, Ef, r_b, r2_b, one_r


def raw_rates_np(c, q, m, sd, rm, rho, T, h, w, bm, fm):
    """:func:`bmctl.moments.equations.raw_rates` with ``B = NP`` (no events), bit for bit; see the module."""
    B = eq.NP
    nd = len(np.broadcast_shapes(*(np.shape(v) for v in (m, sd, rm, rho, T, h, w, bm, fm))))
    W = _col(GH_W, nd)
    var_ln = np.log(1.0 + (sd / m) ** 2)
    sig_ln = np.sqrt(var_ln)
    ws = _smax(w, 0.0, eq.RPM_SOFT)
    lw = np.log(ws)
    rate = c.rate_max_per_h * np.exp(EXP_RATE * lw)
    lratio = np.log(eq.strength_ratio(B, c, T, h))
    ln_ub = math.log(c.u_J_per_m) + c.n_bond * lratio
    ln_uc = math.log(c.u_J_per_m) - c.n_frac * lratio
    ln_e = math.log(c.e_max_J_per_um2) + 1.2 * lw
    ln_u_mean = math.log(c.u_mean_max_J) + 2.0 * lw
    ln_s = np.log(m) - 0.5 * var_ln + sig_ln * _col(GH_T, nd)  # (N_S, ...)
    s = np.exp(ln_s)
    om = 1.0 - rm
    v_r = rho * rho * rm * om

    k_cv, k_fcv = q.get("r_link_cv_slope", 0.0), q.get("frac_link_cv_shift", 0.0)
    lncv2 = None if eq._zero(k_cv) and eq._zero(k_fcv) else np.log(rho * rho * om / rm)
    beta = q["r_size_corr"] if eq._zero(k_cv) else q["r_size_corr"] + k_cv * lncv2
    shift = q["frac_link_shift"] if eq._zero(k_fcv) else q["frac_link_shift"] + k_fcv * lncv2
    sh = np.broadcast_shapes(np.shape(beta), np.shape(sig_ln), np.shape(rm))
    if eq._zero(shift):
        betas = np.broadcast_to(beta, sh)[None]
    else:
        betas = np.stack([np.broadcast_to(beta, sh), np.broadcast_to(beta + shift, sh)])
    rkL, ErL, vwL, EfL, rbL, r2bL, orL = _link(betas, rm, v_r, sig_ln, nd)
    rk, Er_nodes, v_w, Ef, r_b, r2_b, one_r = rkL[:, 0], ErL[0], vwL[0], EfL[:, 0], rbL[:, 0], r2bL[:, 0], orL[:, 0]
    f = -1 if ErL.shape[0] > 1 else 0
    Ef_f, r_b_f, r2_b_f, one_r_f = EfL[:, f], rbL[:, f], r2bL[:, f], orL[:, f]

    gamma, delta = c.gamma_per_um2 * bm, c.delta_per_um2 * fm
    cb = np.exp(q["bond_log_scale"] + q["bond_rpm_slope"] * (ws - 0.5))
    cf = np.exp(q["frac_log_scale"] + q["frac_rpm_slope"] * (ws - 0.5))
    ab, ob, ac, oc = q["bond_slope"], q["bond_offset"], q["frac_slope"], q["frac_offset"]
    ln_lam1 = (math.log(c.equiaxing * 1.5 * c.plastic_share / (math.pi / 4 * UM**3 * c.yield_Pa) + 1e-300)
               + q["round_log_scale"] + q["round_rpm_slope"] * (ws - 0.5) + ln_e - lratio
               + np.log(_smax(1.0 - c.equiaxing_hardening * h, 0.0, 0.02)))
    kap = q["round_size_bias"]

    # fracture: split nodes (x, 1 - x) x size nodes
    base_c, nac = ln_e - math.log(UM) - ln_uc, -ac
    c_split = [B.exp(ac * math.log(2 * math.sqrt(x * (1 - x)))) for x in GL_XH]
    inv = 1.0 / one_r_f  # fragment_tables
    g2 = 0.5 * q["frac_r_gain"]
    d = 1.0 - _col(_FRAG_SQ, nd + 1) / (_col(_FRAG_X, nd + 1) * inv + _col(_FRAG_C, nd + 1))  # (2 GL_XH, N_S, ...)
    r = g2 * (d + np.sqrt(d * d + 1e-4))
    lnL0 = base_c + ln_s
    q_k = delta * s * s * Ef_f
    e_k = np.exp(np.minimum(nac * lnL0 - oc, 600.0))
    pf = ds = dr = dr2 = 0.0
    for n, (x, wx, c_x) in enumerate(zip(GL_XH, GL_WH, c_split)):
        xx = x * (1 - x)
        r1, r2 = r[2 * n], r[2 * n + 1]
        p = wx * _sat(q_k * xx) / (1.0 + e_k * c_x)
        pf = pf + p
        ds = ds + p * (math.sqrt(x) + math.sqrt(1 - x) - 1.0)
        dr = dr + p * (r1 + r2)
        dr2 = dr2 + p * (r1 * r1 + r2 * r2)
    Pf = cf * pf
    dsf = cf * ds * s
    drf = cf * (dr - pf * r_b_f)
    dr2f = cf * (dr2 - pf * r2_b_f)
    lam = np.exp(ln_lam1 - ln_s - kap * var_ln)

    # bonding: the size pairs (i <= j) along one axis
    cn = c.contact_nodes
    uu = np.exp(ln_u_mean) * (3 * math.pi / (c.modulus_Pa * UM**3))
    nab, nc0 = -ab, -(ab * (ln_e - math.log(UM) - ln_ub) + ob)
    s2 = s * s
    s3 = s2 * s
    cap_m8 = (0.5 * math.pi) ** -8 / ((s2 * s2) * (s2 * s2))
    a34 = 0.75 * s
    gE = s * Ef
    gG = gamma * gE
    wsv = W * (1 - Pf)
    per = s / one_r
    si, sj = s[_PI], s[_PJ]
    s2n = s2[_PI] + s2[_PJ]
    s_new = np.sqrt(s2n)
    a_h = a34[_PI] * sj / (si + sj)  # _inv_contact
    d_h2 = a_h * a_h * uu / (s3[_PI] + s3[_PJ])
    d_h4 = d_h2 * d_h2
    S8 = np.sqrt(np.sqrt(np.sqrt(1.0 / (d_h4 * d_h4) + (cap_m8[_PI] + cap_m8[_PJ]))))
    lnL = np.log(s2n * S8)
    pb = _sat(gG[_PI] * gE[_PJ]) / (1.0 + np.exp(np.minimum(nab * lnL + nc0, 700.0)))
    p = pb * wsv[_PI] * wsv[_PJ]
    p = _col(_P2, nd) * p
    # eqn 18 over the contact bins (_bond_r_sums): bins along one more axis
    equal = eq._common_weight(cn) is not None
    perim = per[_PI] + per[_PJ]
    d_pi = (2 / math.pi) / S8
    v = 1.0 - s_new / (perim - d_pi * _col([fd for _, fd in cn], nd + 1))
    r2x = v + np.sqrt(v * v + 1e-4)
    if equal:
        rn1, rn2 = _sum0(r2x), _sum0(r2x * r2x)
    else:
        wd = _col([wd for wd, _ in cn], nd + 1)
        rn1, rn2 = _sum0(wd * r2x), _sum0(wd * (r2x * r2x))
    Q = _sum0(p[_QIDX])  # (N_S, ...)
    sb = _sum0(p * s_new)
    rb1 = _sum0(p * rn1)
    rb2 = _sum0(p * rn2)
    gb1, gb2 = eq._bond_r_scales(cn, q["bond_r_gain"])
    Pb_sum = cb * (0.5 * _sum0(Q))
    dsb = cb * (sb - _sum0(s * Q))
    drb = cb * (gb1 * rb1 - _sum0(r_b * Q))
    dr2b = cb * (gb2 * rb2 - _sum0(r2_b * Q))

    Pf_sum = _sum0(W * Pf)
    g_N = rate * (Pf_sum - 0.5 * Pb_sum)
    Es2 = m * m + sd * sd
    Er2 = rm * rm + v_r
    gv = q["r_var_gain"]
    zn = c.round_nodes
    e2k = rk * rk + v_w
    e2n = _sum0(W * e2k)
    w_z = sum(wz for wz, _ in zn)
    g1 = W * (rk / Er_nodes)
    g2 = W * (e2k / e2n)
    e1 = np.exp(lam * _col([-z for _, z in zn], nd + 1))  # (bins, N_S, ...)
    we = _col([wz for wz, _ in zn], nd + 1) * e1
    m1 = _sum0(we)
    m2 = _sum0(we * e1)
    round1 = _sum0(g1 * (w_z - m1))
    round2 = _sum0(g2 * (w_z - m2))
    round2 = round2 * np.exp(q["round_var_log_scale"] + q["round_var_rpm_slope"] * (ws - 0.5))
    dsf_sum = _sum0(W * dsf)
    dEs = rate * (0.5 * q["bond_ds_gain"] * dsb + q["frac_ds_gain"] * dsf_sum) - m * g_N
    dEs2 = -Es2 * g_N
    src1 = 0.5 * drb + _sum0(W * drf)
    dEr = rate * (src1 - round1 * rm) - rm * g_N
    src2 = 0.5 * dr2b + _sum0(W * dr2f)
    src2 = gv * src2 + (1 - gv) * 2 * rm * src1
    dEr2 = rate * (src2 - round2 * Er2) - Er2 * g_N
    return dEs, dEs2, dEr, dEr2
