"""The moment model's particle field and RKC step on numpy, vectorised over the field's quadrature nodes.

:func:`~bmctl.moments.equations.raw_rates` is written once for numpy and casadi, node by node and pair
by pair: on numpy that is about 3000 small array operations per call, whose per-call overhead,
not the arithmetic, is what a batch of a few hundred states costs (the global search calls the field
about 500 times in a row per batch of candidates). :func:`raw_rates_np` evaluates the same field
with the size nodes, the size pairs, the split nodes, the contact bins and the rounding bins as
array axes (about 400 operations), and :func:`step_np` the RKC step of
:func:`~bmctl.moments.equations.step` with the four integration coordinates as one array. Every
element sees the same floating-point operations in the same order, so the results are
bit-identical: sums over nodes run left to right as Python's ``sum`` does, with explicit additions;
exp and log are numpy's in both; constants enter as arrays of the same values. ``equations.step``
and ``equations.raw_rates`` take this path on 1-D float batches (:func:`usable`);
``tests/moments/test_npfield.py`` checks the identity bit by bit. A change of
:func:`~bmctl.moments.equations.raw_rates`, :func:`~bmctl.moments.equations.y_to_state` or
:func:`~bmctl.moments.equations.step` must be made here too.
"""
from __future__ import annotations

import math

import numpy as np

from . import equations as eq
from .numerics import GH_T, GH_W, GL_WH, GL_XH, N_S
from .physics import EXP_RATE, UM
from ..heap import keep_heap  # noqa: F401  (the bmctl command's heap setting, re-exported)


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


def _c(vals, nd: int) -> np.ndarray:
    """Constants along a leading axis, broadcastable against arrays of ``nd`` trailing dimensions."""
    a = np.asarray(vals, dtype=float).reshape((-1,) + (1,) * nd)
    a.flags.writeable = False
    return a


# the field runs on 1-D batches (usable): node arrays are (nodes, n), pair-and-bin arrays (bins, pairs, n)
_GT = _c(GH_T, 1)
_W1, _W2 = _c(GH_W, 1), _c(GH_W, 2)
_THALF = _c(GH_T[_HALF + 1:], 2)
_FRAG_X, _FRAG_SQ, _FRAG_C = _c(_FRAG_X, 2), _c(_FRAG_SQ, 2), _c(_FRAG_C, 2)
_P2 = _c(_P2, 1)
_XX = _c([x * (1 - x) for x in GL_XH], 2)
_WX = _c(GL_WH, 2)
_KX = _c([math.sqrt(x) + math.sqrt(1 - x) - 1.0 for x in GL_XH], 2)
_NODES: dict = {}
# numbers as 0-d arrays: numpy combines those with an array faster than a Python float (the same value)
_Z, _H, _1, _3 = np.array(0.0), np.array(0.5), np.array(1.0), np.array(3.0)
_E4, _E9, _600, _700, _075 = np.array(1e-4), np.array(1e-9), np.array(600.0), np.array(700.0), np.array(0.75)
_RKC: dict = {}


def _card_nodes(c):
    """(contact f, contact weights, -z, rounding weights, w_z) of the card's quadrature bins, as columns."""
    key = (c.contact_nodes, c.round_nodes)
    got = _NODES.get(key)
    if got is None:
        cn, zn = c.contact_nodes, c.round_nodes
        got = _NODES[key] = (_c([fd for _, fd in cn], 2), _c([wd for wd, _ in cn], 2), _c([-z for _, z in zn], 2),
                             _c([wz for wz, _ in zn], 2), sum(wz for wz, _ in zn))
    return got


