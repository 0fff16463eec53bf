"""The moment equations: ONE definition evaluated with numpy (batched) or casadi (symbolic).

Every function takes a backend ``B`` (:data:`NP` or :data:`CA`) that supplies the few
elementary operations used; everything else is arithmetic, so the same code builds a
numpy value and a casadi expression graph. Components of a state are passed as a list
(``xs[i]`` is a scalar, a numpy array over a batch, or a casadi SX/MX scalar).

State x = (s_mean_um, s_std_um, r_mean, r_std, temperature_c, hardening)
Input u = (rpm, milling),  parameters p = (gamma_mult, delta_mult): the plant's contact factor
gamma and parting factor delta relative to the card, acting inside eqns (15) and (20).

The particle part is integrated in raw-moment coordinates y = (ln E[s], ln E[s^2], E[r], E[r^2])
and read back through a smooth projection onto realisable sets (std > 0, 0 < r_mean < 1,
Beta-feasible r_std < sqrt(r_mean (1 - r_mean))), so every step returns a realisable state.
"""

from __future__ import annotations

import math

from ..physics.constants import R_MAX
from .numerics import (CA, GH_T, GH_W, GL_W, GL_WH, GL_X, GL_XH, N_S, N_X, NP, Backend,  # noqa: F401
                       backend, node_exps, node_sigmoids, sat, smax, smin)
from .physics import EXP_RATE, UM, Constants


# limits of the realisable projection
S_FLOOR_UM = 0.1
CV_FLOOR = 1e-4
R_LO, R_HI, R_EPS = 1e-4, R_MAX, 1e-5  # r_mean's ceiling is the plant's r ceiling
RHO_LO, RHO_HI, RHO_EPS = 1e-3, 0.98, 1e-4
RPM_SOFT = 1e-3  # rpm/rpm_max below which the speed is softened (rates ~ 0 there)


# --- projection and coordinates -----------------------------------------------------------------


def project(B, xs):
    """Smoothly project (s_mean, s_std, r_mean, r_std) onto realisable moment sets.

    Returns (m, sd, rm, rho): s_mean >= 0.1 um, s_std > 0 (cv >= 1e-4),
    r_mean in [1e-4, 0.99], rho = r_std / sqrt(rm (1 - rm)) in [1e-3, 0.98].
    Identity (to < 1e-6 relative) on realisable sets away from these limits.
    """
    m = smax(B, xs[0], S_FLOOR_UM, 1e-3)
    sd = B.sqrt(xs[1] * xs[1] + (CV_FLOOR * m) ** 2)
    rm = smax(B, smin(B, xs[2], R_HI, R_EPS), R_LO, R_EPS)
    rs = B.sqrt(xs[3] * xs[3] + 1e-12)
    rho = smax(B, smin(B, rs / B.sqrt(rm * (1 - rm)), RHO_HI, RHO_EPS), RHO_LO, RHO_EPS)
    return m, sd, rm, rho


def to_y(B, xs):
    """Integration coordinates y = (ln E[s], ln E[s^2], E[r], E[r^2]) of a (projected) state.

    Raw moments evolve without artificial stiffness (the log of a vanishing variance would
    be stiff); realisability is restored smoothly by :func:`y_to_state` wherever y is read.
    """
    m, sd, rm, rho = project(B, xs)
    return [B.log(m), B.log(m * m + sd * sd), rm, rm * rm + rho * rho * rm * (1 - rm)]


def y_to_state(B, y):
    """Realisable (m, sd, rm, rho) of integration coordinates (smooth projection)."""
    m = B.exp(y[0])
    fl = (CV_FLOOR * m) ** 2
    var = smax(B, B.exp(y[1]) - m * m, fl, fl)
    rm = smax(B, smin(B, y[2], R_HI, R_EPS), R_LO, R_EPS)
    rho2 = (y[3] - rm * rm) / (rm * (1 - rm))
    rho2 = smax(B, smin(B, rho2, RHO_HI**2, RHO_EPS), RHO_LO**2, RHO_LO**2)
    return m, B.sqrt(var), rm, B.sqrt(rho2)


def state_to_x(B, m, sd, rm, rho):
    """(s_mean, s_std, r_mean, r_std) of a realisable state."""
    return [m, sd, rm, rho * B.sqrt(rm * (1 - rm))]


# --- thermal part (exact) -----------------------------------------------------------------------


def power_W(c: Constants, w):
    """Mean dissipated power at rpm = w rpm_max (exact: P ~ rpm^3)."""
    return c.power_max_W * w * w * w


