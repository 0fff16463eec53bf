"""Model cards: what a card implies (masses, mixtures, kinematics per rpm, validity, coefficients).

``card show`` prints the derived masses, the law of mixtures, the kinematics per rpm, the validity,
the card's moment coefficients and the operating window they were calibrated for."""

from __future__ import annotations

import sys

from ._args import float_arg


def configure(p):
    sub = p.add_subparsers(dest="card_command", metavar="ACTION", parser_class=type(p))
    sub.required = True
    show = sub.add_parser("show", help="derived quantities a process engineer checks, as a table",
                          description="Derived quantities of a model card: loading, law of mixtures, and per rpm "
                                      "ball velocity, collision frequency, impact energy, Hertz radius, trapped "
                                      "share, hits per particle per hour, dissipated power, steady vial temperature; "
                                      "whether the card has moment coefficients of its own and their held-out error; "
                                      "the steady vial temperatures the model was calibrated for.")
    show.add_argument("model", metavar="CARD.toml", help="model card")
    show.add_argument("--rpm", type=_rpm_list, default=None, metavar="R1,R2,...",
                      help="speeds of the table, each at least 1 rpm (default: the card's rpm x 0.5, 0.75, 1, 1.25 "
                           "and rpm_max; half of rpm_max for a card whose rpm is 0)")


#: the slowest speed the report shows: below it a planetary mill does not mill (their slowest settings are tens of rpm)
RPM_MIN = 1.0


def _rpm_list(text: str) -> list[float]:
    """``--rpm``: 1 to 20 comma-separated speeds in [:data:`RPM_MIN`, 2000] rpm, no empty entry.

    Examples
    --------
    >>> _rpm_list("150, 300")
    [150.0, 300.0]
    """
    from ..errors import InputError, quote
    from ..limits import RPM_MAX

    parse = float_arg("--rpm", hi=RPM_MAX)
    items = [t.strip() for t in text.split(",")]
    if not any(items) or len(items) > 20:
        raise InputError(f"--rpm: expected 1 to 20 comma-separated speeds (got {quote(text)})")
    if not all(items):
        raise InputError(f"--rpm: an empty entry in {quote(text)} (expected speeds separated by commas, "
                         "such as 150,300)")
    rpms = [parse(t) for t in items]
    slow = next((r for r in rpms if r < RPM_MIN), None)
    if slow is not None:
        raise InputError(f"--rpm: {slow:g} rpm is below {RPM_MIN:g} rpm, the slowest speed the report shows "
                         f"(got {quote(text)})")
    return rpms