def _full(c, sp, n: int, L: int) -> dict:
    """The constant columns of the field as full arrays for a batch of ``n`` (and ``L`` links), formed once
    per step: numpy's operations on equal shapes skip the broadcasting set-up, which costs more than
    the arithmetic on a few hundred states. The same values, so the same results."""
    fd, wd, mz, wz, _ = _card_nodes(c)
    P, G = len(_PAIRS), len(GL_XH)
    cols = {"GT": (_GT, (N_S, n)), "W1": (_W1, (N_S, n)), "W2L": (_W2, (N_S, L, n)), "W24": (_W2, (N_S, 4, n)),
            "THALF": (_THALF, (2, L, n)), "FX": (_FRAG_X, (4, N_S, n)), "FSQ": (_FRAG_SQ, (4, N_S, n)),
            "FC": (_FRAG_C, (4, N_S, n)), "XX": (_XX, (G, N_S, n)), "WX": (_WX, (G, N_S, n)), "KX": (_KX, (G, N_S, n)),
            "CX": (sp.c_split, (G, N_S, n)), "P2": (_P2, (P, n)), "fd": (fd, (fd.shape[0], P, n)),
            "wd": (wd, (wd.shape[0], P, n)), "mz": (mz, (mz.shape[0], N_S, n)), "wz": (wz, (wz.shape[0], N_S, n)),
            "W1x2": (_W1, (2, N_S, n))}
    K = {}
    for name, (a, shape) in cols.items():
        K[name] = out = np.empty(shape)
        out[...] = a
    return K


def _sum0(A: np.ndarray) -> np.ndarray:
    """sum(A[0], A[1], ...) as Python's ``sum`` forms it (0 + A[0] + A[1] + ..., left to right)."""
    r = A[0] + _Z
    for k in range(1, A.shape[0]):
        r = r + A[k]
    return r


def _sum_pos(A: np.ndarray) -> np.ndarray:
    """:func:`_sum0` of terms that are never -0.0 (>= +0 or NaN): the leading 0 + changes nothing there."""
    r = A[0] + A[1]
    for k in range(2, A.shape[0]):
        r = r + A[k]
    return r


def _smax(a, lo, eps):
    d = a - lo
    return lo + _H * (d + np.sqrt(d * d + eps * eps))


def _smin(a, hi, eps):
    d = hi - a
    return hi - _H * (d + np.sqrt(d * d + eps * eps))


# equations.y_to_state's bounds and squared widths as 0-d arrays
_YS = {k: np.array(float(v)) for k, v in dict(
    cv=eq.CV_FLOOR, rhi=eq.R_HI, rlo=eq.R_LO, re2=eq.R_EPS * eq.R_EPS, phi2=eq.RHO_HI**2, pe2=eq.RHO_EPS * eq.RHO_EPS,
    plo2=eq.RHO_LO**2, plo4=eq.RHO_LO**2 * eq.RHO_LO**2).items()}


def _y_to_state(y):
    """:func:`bmctl.moments.equations.y_to_state` on numpy, bit for bit (the same operations)."""
    c = _YS
    m = np.exp(y[0])
    fl = (c["cv"] * m) ** 2
    d = np.exp(y[1]) - m * m - fl  # smax(e^y1 - m^2, fl, fl)
    var = fl + _H * (d + np.sqrt(d * d + fl * fl))
    d = c["rhi"] - y[2]  # smin(y2, R_HI, R_EPS)
    rm = c["rhi"] - _H * (d + np.sqrt(d * d + c["re2"]))
    d = rm - c["rlo"]  # smax(., R_LO, R_EPS)
    rm = c["rlo"] + _H * (d + np.sqrt(d * d + c["re2"]))
    rho2 = (y[3] - rm * rm) / (rm * (_1 - rm))
    d = c["phi2"] - rho2  # smin(rho2, RHO_HI^2, RHO_EPS)
    rho2 = c["phi2"] - _H * (d + np.sqrt(d * d + c["pe2"]))
    d = rho2 - c["plo2"]  # smax(., RHO_LO^2, RHO_LO^2)
    rho2 = c["plo2"] + _H * (d + np.sqrt(d * d + c["plo4"]))
    return m, np.sqrt(var), rm, np.sqrt(rho2)


def _sat(q):
    q2 = q * q
    return q / np.sqrt(np.sqrt(_1 + q2 * q2))


def usable(first, *xs) -> bool:
    """True when the fast path applies: ``first`` a 1-D float64 array, each of ``xs`` a plain number or
    a float64 array of the same shape or of none (every node array is then (nodes, n))."""
    if not (isinstance(first, np.ndarray) and first.dtype == np.float64 and first.ndim == 1):
        return False
    for v in xs:
        if isinstance(v, np.ndarray):
            if v.dtype != np.float64 or (v.shape != first.shape and v.ndim):
                return False
        elif not isinstance(v, (float, int, np.floating)):
            return False
    return True