def thermal_rhs(c: Constants, T, h, w):
    """dT/dt and dh/dt (per hour) while milling at w = rpm / rpm_max (w = 0: rest)."""
    P = power_W(c, w)
    dT = P * (3600.0 / c.heat_capacity_J_per_K) - (T - c.ambient_C) / c.cooling_time_h
    a = c.hardening_rate_max_per_h * w * w * w
    dh = a * (1 - h) - h / c.recovery_time_h
    return dT, dh


def thermal_exact(B, c: Constants, T, h, w, t_h):
    """Closed-form T and h after ``t_h`` hours at constant w (as plant.thermal)."""
    T_ss = c.ambient_C + power_W(c, w) * c.cooling_time_h * 3600.0 / c.heat_capacity_J_per_K
    T1 = T_ss + (T - T_ss) * B.exp(-t_h / c.cooling_time_h)
    a = c.hardening_rate_max_per_h * w * w * w
    b = 1.0 / c.recovery_time_h
    h_ss = a / (a + b)
    h1 = h_ss + (h - h_ss) * B.exp(-(a + b) * t_h)
    return T1, h1


def strength_ratio(B, c: Constants, T, h):
    """sigma_eff / sigma = (1 + H h)(1 - S (1 - exp(-(T - T_amb)/T_s))) (thermal.py, smooth in T)."""
    soft = 1.0 - c.softening_max * (1.0 - B.exp(-(T - c.ambient_C) / c.softening_scale_K))
    return (1.0 + c.hardening_max * h) * soft


# --- the particle field -------------------------------------------------------------------------


def fragment_tables(B, one_r, gfr):
    """Per split node x of GL_XH: (r1 + r2, r1^2 + r2^2) of the two fragments (plant events.fractured, smooth clip).

    r = smax(1 - sqrt(x) / (x / one_r + 2 sqrt(x (1 - x)) / pi), 0, 0.01) gfr, written out
    (smax(d, 0, e) = (d + sqrt(d^2 + e^2)) / 2) with 1 / one_r formed once.
    """
    inv = 1.0 / one_r
    g2 = 0.5 * gfr
    out = []
    for x in GL_XH:
        c = 2 * math.sqrt(x * (1 - x)) / math.pi
        d1 = 1.0 - math.sqrt(x) / (x * inv + c)
        d2 = 1.0 - math.sqrt(1 - x) / ((1 - x) * inv + c)
        r1 = g2 * (d1 + B.sqrt(d1 * d1 + 1e-4))
        r2 = g2 * (d2 + B.sqrt(d2 * d2 + 1e-4))
        out.append((r1 + r2, r1 * r1 + r2 * r2))
    return out


def bond_r_moments(B, s_new, perim, d_pi, nodes, gain=1.0):
    """E[r_new] and E[r_new^2] of a bonded particle over the random contact length.  (18), (16), (5)

    r_new = 1 - s_new / (perim - 2 d / pi) (eqn 18, clipped smoothly at 0), with the contact
    length d = d_mean * f and f ~ sqrt(U_in / E[U_in]) (eqn 16 under the energy law of eqn 5)
    taken at the quadrature ``nodes`` ((weight, f), physics.CONTACT_BINS). ``d_pi`` is
    2 d_mean / pi; ``perim`` = s_i / (1 - r_i) + s_j / (1 - r_j) (the summed perimeter / pi).
    """
    (g1, g2), (rn1, rn2) = _bond_r_scales(nodes, gain), _bond_r_sums(B, s_new, perim, d_pi, nodes)
    return g1 * rn1, g2 * rn2


def _common_weight(nodes):
    """The weight shared by all quadrature ``nodes`` ((weight, f) pairs), or None if they differ."""
    ws = {wd for wd, _ in nodes}
    return ws.pop() if len(ws) == 1 else None


def _bond_r_scales(nodes, gain):
    """Factors that turn :func:`_bond_r_sums` into E[r_new], E[r_new^2] (the smooth clip's 1/2,
    the gain and, for equal weights, the weight)."""
    w = _common_weight(nodes)
    w = 1.0 if w is None else w
    return 0.5 * gain * w, 0.25 * gain * gain * w