def format_report(rep: dict, coeffs=None) -> str:
    """The report of :func:`bmctl.cards.card_report` as text (one table per section).

    Parameters
    ----------
    rep : dict
        From :func:`bmctl.cards.card_report`.
    coeffs : bmctl.moments.forcard.Status, optional
        The card's moment coefficients (:func:`bmctl.moments.forcard.status`); a section when given.
    """
    ld, val = rep["loading"], rep["validity"]
    lines = [f"card {rep['name']}", "", "loading"]
    lines.append(f"  ball mass          {ld['ball_mass_g']:.4g} g (rho pi d^3/6: {ld['ball_mass_from_geometry_g']:.4g} g)")
    lines.append(f"  balls, total       {ld['balls_total_g']:.4g} g; fill {ld['ball_fill']:.1%} of a {ld['vial_ml']:.3g} ml vial")
    lines.append(f"  powder             {ld['powder_g']:.4g} g (ball-to-powder ratio {ld['ball_to_powder_ratio']:.4g})")
    pw = rep["powder"]
    if pw is not None:
        comp = " + ".join(f"{x:.3g} {n}" for n, x in zip(pw["materials"], pw["molar_fractions"]))
        lines += ["", f"powder (molar fractions {comp}); card value / molar law of mixtures"]
        lines.append(f"  E                  {pw['E_GPa'][0]:.4g} / {pw['E_GPa'][1]:.4g} GPa")
        lines.append(f"  yield stress       {pw['sigma_MPa'][0]:.4g} / {pw['sigma_MPa'][1]:.4g} MPa")
        lines.append(f"  density            {pw['density_kg_m3'][0]:.5g} / {pw['density_kg_m3'][1]:.5g} kg/m^3")
        lines.append(f"  Poisson ratio      {pw['poisson']:.3g} (reported; not used by the model)")
    head = ("rpm", "v m/s", "coll./s", "E_imp mJ", "a_H µm", "trapped", "hits/p/h", "P W", "T_ss °C", "")
    lines += ["", "per rpm (Burgio kinematics; Hertz radius after Maurice & Courtney)",
              "  " + "".join(f"{h:>10}" for h in head)]
    for r in rep["rows"]:
        cells = (f"{r['rpm']:.6g}", f"{r['v_ms']:.3g}", f"{r['collisions_per_s']:.4g}", f"{r['impact_energy_mJ']:.3g}",
                 f"{r['hertz_radius_um']:.3g}", f"{r['trapped_share']:.2e}", f"{r['hits_per_particle_per_h']:.3g}",
                 f"{r['power_W']:.3g}", f"{r['steady_temperature_C']:.0f}",
                 "outside" if not r["valid"] else ("" if r.get("in_window", True) else "uncalib."))
        lines.append("  " + "".join(f"{c:>10}" for c in cells))
    t_max = val["temperature_max_C"]
    lines += ["", "validity",
              f"  rpm                0 to {val['rpm_max']:g}",
              f"  sizes              {val['s_min_um']:g} to {val['s_max_um']:g} µm",
              f"  vial temperature   " + ("no stated maximum" if t_max is None
                                         else f"up to {t_max:g} °C ({val['temperature_reason']})")]
    win = rep.get("window") or {}
    if win.get("temperature_c") is not None:
        lo, hi = win["temperature_c"]
        lines.append(f"  calibrated for     steady vial {lo:.0f}–{hi:.0f} °C ({win['why']}; 'uncalib.' above: "
                     "predictions there are extrapolations)")
    if coeffs is not None:
        lines += ["", "moment coefficients", f"  file               {coeffs.line()}"]
        f = coeffs.file
        if f is not None and f.heldout_mean:
            worst = ", ".join(f"{k.removesuffix('_um')} {100 * float(v):.1f} %" for k, v in f.heldout_max.items()
                              if k != "temperature_c")
            lines.append(f"  held-out NRMSE     mean over schedules: " + f.heldout_line().removeprefix("held-out NRMSE "))
            if worst:
                lines.append(f"                     worst schedule: {worst}")
        if f is not None and f.window:
            r_lo, r_hi = f.window.get("rpm", (float("nan"),) * 2)
            lines.append(f"  identified on      {r_lo:g}–{r_hi:g} rpm")
        if not coeffs.ok:
            lines.append("  commands that run the moment model refuse this card until `bmctl identify` gives it its own")
    return "\n".join(lines)


def run(args) -> int:
    from ..cards import card_report
    from ..config import load_card
    from ..moments.forcard import status

    card = load_card(args.model)
    st = status(card, args.model)
    if args.rpm is not None:
        for r in args.rpm:
            if r > card.mill.rpm_max:
                from ..errors import InputError

                raise InputError(f"--rpm: {r:g} exceeds the mill's rpm_max {card.mill.rpm_max:g} ({args.model})")
    win = st.file.window if st.ok else None
    print(format_report(card_report(card, args.rpm, win), st))
    if args.rpm is None and card.process.rpm <= 0:  # report_rpms centres the table on rpm_max / 2 then
        print(f"bmctl: note: the card's process.rpm is 0 (no recipe speed): the table is around half its rpm_max "
              f"({card.mill.rpm_max / 2:g} rpm); give --rpm for the speeds you mean", file=sys.stderr)
    return 0