def _link(beta, rm, v_r, sig_ln, W2, THALF):
    """``link`` of raw_rates for L slopes at once: beta (L, n) -> per-node arrays (N_S, L, n)."""
    k = -beta * sig_ln  # (L, n)
    half = np.exp(k * THALF)  # (2, L, n)
    inv = _1 / half
    ev = np.concatenate([inv[::-1], np.ones(half[:1].shape), half])  # (N_S, L, n)
    a_ = np.log(rm / (_1 - rm))
    S = np.empty((N_S, 2) + k.shape)
    for _ in range(4):
        ea = np.exp(np.minimum(-a_, _600))
        sg = _1 / (_1 + ea * ev)
        np.multiply(W2, sg, out=S[:, 0])  # wsg
        np.multiply(S[:, 0], sg, out=S[:, 1])
        s1, s2 = _sum_pos(S)  # w sg and w sg^2 >= +0
        fp = s1 - s2
        a_ = a_ - (s1 - rm) / (fp + _E9)
    ea = np.exp(np.minimum(-a_, _600))
    sg = _1 / (_1 + ea * ev)
    nrm = _sum_pos(W2 * sg)  # (L, n)
    rk = _smin(rm * sg / nrm, eq.R_HI, eq.R_EPS)
    np.multiply(W2, rk, out=S[:, 0])  # Wrk
    np.multiply(S[:, 0], rk, out=S[:, 1])
    Er_nodes, s2 = _sum0(S)
    var_between = s2 - Er_nodes * Er_nodes
    v_w = _smax(v_r - var_between, 0.05 * v_r, 1e-8)  # (L, n)
    omk = _1 - rk
    omk2 = omk * omk
    Ef = _1 / omk + v_w / (omk2 * omk)
    den = omk2 + v_w
    r_b = (rk * omk2 + v_w) / den
    r2_b = (rk * rk * omk2 + v_w) / den
    one_r = omk * den / (omk2 + _3 * v_w)
    return rk, Er_nodes, v_w, Ef, r_b, r2_b, one_r


class _Speed:
    """The parts of the field that depend on the speed and (gamma, delta) only, formed once per step."""

    __slots__ = ("ws", "rate", "ln_e", "ln_e_um", "gamma", "delta", "cb", "cf", "lam_head", "uu", "round2_f",
                 "c_split")

    def __init__(self, c, q, w, bm, fm, em=None):
        ws = _smax(w, 0.0, eq.RPM_SOFT)
        wh = ws - 0.5
        lw = np.log(ws)
        self.ws = ws
        self.rate = c.rate_max_per_h * np.exp(EXP_RATE * lw)
        ln_e = math.log(c.e_max_J_per_um2) + 1.2 * lw
        if em is not None:  # the mill's impact energy per particle against the card's (energy_mult)
            ln_e = ln_e + np.log(em)
        self.ln_e = ln_e
        self.ln_e_um = ln_e - math.log(UM)  # the common head of ln(dU_d / (d_c u_c)) and of the bonding law
        ln_u_mean = math.log(c.u_mean_max_J) + 2.0 * lw
        self.gamma, self.delta = c.gamma_per_um2 * bm, c.delta_per_um2 * fm
        self.cb = np.exp(q["bond_log_scale"] + q["bond_rpm_slope"] * wh)
        self.cf = np.exp(q["frac_log_scale"] + q["frac_rpm_slope"] * wh)
        # ln_lam1 = (((head + slope * (ws - 0.5)) + ln_e) - lratio) + ln(...): the speed's part, left to right
        self.lam_head = (math.log(c.equiaxing * 1.5 * c.plastic_share / (math.pi / 4 * UM**3 * c.yield_Pa) + 1e-300)
                         + q["round_log_scale"] + q["round_rpm_slope"] * wh + ln_e)
        self.uu = np.exp(ln_u_mean) * (3 * math.pi / (c.modulus_Pa * UM**3))
        self.round2_f = np.exp(q["round_var_log_scale"] + q["round_var_rpm_slope"] * wh)
        ac = q["frac_slope"]
        self.c_split = _c([float(eq.NP.exp(ac * math.log(2 * math.sqrt(x * (1 - x))))) for x in GL_XH], 2)


def raw_rates_np(c, q, m, sd, rm, rho, T, h, w, bm, fm, em=None):
    """:func:`bmctl.moments.equations.raw_rates` with ``B = NP`` (no events), bit for bit, on 1-D batches
    (:func:`usable`); see the module."""
    return _field(c, q, _Speed(c, q, w, bm, fm, em), m, sd, rm, rho, T, h)