def _bond_r_sums(B, s_new, perim, d_pi, nodes):
    """sum_b w_b x_b and sum_b w_b x_b^2 with x_b = 2 smax(v_b, 0, 0.01) = v_b + sqrt(v_b^2 + 1e-4),
    v_b = 1 - s_new / (perim - d_pi f_b) (eqn 18 at contact bin b); equal weights are left out."""
    equal = _common_weight(nodes) is not None
    rn1 = rn2 = 0.0
    for wd, fd in nodes:
        v = 1.0 - s_new / (perim - d_pi * fd)
        r2x = v + B.sqrt(v * v + 1e-4)
        if equal:
            rn1, rn2 = rn1 + r2x, rn2 + r2x * r2x
        else:
            rn1, rn2 = rn1 + wd * r2x, rn2 + wd * (r2x * r2x)
    return rn1, rn2


def _inv_contact(B, a34_i, si, sj, s3_sum, cap_sum, uu):
    """1 / d of eqn 16 with its cap, d = smin_pos(d_h, (pi/2) smin_pos(si, sj)) with the scale-free
    smooth minimum smin_pos(a, b) = (a^-8 + b^-8)^(-1/8) (within 9 % of the min), without exp/log:
    d^-8 = d_h^-8 + (pi/2)^-8 (si^-8 + sj^-8), d_h^2 = (3/4 si sj / (si + sj))^2 uu / (si^3 + sj^3).

    The per-node parts are passed in: ``a34_i`` = 3/4 si, ``s3_sum`` = si^3 + sj^3, ``cap_sum`` =
    (pi/2)^-8 (si^-8 + sj^-8), ``uu`` = E[U] 3 pi / (E um^3). Sizes in um.
    """
    a_h = a34_i * sj / (si + sj)
    d_h2 = a_h * a_h * uu / s3_sum
    d_h4 = d_h2 * d_h2
    return B.sqrt(B.sqrt(B.sqrt(1.0 / (d_h4 * d_h4) + cap_sum)))


def energy_of(ps):
    """The ``energy_mult`` of a multiplier list (gamma_mult, delta_mult[, energy_mult]); None without it."""
    return ps[2] if len(ps) > 2 else None


def _zero(v) -> bool:
    """True for a plain number equal to 0 (not a casadi symbol): the term it scales can be left out."""
    return isinstance(v, (int, float)) and v == 0


#: evaluate the numpy field with :mod:`bmctl.moments.npfield` (the same numbers, bit for bit, with fewer
#: and larger array operations); False runs the node-by-node definition below
NP_VECTORISED = True


def raw_rates(B, c: Constants, q, m, sd, rm, rho, T, h, w, bm, fm, events: bool = False, em=None):
    """Rates (per hour of milling) of E[s], E[s^2], E[r], E[r^2] at speed w = rpm / rpm_max.

    With ``events``, two more: bonding and fracture events per particle and hour of milling
    (the plant's counts; d ln N / dt is their difference).

    The population is closed as s ~ log-normal(m, sd) (5 Gauss-Hermite nodes); at size node k
    the r law has mean r_k with logit r_k linear in ln s_k (slope ``r_size_corr``, mean rm) and
    the variance left over, seen by the kernels through delta-method averages (the fracture terms
    see the link with slope ``r_size_corr + frac_link_shift``). Per particle and impact (rate k(w)):
    fracture probability Pf(s) = E_x[sat(delta s^2 x(1-x)/(1-r))] * logistic law of
    eqn (17) in ln(dU_d / (d_c u_c)); bonding of a pair Pb(si, sj) = sat(gamma si sj/(1-r)^2)
    * logistic law in ln((dU_i + dU_j)/(d_ij u_b)) * (1 - Pf_i)(1 - Pf_j).
    The total s^2 is conserved exactly (eqn 2); N changes by -1 per bond, +1 per fracture.
    ``q`` maps coefficient names to numbers (or casadi symbols).

    On numpy arrays (without ``events``) the same field is evaluated by
    :func:`bmctl.moments.npfield.raw_rates_np`, vectorised over the nodes and bit-identical
    (:data:`NP_VECTORISED` switches it off).
    """
    if B is NP and not events and NP_VECTORISED:
        from .npfield import raw_rates_np, usable

        if usable(m, sd, rm, rho, T, h, w, bm, fm, *([] if em is None else [em])):
            return raw_rates_np(c, q, m, sd, rm, rho, T, h, w, bm, fm, em)
    var_ln = B.log(1.0 + (sd / m) ** 2)
    sig_ln = B.sqrt(var_ln)
    ws = smax(B, w, 0.0, RPM_SOFT)
    lw = B.log(ws)
    rate = c.rate_max_per_h * B.exp(EXP_RATE * lw)  # impacts per particle per hour
    lratio = B.log(strength_ratio(B, c, T, h))
    ln_ub = math.log(c.u_J_per_m) + c.n_bond * lratio
    ln_uc = math.log(c.u_J_per_m) - c.n_frac * lratio
    ln_e = math.log(c.e_max_J_per_um2) + 1.2 * lw  # ln(J per um^2 of s^2)
    if em is not None:  # energy_mult: the mill's impact energy per particle against the card's
        ln_e = ln_e + B.log(em)
    ln_u_mean = math.log(c.u_mean_max_J) + 2.0 * lw
    # size nodes (log-normal closure)
    ln_s = [B.log(m) - 0.5 * var_ln + sig_ln * t for t in GH_T]
    s = [B.exp(v) for v in ln_s]
    # r law seen by the kernels. Irregular particles are the large, freshly bonded ones: the
    # mean r at size node k follows a logit link in ln s with slope beta = `r_size_corr`
    # (0 = mean field), normalised so that the nodes average to rm; the within-node variance
    # v_w is the rest of v_r. p_b, p_c ~ 1/(1-r) (eqns 15, 20) weight irregular particles up; their
    # second-order (delta-method) averages at each node are finite for every realisable state.
    om = 1.0 - rm
    v_r = rho * rho * rm * om

    def link(beta):
        """(r_k, E over nodes, within-node variance, E[1/(1-r)], r_b, r2_b, perimeter factor) per node."""
        # logit link: logit r_k = a + beta (ln s_k - mu_ln); a by 4 Newton steps from logit(rm) so that
        # the nodes average to rm, then an exact rescale (beta = 0: every node at rm, the mean field)
        # sigmoid(a + v_k) = 1 / (1 + e^-a e^-v_k): the node factors e^-v_k are formed once (the nodes
        # are symmetric, so two exponentials and their inverses), each Newton step costs one exponential
        ev = node_exps(B, -beta * sig_ln)
        a_ = B.log(rm / (1 - rm))
        for _ in range(4):
            sg = node_sigmoids(B, a_, ev)
            wsg = [GH_W[k] * sg[k] for k in range(N_S)]
            s1 = sum(wsg)
            fp = s1 - sum(wsg[k] * sg[k] for k in range(N_S))  # sum w sg (1 - sg)
            a_ = a_ - (s1 - rm) / (fp + 1e-9)
        sg = node_sigmoids(B, a_, ev)
        nrm = sum(GH_W[k] * sg[k] for k in range(N_S))
        rk = [smin(B, rm * sg[k] / nrm, R_HI, R_EPS) for k in range(N_S)]
        Er_nodes = sum(GH_W[k] * rk[k] for k in range(N_S))
        var_between = sum(GH_W[k] * rk[k] * rk[k] for k in range(N_S)) - Er_nodes * Er_nodes
        v_w = smax(B, v_r - var_between, 0.05 * v_r, 1e-8)
        Ef, r_b, r2_b, one_r = [], [], [], []
        for k in range(N_S):
            omk = 1.0 - rk[k]
            omk2 = omk * omk
            Ef.append(1.0 / omk + v_w / (omk2 * omk))  # E[1/(1-r)]
            r_b.append((rk[k] * omk2 + v_w) / (omk2 + v_w))  # E[r/(1-r)] / E[1/(1-r)]: r of a reacting particle
            r2_b.append((rk[k] * rk[k] * omk2 + v_w) / (omk2 + v_w))  # E[r^2/(1-r)] / E[1/(1-r)]
            one_r.append(omk * (omk2 + v_w) / (omk2 + 3 * v_w))  # perimeter factor of a reacting particle
        return rk, Er_nodes, v_w, Ef, r_b, r2_b, one_r

    # bonding and rounding see the link of slope beta; the fracture terms (parent removed, eqn 20's
    # 1/(1-r), fragment perimeters) see slope beta + `frac_link_shift` (docs/moments.md, Sec. 2):
    # the net r a fracture creates depends on the parent's r twice, through its removal and through
    # the fragments' share of its perimeter, and one slope for both processes cannot set it
    # both slopes grow with ln CV^2 of r (`r_link_cv_slope`, `frac_link_cv_shift`): where most particles
    # are round, r sits on a few large irregular ones and the plant's link is steeper (docs/moments.md, Sec. 6)
    k_cv, k_fcv = q.get("r_link_cv_slope", 0.0), q.get("frac_link_cv_shift", 0.0)
    lncv2 = None if _zero(k_cv) and _zero(k_fcv) else B.log(rho * rho * om / rm)  # ln (r_std / r_mean)^2
    beta = q["r_size_corr"] if _zero(k_cv) else q["r_size_corr"] + k_cv * lncv2
    rk, Er_nodes, v_w, Ef, r_b, r2_b, one_r = link(beta)
    shift = q["frac_link_shift"] if _zero(k_fcv) else q["frac_link_shift"] + k_fcv * lncv2
    if _zero(shift):  # the same link: reuse it (defaults, numpy path)
        Ef_f, r_b_f, r2_b_f, one_r_f = Ef, r_b, r2_b, one_r
    else:
        _, _, _, Ef_f, r_b_f, r2_b_f, one_r_f = link(beta + shift)
    # p = (bm, fm): the plant's gamma and delta relative to the card. They act where eqns (15) and
    # (20) put them, inside the saturation of p_b and p_c, so the averaged rates respond to them as
    # the plant's do (weakly where the probabilities saturate); nothing about the response is fitted.
    gamma, delta = c.gamma_per_um2 * bm, c.delta_per_um2 * fm
    cb = B.exp(q["bond_log_scale"] + q["bond_rpm_slope"] * (ws - 0.5))
    cf = B.exp(q["frac_log_scale"] + q["frac_rpm_slope"] * (ws - 0.5))
    ab, ob, ac, oc = q["bond_slope"], q["bond_offset"], q["frac_slope"], q["frac_offset"]
    # rounding per impact: lam(s) = eta 1.5 E[dU_p] / (pi/4 s^3 sigma_eff) = lam1 / s (s in um)
    ln_lam1 = (math.log(c.equiaxing * 1.5 * c.plastic_share / (math.pi / 4 * UM**3 * c.yield_Pa) + 1e-300)
               + q["round_log_scale"] + q["round_rpm_slope"] * (ws - 0.5) + ln_e - lratio
               + B.log(smax(B, 1.0 - c.equiaxing_hardening * h, 0.0, 0.02)))  # eta_eq (1 - a h)^+
    kap = q["round_size_bias"]

    Pf, dsf, drf, dr2f, lam = [], [], [], [], []
    base_c, nac = ln_e - math.log(UM) - ln_uc, -ac
    c_split = [B.exp(ac * math.log(2 * math.sqrt(x * (1 - x)))) for x in GL_XH]  # |ac ln(..)| < 100
    for k in range(N_S):
        sk = s[k]
        frag = fragment_tables(B, one_r_f[k], q["frac_r_gain"])
        # ln(dU_d / (d_c u_c)) with d_c = s at x = 1/2: ln e + ln s - ln UM - ln u_c
        lnL0 = base_c + ln_s[k]
        q_k = delta * sk * sk * Ef_f[k]  # eqn 20
        e_k = B.exp(B.fmin(nac * lnL0 - oc, 600.0))
        pf = ds = dr = dr2 = 0.0
        for x, wx, (rsum, r2sum), c_x in zip(GL_XH, GL_WH, frag, c_split):
            xx = x * (1 - x)
            # sigmoid(ac (lnL0 - ln(2 sqrt(xx))) + oc) = 1 / (1 + e_k c_x)   (eqn 17)
            p = wx * sat(B, q_k * xx) / (1.0 + e_k * c_x)
            pf = pf + p
            ds = ds + p * (math.sqrt(x) + math.sqrt(1 - x) - 1.0)
            dr = dr + p * rsum
            dr2 = dr2 + p * r2sum
        Pf.append(cf * pf)
        dsf.append(cf * ds * sk)
        drf.append(cf * (dr - pf * r_b_f[k]))
        dr2f.append(cf * (dr2 - pf * r2_b_f[k]))
        lam.append(B.exp(ln_lam1 - ln_s[k] - kap * var_ln))  # at the r-mass-biased size s exp(kap var)

    cn = c.contact_nodes
    uu = B.exp(ln_u_mean) * (3 * math.pi / (c.modulus_Pa * UM**3))  # E[U] u_fac of eqn 16
    # eqn 17's law, sigmoid(ab (base_b + ln L) + ob), as 1 / (1 + exp(nab ln L + nc0))
    nab, nc0 = -ab, -(ab * (ln_e - math.log(UM) - ln_ub) + ob)
    # per-node factors, formed once: the contact cap (pi/2) smin_pos(si, sj) enters _inv_contact
    # through its -8th power, (pi/2)^-8 (si^-8 + sj^-8) (no exp/log pairs per pair)
    s2 = [sk * sk for sk in s]
    s3 = [s2[k] * s[k] for k in range(N_S)]
    cap_m8 = [(0.5 * math.pi) ** -8 / ((v * v) * (v * v)) for v in s2]
    a34 = [0.75 * sk for sk in s]
    gE = [s[k] * Ef[k] for k in range(N_S)]  # eqn 15 per particle (s / (1 - r), averaged)
    gG = [gamma * v for v in gE]
    wsv = [GH_W[k] * (1 - Pf[k]) for k in range(N_S)]  # node weight x survival of fracture
    per = [s[k] / one_r[k] for k in range(N_S)]  # perimeter / pi of a reacting particle
    # sums over pairs: Q_k = bond probability mass of the pairs that contain node k (both ends),
    # so that sum_pairs p (x_new - x_i - x_j) = sum_pairs p x_new - sum_k x_k Q_k
    Q = [0.0] * N_S
    sb = rb1 = rb2 = 0.0
    for i in range(N_S):
        for j in range(i, N_S):
            si, sj = s[i], s[j]
            s2n = s2[i] + s2[j]
            s_new = B.sqrt(s2n)  # eqn 18 (s^2 conserved, eqn 2)
            S8 = _inv_contact(B, a34[i], si, sj, s3[i] + s3[j], cap_m8[i] + cap_m8[j], uu)  # 1 / d, eqn 16 capped
            lnL = B.log(s2n * S8)
            pb = sat(B, gG[i] * gE[j]) / (1.0 + B.exp(B.fmin(nab * lnL + nc0, 700.0)))  # eqns 15, 17
            p = pb * wsv[i] * wsv[j]
            if i != j:
                p = 2.0 * p
            # eqn 18, averaged over the random contact length (d ~ sqrt(U_in), eqn 16; CONTACT_BINS);
            # 2 d / pi is the capped mean contact length, the sums scale it per sqrt(U) bin
            rn1, rn2 = _bond_r_sums(B, s_new, per[i] + per[j], (2 / math.pi) / S8, cn)
            Q[i] = Q[i] + p
            Q[j] = Q[j] + p
            sb = sb + p * s_new
            rb1 = rb1 + p * rn1
            rb2 = rb2 + p * rn2
    gb1, gb2 = _bond_r_scales(cn, q["bond_r_gain"])
    Pb_sum = cb * (0.5 * sum(Q))
    dsb = cb * (sb - sum(s[k] * Q[k] for k in range(N_S)))
    drb = cb * (gb1 * rb1 - sum(r_b[k] * Q[k] for k in range(N_S)))
    dr2b = cb * (gb2 * rb2 - sum(r2_b[k] * Q[k] for k in range(N_S)))

    Pf_sum = sum(GH_W[k] * Pf[k] for k in range(N_S))
    g_N = rate * (Pf_sum - 0.5 * Pb_sum)  # d ln N / dt
    Es2 = m * m + sd * sd
    Er2 = rm * rm + v_r
    gv = q["r_var_gain"]
    zn = c.round_nodes
    # rounding of E[r] and E[r^2]: node k carries the share r_k / rm of E[r] and (r_k^2 + v_w) / E[r^2] of E[r^2]
    e2k = [rk[k] * rk[k] + v_w for k in range(N_S)]
    e2n = sum(GH_W[k] * e2k[k] for k in range(N_S))
    round1 = round2 = 0.0
    w_z = sum(wz for wz, _ in zn)
    for k in range(N_S):
        g1, g2 = GH_W[k] * (rk[k] / Er_nodes), GH_W[k] * (e2k[k] / e2n)  # node k's shares
        # r <- r exp(-lam Z) per impact (equiaxing); r^2 <- r^2 exp(-2 lam Z): sum_Z wz (1 - e) = w_z - sum_Z wz e
        m1 = m2 = 0.0
        for wz, z in zn:
            e1 = B.exp(lam[k] * -z)
            we = wz * e1
            m1 = m1 + we
            m2 = m2 + we * e1
        round1 = round1 + g1 * (w_z - m1)
        round2 = round2 + g2 * (w_z - m2)
    round2 = round2 * B.exp(q["round_var_log_scale"] + q["round_var_rpm_slope"] * (ws - 0.5))
    dsf_sum = sum(GH_W[k] * dsf[k] for k in range(N_S))
    dEs = rate * (0.5 * q["bond_ds_gain"] * dsb + q["frac_ds_gain"] * dsf_sum) - m * g_N
    dEs2 = -Es2 * g_N
    src1 = 0.5 * drb + sum(GH_W[k] * drf[k] for k in range(N_S))
    dEr = rate * (src1 - round1 * rm) - rm * g_N
    src2 = 0.5 * dr2b + sum(GH_W[k] * dr2f[k] for k in range(N_S))
    # r_var_gain blends the mean-field r^2 source with a pure shift of the r law (2 rm src1)
    src2 = gv * src2 + (1 - gv) * 2 * rm * src1
    dEr2 = rate * (src2 - round2 * Er2) - Er2 * g_N
    if events:
        return dEs, dEs2, dEr, dEr2, rate * 0.5 * Pb_sum, rate * Pf_sum
    return dEs, dEs2, dEr, dEr2