def _field(c, q, sp: _Speed, m, sd, rm, rho, T, h, K=None):
    B = eq.NP
    n = m.shape[0]
    k_cv, k_fcv = q.get("r_link_cv_slope", 0.0), q.get("frac_link_cv_shift", 0.0)
    two = not (eq._zero(q["frac_link_shift"]) and eq._zero(k_fcv))
    if K is None:
        K = _full(c, sp, n, 2 if two else 1)
    var_ln = np.log(_1 + (sd / m) ** 2)
    sig_ln = np.sqrt(var_ln)
    rate = sp.rate
    lratio = np.log(eq.strength_ratio(B, c, T, h))
    ln_ub = math.log(c.u_J_per_m) + c.n_bond * lratio
    ln_uc = math.log(c.u_J_per_m) - c.n_frac * lratio
    ln_s = np.log(m) - _H * var_ln + sig_ln * K["GT"]  # (N_S, n)
    # per-node quantities that the size pairs gather, one block: s^2, s^3, the contact cap's (pi/2)^-8 s^-8,
    # the perimeter / pi, s, 3/4 s, gamma s E[1/(1-r)], the node weight x survival
    X9 = np.empty((8, N_S, n))
    s = np.exp(ln_s, out=X9[4])
    om = _1 - rm
    v_r = rho * rho * rm * om

    lncv2 = None if eq._zero(k_cv) and eq._zero(k_fcv) else np.log(rho * rho * om / rm)
    beta = q["r_size_corr"] if eq._zero(k_cv) else q["r_size_corr"] + k_cv * lncv2
    shift = q["frac_link_shift"] if eq._zero(k_fcv) else q["frac_link_shift"] + k_fcv * lncv2
    betas = np.empty((2 if two else 1, n))
    betas[0] = beta
    if two:
        np.add(beta, shift, out=betas[1])
    rkL, ErL, vwL, EfL, rbL, r2bL, orL = _link(betas, rm, v_r, sig_ln, K["W2L"], K["THALF"])
    rk, Er_nodes, v_w, Ef, r_b, r2_b, one_r = rkL[:, 0], ErL[0], vwL[0], EfL[:, 0], rbL[:, 0], r2bL[:, 0], orL[:, 0]
    f = 1 if two else 0
    Ef_f, r_b_f, r2_b_f, one_r_f = EfL[:, f], rbL[:, f], r2bL[:, f], orL[:, f]

    ab, ob, ac, oc = q["bond_slope"], q["bond_offset"], q["frac_slope"], q["frac_offset"]
    ln_lam1 = sp.lam_head - lratio + np.log(_smax(1.0 - c.equiaxing_hardening * h, 0.0, 0.02))
    kap = q["round_size_bias"]
    fd, wd, mz, wz, w_z = K["fd"], K["wd"], K["mz"], K["wz"], _card_nodes(c)[4]

    # fracture: split nodes (x, 1 - x) x size nodes (fragment_tables)
    cf = sp.cf
    base_c, nac = sp.ln_e_um - ln_uc, -ac
    inv = _1 / one_r_f
    g2 = 0.5 * q["frac_r_gain"]
    d = _1 - K["FSQ"] / (K["FX"] * inv + K["FC"])  # (2 GL_XH, N_S, n)
    r = g2 * (d + np.sqrt(d * d + _E4))
    lnL0 = base_c + ln_s
    q_k = sp.delta * s * s * Ef_f
    e_k = np.exp(np.minimum(nac * lnL0 - oc, _600))
    # the split nodes along one axis: p per node, then pf, ds, dr, dr2 summed over them
    P = K["WX"] * _sat(q_k * K["XX"]) / (_1 + e_k * K["CX"])  # (GL_XH, N_S, n)
    r = r.reshape((len(GL_XH), 2) + r.shape[1:])  # (r1, r2) per split node
    rr = r * r
    A = np.empty((len(GL_XH), 4, N_S, n))
    A[:, 0] = P
    np.multiply(P, K["KX"], out=A[:, 1])
    np.multiply(P, r[:, 0] + r[:, 1], out=A[:, 2])
    np.multiply(P, rr[:, 0] + rr[:, 1], out=A[:, 3])
    pf, ds, dr, dr2 = _sum0(A)
    # the fracture's node sums, sum_k w_k (Pf, dsf, drf, dr2f)_k, in one pass
    F4 = np.empty((N_S, 4, n))
    Pf = np.multiply(cf, pf, out=F4[:, 0])
    np.multiply(cf * ds, s, out=F4[:, 1])
    np.multiply(cf, dr - pf * r_b_f, out=F4[:, 2])
    np.multiply(cf, dr2 - pf * r2_b_f, out=F4[:, 3])
    Pf_sum, dsf_sum, drf_sum, dr2f_sum = _sum0(K["W24"] * F4)
    lam = np.exp(ln_lam1 - ln_s - kap * var_ln)

    # bonding: the size pairs (i <= j) along one axis
    cn = c.contact_nodes
    nab, nc0 = -ab, -(ab * (sp.ln_e_um - ln_ub) + ob)
    s2 = np.multiply(s, s, out=X9[0])
    np.multiply(s2, s, out=X9[1])
    np.divide((0.5 * math.pi) ** -8, (s2 * s2) * (s2 * s2), out=X9[2])
    np.divide(s, one_r, out=X9[3])
    np.multiply(_075, s, out=X9[5])
    gE = s * Ef
    np.multiply(sp.gamma, gE, out=X9[6])
    np.multiply(K["W1"], _1 - Pf, out=X9[7])
    s2n, s3_sum, cap_sum, perim = X9[:4, _PI] + X9[:4, _PJ]  # node i + node j of each pair
    si, sj = s[_PI], s[_PJ]
    s_new = np.sqrt(s2n)
    a_h = X9[5][_PI] * sj / (si + sj)  # _inv_contact
    d_h2 = a_h * a_h * sp.uu / s3_sum
    d_h4 = d_h2 * d_h2
    S8 = np.sqrt(np.sqrt(np.sqrt(_1 / (d_h4 * d_h4) + cap_sum)))
    lnL = np.log(s2n * S8)
    pb = _sat(X9[6][_PI] * gE[_PJ]) / (_1 + np.exp(np.minimum(nab * lnL + nc0, _700)))
    wsv = X9[7]
    p = pb * wsv[_PI] * wsv[_PJ]
    p = K["P2"] * p
    # eqn 18 over the contact bins (_bond_r_sums): bins along one more axis
    d_pi = (2 / math.pi) / S8
    v = _1 - s_new / (perim - d_pi * fd)
    r2x = v + np.sqrt(v * v + _E4)
    R = np.empty((fd.shape[0], 3) + s_new.shape)  # (bins, 3, pairs, n): rows 1, 2 the two sums' terms
    if eq._common_weight(cn) is not None:
        R[:, 1] = r2x
        np.multiply(r2x, r2x, out=R[:, 2])
    else:
        np.multiply(wd, r2x, out=R[:, 1])
        np.multiply(wd, r2x * r2x, out=R[:, 2])
    X = _sum0(R[:, 1:])  # rn1, rn2: (2, pairs, n)
    P3 = np.empty((3,) + s_new.shape)  # p (s_new, rn1, rn2): sb, rb1, rb2 = their sums over the pairs
    np.multiply(p, s_new, out=P3[0])
    np.multiply(p, X, out=P3[1:])
    sb, rb1, rb2 = _sum0(P3.swapaxes(0, 1))
    Q = _sum0(p[_QIDX])  # (N_S, n)
    gb1, gb2 = eq._bond_r_scales(cn, q["bond_r_gain"])
    Q4 = np.empty((N_S, 4, n))
    Q4[:, 0] = Q
    np.multiply(s, Q, out=Q4[:, 1])
    np.multiply(r_b, Q, out=Q4[:, 2])
    np.multiply(r2_b, Q, out=Q4[:, 3])
    sQ, ssQ, rQ, r2Q = _sum0(Q4)
    cb = sp.cb
    Pb_sum = cb * (0.5 * sQ)
    dsb = cb * (sb - ssQ)
    drb = cb * (gb1 * rb1 - rQ)
    dr2b = cb * (gb2 * rb2 - r2Q)

    g_N = rate * (Pf_sum - 0.5 * Pb_sum)
    Es2 = m * m + sd * sd
    Er2 = rm * rm + v_r
    gv = q["r_var_gain"]
    e2k = rk * rk + v_w
    e2n = _sum0(K["W1"] * e2k)
    e1 = np.exp(lam * mz)  # (bins, N_S, n)
    M = np.empty((mz.shape[0], 2, N_S, n))
    we = np.multiply(wz, e1, out=M[:, 0])
    np.multiply(we, e1, out=M[:, 1])
    m12 = _sum0(M)  # (2, N_S, n)
    G = np.empty((2, N_S, n))
    np.divide(rk, Er_nodes, out=G[0])
    np.divide(e2k, e2n, out=G[1])
    g12 = K["W1x2"] * G
    round1, round2 = _sum0((g12 * (w_z - m12)).swapaxes(0, 1))
    round2 = round2 * sp.round2_f
    dEs = rate * (0.5 * q["bond_ds_gain"] * dsb + q["frac_ds_gain"] * dsf_sum) - m * g_N
    dEs2 = -Es2 * g_N
    src1 = 0.5 * drb + drf_sum
    dEr = rate * (src1 - round1 * rm) - rm * g_N
    src2 = 0.5 * dr2b + dr2f_sum
    src2 = gv * src2 + (1 - gv) * 2 * rm * src1
    dEr2 = rate * (src2 - round2 * Er2) - Er2 * g_N
    return dEs, dEs2, dEr, dEr2