def y_rates(B, c, q, y, T, h, w, bm, fm, events: bool = False, em=None):
    """dy/dt (per hour of milling) of the integration coordinates y; with ``events``, followed by
    the bonding and fracture events per particle and hour (:func:`raw_rates`)."""
    m, sd, rm, rho = y_to_state(B, y)
    out = raw_rates(B, c, q, m, sd, rm, rho, T, h, w, bm, fm, events=events, em=em)
    return [out[0] / m, out[1] / (m * m + sd * sd), out[2], out[3], *out[4:]]


def casadi_rate_field(c, q, theta=None, events: bool = False):
    """The particle field :func:`y_rates` as one casadi.Function and a list-in, list-out wrapper.

    Returns ``(F, rates)``: ``F(y[4], a[5][, theta]) -> dy/dt[4]`` with ``a`` = (T, h,
    rpm / rpm_max, gamma_mult, delta_mult), and ``rates(y, T, h, w, bm, fm)`` (the ``rates``
    argument of :func:`step`). ``theta``, when given, is a casadi symbol that ``q`` refers to
    (the free coefficients of an identification); it becomes a third input of ``F``. With
    ``events``, ``F`` has two more outputs, the bonding and fracture events per particle and hour
    (pass ``events=True`` to :func:`step` with these ``rates`` too).
    """
    import casadi as ca

    y = ca.SX.sym("y", 4)
    a = ca.SX.sym("a", 5)  # T, h, w, bm, fm
    extra = [] if theta is None else [theta]
    out = y_rates(CA(), c, q, [y[i] for i in range(4)], a[0], a[1], a[2], a[3], a[4], events=events)
    F = ca.Function("moment_rates", [y, a] + extra, [ca.vertcat(*out)], {"cse": True})

    def rates(yl, T, h, w, bm, fm):
        v = F(ca.vertcat(*yl[:4]), ca.vertcat(T, h, w, bm, fm), *extra)
        return [v[i] for i in range(len(out))]

    return F, rates


def rhs(B, c, q, xs, us, ps):
    """Continuous-time field dx/dt (per hour), duty-averaged over the milling fraction.

    dx/dt = milling * f_mill(x, rpm) + (1 - milling) * f_rest(x); f_rest moves only T and h.
    Evaluated at the smooth projection of x (so it is defined for any x).
    """
    m, sd, rm, rho = project(B, xs)
    T, h = xs[4], xs[5]
    w = us[0] / c.rpm_max
    duty = us[1]
    dEs, dEs2, dEr, dEr2 = raw_rates(B, c, q, m, sd, rm, rho, T, h, w, ps[0], ps[1],
                                     em=energy_of(ps))
    rs = rho * B.sqrt(rm * (1 - rm))
    dsd = (dEs2 - 2 * m * dEs) / (2 * sd)
    drs = (dEr2 - 2 * rm * dEr) / (2 * rs)
    dT1, dh1 = thermal_rhs(c, T, h, w)
    dT0, dh0 = thermal_rhs(c, T, h, 0.0)
    return [duty * dEs, duty * dsd, duty * dEr, duty * drs,
            duty * dT1 + (1 - duty) * dT0, duty * dh1 + (1 - duty) * dh0]


def rkc_coefficients(stages: int, damping: float = 2.0 / 13.0) -> dict:
    """Coefficients of the second-order Runge-Kutta-Chebyshev method (Sommeijer, Shampine & Verwer 1998).

    An explicit method whose real stability interval grows as ~0.65 stages^2, suited to the
    dissipative, stiff-at-high-rpm moment field (eigenvalues down to ~-1.4 per impact).
    Returns lists mu, nu, mut, gamt (index j = 1..s) and stage times c.
    """
    s = int(stages)
    if s < 2:
        raise ValueError("RKC needs >= 2 stages")
    w0 = 1.0 + damping / s**2
    # Chebyshev T_j(w0) and derivatives
    T = [1.0, w0]
    dT = [0.0, 1.0]
    ddT = [0.0, 0.0]
    for j in range(2, s + 1):
        T.append(2 * w0 * T[j - 1] - T[j - 2])
        dT.append(2 * T[j - 1] + 2 * w0 * dT[j - 1] - dT[j - 2])
        ddT.append(4 * dT[j - 1] + 2 * w0 * ddT[j - 1] - ddT[j - 2])
    w1 = dT[s] / ddT[s]
    b = [0.0] * (s + 1)
    for j in range(2, s + 1):
        b[j] = ddT[j] / dT[j] ** 2
    b[0] = b[1] = b[2]
    a = [1.0 - b[j] * T[j] for j in range(s + 1)]
    c = [0.0] * (s + 1)
    for j in range(2, s + 1):
        c[j] = w1 * ddT[j] / dT[j]
    c[1] = c[2] / dT[2]
    c[s] = 1.0
    mu = [0.0] * (s + 1)
    nu = [0.0] * (s + 1)
    mut = [0.0] * (s + 1)
    gamt = [0.0] * (s + 1)
    mut[1] = b[1] * w1
    for j in range(2, s + 1):
        mu[j] = 2 * b[j] * w0 / b[j - 1]
        nu[j] = -b[j] / b[j - 2]
        mut[j] = 2 * b[j] * w1 / b[j - 1]
        gamt[j] = -a[j - 1] * mut[j]
    beta = (2.0 / 3.0) * (s * s - 1) * (1 - 2.0 * damping / 15.0)
    return {"s": s, "mu": mu, "nu": nu, "mut": mut, "gamt": gamt, "c": c, "beta": beta}