def step_np(c, q, xs, us, ps, dt_h, n_sub: int, stages: int):
    """:func:`bmctl.moments.equations.step` with ``B = NP`` (no ``rates``, no events), bit for bit, on
    1-D batches (:func:`usable`): the field by :func:`_field` with the speed's part formed once, the four
    integration coordinates as one (4, n) array in the RKC stages, and the vial's closed form with the
    parts that do not change within the step formed once."""
    B = eq.NP
    w = us[0] / c.rpm_max
    duty = us[1]
    bm, fm = ps[0], ps[1]
    sp = _Speed(c, q, w, bm, fm, eq.energy_of(ps))
    Z = np.stack(eq.to_y(B, xs))  # (4, n)
    two = not (eq._zero(q["frac_link_shift"]) and eq._zero(q.get("frac_link_cv_shift", 0.0)))
    K_ = _full(c, sp, Z.shape[1], 2 if two else 1)
    T0, h0 = xs[4], xs[5]
    t_mill = duty * dt_h
    hs = t_mill / n_sub
    K = _RKC.get(stages)
    if K is None:
        K = _RKC[stages] = eq.rkc_coefficients(stages)
    # thermal_exact(B, c, T0, h0, w, t) with its speed's part formed once
    T_ss = c.ambient_C + eq.power_W(c, w) * c.cooling_time_h * 3600.0 / c.heat_capacity_J_per_K
    dT = T0 - T_ss
    a = c.hardening_rate_max_per_h * w * w * w
    b = 1.0 / c.recovery_time_h
    h_ss = a / (a + b)
    dh = h0 - h_ss
    nab_ = -(a + b)

    def F(Y, t):
        Tt = T_ss + dT * np.exp(-t / c.cooling_time_h)
        ht = h_ss + dh * np.exp(nab_ * t)
        m, sd, rm, rho = _y_to_state(Y)
        out = _field(c, q, sp, m, sd, rm, rho, Tt, ht, K_)
        Fz = np.empty(Y.shape)
        np.divide(out[0], m, out=Fz[0])
        np.divide(out[1], m * m + sd * sd, out=Fz[1])
        Fz[2] = out[2]
        Fz[3] = out[3]
        return Fz

    t = 0.0
    for _ in range(n_sub):
        F0 = F(Z, t)
        Y2 = Z
        Y1 = Z + K["mut"][1] * hs * F0
        for j in range(2, K["s"] + 1):
            Fj = F(Y1, t + K["c"][j - 1] * hs)
            mu, nu, mut, gamt = K["mu"][j], K["nu"][j], K["mut"][j], K["gamt"][j]
            Y = (1 - mu - nu) * Z + mu * Y1 + nu * Y2 + mut * hs * Fj + gamt * hs * F0
            Y2, Y1 = Y1, Y
        Z = Y1
        t = t + hs
    T1, h1 = eq.thermal_exact(B, c, T0, h0, w, t_mill)
    T2, h2 = eq.thermal_exact(B, c, T1, h1, 0.0, dt_h - t_mill)
    return eq.state_to_x(B, *eq.y_to_state(B, [Z[0], Z[1], Z[2], Z[3]])) + [T2, h2]