def step(B, c, q, xs, us, ps, dt_h: float, n_sub: int, stages: int, rates=None, events: bool = False):
    """Advance over ``dt_h`` hours: mill ``milling * dt_h`` at rpm, then rest (as Plant.advance).

    Milling phase: ``n_sub`` substeps of RKC2 with ``stages`` stages in y coordinates,
    T and h exact (closed form) at every stage time. Rest: particles unchanged, T and h exact.
    ``rates(y, T, h, w, bm, fm)`` defaults to :func:`y_rates` (a compiled casadi version of it
    makes symbolic construction fast). With ``events`` the result has two more entries: the
    bonding and fracture events per particle over the interval, integrated with the moments
    (``rates`` must then return the event rates too).
    """
    if rates is None and B is NP and not events and NP_VECTORISED:
        from .npfield import step_np, usable

        if usable(xs[0], *xs[1:6], us[0], us[1], *ps, dt_h):
            return step_np(c, q, xs, us, ps, dt_h, n_sub, stages)  # the same numbers, bit for bit
    em = energy_of(ps)
    if em is not None and rates is not None:
        raise ValueError("energy_mult: a compiled rate field takes (gamma_mult, delta_mult) only")
    rates = rates or (lambda y, T, h, w, bm, fm: y_rates(B, c, q, y[:4], T, h, w, bm, fm, events=events, em=em))
    w = us[0] / c.rpm_max
    duty = us[1]
    bm, fm = ps[0], ps[1]
    z = to_y(B, xs) + ([0.0, 0.0] if events else [])
    T0, h0 = xs[4], xs[5]
    t_mill = duty * dt_h
    hs = t_mill / n_sub
    K = rkc_coefficients(stages)

    def F(zz, t):
        Tt, ht = thermal_exact(B, c, T0, h0, w, t)
        return rates(zz, Tt, ht, w, bm, fm)

    t = 0.0
    for _ in range(n_sub):
        F0 = F(z, t)
        y_prev2 = z
        y_prev = [zi + K["mut"][1] * hs * fi for zi, fi in zip(z, F0)]
        for j in range(2, K["s"] + 1):
            Fj = F(y_prev, t + K["c"][j - 1] * hs)
            mu, nu, mut, gamt = K["mu"][j], K["nu"][j], K["mut"][j], K["gamt"][j]
            y = [(1 - mu - nu) * z0 + mu * a + nu * b_ + mut * hs * f + gamt * hs * f0
                 for z0, a, b_, f, f0 in zip(z, y_prev, y_prev2, Fj, F0)]
            y_prev2, y_prev = y_prev, y
        z = y_prev
        t = t + hs
    T1, h1 = thermal_exact(B, c, T0, h0, w, t_mill)
    T2, h2 = thermal_exact(B, c, T1, h1, 0.0, dt_h - t_mill)
    return state_to_x(B, *y_to_state(B, z[:4])) + [T2, h2] + list(z[4:])
