"""The milling plant: the paper's stochastic model as a fast, seeded simulator.

One class, :class:`Plant`, and a factory, :func:`make_plant`. The Monte Carlo
scheme is constant-number (Smith & Matsoukas 1998): M simulated particles stand for
the vial's population with a common weight w = X / sum(s^2), where X is the
represented total of s^2 (planar mass, eqn 2) and stays exact. Bonding frees one slot
and fracture needs one; the batch fills freed slots with fracture fragments and the
rest with copies of random particles, or removes random particles.

Events are processed in vectorised batches: in a step dt a Poisson number of impacts,
each on a pair of distinct particles (the impacted particle i and its bonding partner
j, eqn 15) drawn independently, as one impact at a time would draw them. Each impact
also draws the slot v that a bond's copy or a fracture's extra fragment will use. A
batch processes, at once, the impacts that come first in the queue for all of their
slots i, j, v; the others wait for the next batch. Every slot thus sees its impacts in
their drawn order, and a new particle takes over its slot's later impacts
(docs/verification.md).
"""

from __future__ import annotations

import math
import numbers
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from ..config import ModelCard, card_schedule, load_card
from ..errors import InputError, require_generator
from ..shipped import models_dir
from . import events as ev
from . import thermal
from .kernels import Kernels, PaperKernels
from .kinematics import Kinematics, kinematics
from .population import UM, initial_sample, moments, raster

ENGINES = ("numba", "numpy")  # the compiled event step (default) and the numpy batch code it replicates

MODELS_DIR = models_dir()  # the shipped cards: a clone's models/, or the copy a wheel carries


def default_card() -> ModelCard:
    """The lab card (Al-Ni 1:1, 300 rpm) shipped in ``models/``."""
    return load_card(MODELS_DIR / "alni-1to1-300rpm-lab.toml")


@dataclass
class EventCounts:
    """Counters of events in the simulated sample."""

    impacts: int = 0
    bonds: int = 0
    fractures: int = 0

    def copy(self) -> "EventCounts":
        return EventCounts(self.impacts, self.bonds, self.fractures)


@dataclass
class Record:
    """One recorded time of a run.

    Attributes
    ----------
    t_h : float
        Time (h).
    moments : dict
        Output of :meth:`Plant.moments`.
    temperature_c : float
        Vial temperature.
    bonds, fractures : int
        Events in the simulated sample since the previous record.
    p : ndarray or None
        Raster p(s, r) when kept.
    """

    t_h: float
    moments: dict
    temperature_c: float
    bonds: int
    fractures: int
    p: np.ndarray | None = None


class Plant:
    """The stochastic milling plant (eqns 1-20 with kinematics, heat and hardening).

    Parameters
    ----------
    card : ModelCard or path-like
        Calibrated parameters (see ``models/``), or the card file.
    rng : numpy.random.Generator
        The single source of randomness of this plant.
    particles : int, optional
        Number M of simulated particles (default: the card's, 20,000).
    kernels : Kernels, optional
        The impact physics the event machinery runs (default: the paper's,
        :class:`bmctl.plant.kernels.PaperKernels`, with the card's ``[simulation] samplers``);
        verification swaps in simple kernels.
    engine : {"numba", "numpy"}, optional
        How the events run: ``"numba"`` (default) runs the paper's kernels as one compiled
        loop per step (:mod:`bmctl.plant._compiled`), ``"numpy"`` as vectorised numpy batches.
        Both draw the same variates in the same order: a seed gives the same trajectory
        (docs/performance.md). Other kernels, and subclasses that override the event
        methods, always run the numpy code.

    Examples
    --------
    >>> import numpy as np
    >>> from bmctl.plant import make_plant
    >>> plant = make_plant("models/alni-1to1-300rpm-lab.toml", seed=1, particles=2000)  # doctest: +SKIP
    >>> plant.advance(rpm=300, hours=1.0)  # doctest: +SKIP
    >>> plant.moments()["s_mean_um"] > 40  # doctest: +SKIP
    True
    """

    def __init__(self, card: ModelCard, rng: np.random.Generator, particles: int | None = None,
                 kernels: Kernels | None = None, engine: str = "numba"):
        if engine not in ENGINES:
            raise InputError(f"engine: must be one of {', '.join(ENGINES)} (got {engine!r})")
        if isinstance(card, (str, os.PathLike)):  # a card file, as make_plant takes it
            card = load_card(card)
        elif not isinstance(card, ModelCard):
            raise TypeError(f"card: must be a ModelCard or a card file's path (got {type(card).__name__})")
        self.card = card
        self.kernels: Kernels = PaperKernels(card.simulation.samplers) if kernels is None else kernels
        self.engine = engine
        require_generator(rng, "rng")
        self.rng = rng
        if particles is not None and (isinstance(particles, bool) or not isinstance(particles, numbers.Integral)):
            raise InputError(f"particles: must be a whole number >= 2 (got {particles!r})")
        M = int(card.simulation.particles if particles is None else particles)
        if M < 2:
            raise InputError(f"particles: must be >= 2 (got {M})")
        init = card.initial
        self.s, self.r = initial_sample(rng, M, init.s_mean_um, init.s_std_um, init.r_mean)
        mat, mill = card.material, card.mill
        self.powder_kg = mill.ball_count * mat.impactor_mass_kg / mill.ball_to_powder_ratio
        n_real = self.powder_kg / (mat.powder_density_kg_m3 * math.pi / 6 * np.mean(self.s**3))
        self.total_area = float(n_real * np.mean(self.s**2))  # X: represented sum of s^2 (eqn 2), m^2
        self.t_s = 0.0
        self.temperature_C = card.thermal.ambient_C
        self.hardening = 0.0
        self.counts = EventCounts()
        self._queue = (np.empty(0, dtype=np.int64),) * 3  # impacts (i, j, v) waiting for a later batch
        st = card.stochastic
        self._gamma = st.gamma_per_um2 * 1e12  # 1/um^2 -> 1/m^2 (eqn 15)
        self._delta = st.delta_per_um2 * 1e12  # (eqn 20)
        self._dissipated_share = ev.mean_dissipated_share(st.alpha, st.beta)

    # --- state -----------------------------------------------------------------------------
    @property
    def M(self) -> int:
        """Number of simulated particles."""
        return self.s.size

    @property
    def weight(self) -> float:
        """Real particles per simulated particle, w = X / sum(s^2)."""
        return self.total_area / float(np.dot(self.s, self.s))

    @property
    def represented_particles(self) -> float:
        """Number of real particles the sample stands for (w M)."""
        return self.weight * self.M

    def hit_rate(self, kin: Kinematics) -> float:
        """Impacts per particle per second, the kernels' rate.

        For the paper's kernels f * trapped share * E[(U_in-U_out)/U_in] * E[1/c(psi)], with
        c(psi) the mean dissipated share at incidence psi (:class:`bmctl.plant.kernels.PaperKernels`).
        """
        return self.kernels.rate(self, kin)

    def effective_yield_stress(self) -> float:
        """sigma_eff at the current temperature and hardening."""
        return thermal.effective_yield_stress(
            self.card.material.yield_stress_Pa, self.temperature_C, self.hardening, self.card.thermal
        )

    # --- dynamics --------------------------------------------------------------------------
    def advance(self, rpm: float, hours: float, milling: float = 1.0, progress: Callable[[float], None] | None = None):
        """Mill at ``rpm`` for ``hours * milling``, then rest for ``hours * (1 - milling)``.

        Parameters
        ----------
        rpm : float
            Sun-disc speed, 0 <= rpm <= the card's ``mill.rpm_max``; 0 is a rest.
        hours : float
            Length of the interval (h), >= 0.
        milling : float, optional
            Fraction of the interval spent milling, in [0, 1].
        progress : callable, optional
            Called with the hours done in each step (for progress bars).
        """
        _check_input(rpm, hours, milling, self.card.mill.rpm_max)
        mill_s = hours * 3600.0 * milling
        rest_s = hours * 3600.0 - mill_s
        try:
            if mill_s > 0 and rpm > 0:
                self._run(kinematics(self.card, rpm), mill_s, progress)
            else:
                rest_s += mill_s
            if rest_s > 0:
                self._run(kinematics(self.card, 0.0), rest_s, progress)
        except (ZeroDivisionError, OverflowError, FloatingPointError):
            self._diverged(rpm)  # sizes overflowed inside a step
        if not float(self.s.max()) <= 2 * self.card.mill.vial_radius_m:  # larger than the vial (m), or NaN
            self._diverged(rpm)

    def _diverged(self, rpm: float):
        """One-line error for a population whose bonding ran away (particles larger than the vial)."""
        raise InputError(f"{self.card.card.name}: the plant's particles grew larger than the vial at {rpm:g} rpm "
                         f"(largest {float(np.nanmax(self.s)) / UM:.3g} µm after {self.t_s / 3600:.3g} h): the card lies outside "
                         "where the plant's laws hold (bonding outruns fracture); lower mill.rpm_max or "
                         "change the loading")

    def run_schedule(
        self,
        segments: Sequence[tuple[float, float]],
        record_every_h: float = 1.0,
        keep_raster: bool = False,
        progress: Callable[[float], None] | None = None,
        on_record: Callable[["Plant"], None] | None = None,
    ) -> list[Record]:
        """Run (hours, rpm) segments, recording every ``record_every_h`` hours (t = 0 included).

        ``on_record(plant)`` is called at each recorded time (t = 0 included), e.g. to keep samples.
        Segments that are not (hours, rpm) with hours a finite number >= 0, and a ``record_every_h``
        that is not a finite number of hours > 0, are refused (:class:`~bmctl.errors.InputError`) as
        by :func:`bmctl.loop.run_open_loop`.
        """
        from ..loop import check_open_loop

        check_open_loop(segments, record_every_h)
        total = sum(h for h, _ in segments)
        times = np.arange(0.0, total + 1e-9, record_every_h)
        if total - times[-1] > 1e-9:
            times = np.append(times, total)
        records = [self._record(keep_raster, self.counts.copy())]
        if on_record is not None:
            on_record(self)
        last = self.counts.copy()
        bounds = np.cumsum([0.0] + [h for h, _ in segments])
        t0 = self.t_s / 3600.0
        for k in range(1, times.size):
            a, b = times[k - 1], times[k]
            for (h, rpm), lo, hi in zip(segments, bounds[:-1], bounds[1:]):
                x0, x1 = max(a, lo), min(b, hi)
                if x1 > x0 + 1e-12:
                    self.advance(rpm, x1 - x0, progress=progress)
            rec = self._record(keep_raster, last)
            rec.t_h = t0 + b
            records.append(rec)
            if on_record is not None:
                on_record(self)
            last = self.counts.copy()
        records[0].t_h = t0
        return records

    def _record(self, keep_raster: bool, last: EventCounts) -> Record:
        return Record(
            t_h=self.t_s / 3600.0,
            moments=self.moments(),
            temperature_c=self.temperature_C,
            bonds=self.counts.bonds - last.bonds,
            fractures=self.counts.fractures - last.fractures,
            p=self.raster() if keep_raster else None,
        )

    def _run(self, kin: Kinematics, seconds: float, progress) -> None:
        sim = self.card.simulation
        rate = self.hit_rate(kin)
        power = kin.mean_power_W
        th = self.card.thermal
        compiled = rate > 0 and self._compiled_step()
        steps = []  # compiled: (mean new impacts, parameters at the step's start) of each step, run at the end
        done = 0.0
        while done < seconds - 1e-9:
            dt = min(sim.max_step_s, seconds - done)
            if rate > 0:
                dt = min(dt, sim.batch_fraction / rate)
            if compiled:
                steps.append((rate * self.M * dt / 2.0, self._step_params()))
            elif rate > 0:
                self._impacts(kin, int(self.rng.poisson(rate * self.M * dt / 2.0)))
            self.temperature_C = thermal.step_temperature(self.temperature_C, power, dt, th)
            self.hardening = thermal.step_hardening(self.hardening, power, self.powder_kg, dt, th)
            self.t_s += dt
            done += dt
            if progress is not None:
                progress(dt / 3600.0)
        if compiled:
            self._run_compiled(kin, steps)
        else:
            self._impacts(kin, 0, flush=True)  # impacts still queued belong to this interval

    def _impacts(self, kin: Kinematics, n: int, flush: bool = False) -> None:
        """Queue ``n`` new impacts and process the queue's first round (every round with ``flush``).

        An impact is a pair (i, j) of distinct particles drawn uniformly and independently of
        the other impacts, and a slot v != j drawn uniformly for its rebalancing (the clone
        source if i and j bond, the victim of an extra fragment if one breaks). A round is
        the impacts that come first in the queue for each of their slots i, j and v: they
        share no slot, so they run at once, and every slot sees its impacts in queue order.
        The physics of an impact is ``self.kernels``.
        """
        if self._compiled_step():
            self._impacts_compiled(kin, n, flush)
            return
        M, rng = self.M, self.rng
        i = rng.integers(0, M, size=n)
        j = (i + rng.integers(1, M, size=n)) % M  # uniform over the others
        v = (j + rng.integers(1, M, size=n)) % M  # rebalancing slot, never the freed slot j
        qi, qj, qv = self._queue
        if qi.size:
            i, j, v = np.concatenate([qi, i]), np.concatenate([qj, j]), np.concatenate([qv, v])
        while i.size:
            ready = _first_round(i, j, v, M)
            self._impact_round(kin, i[ready], j[ready], v[ready])
            i, j, v = i[~ready], j[~ready], v[~ready]
            if not flush:
                break
        self._queue = (i, j, v)

    def _compiled_step(self) -> bool:
        """Whether the events run compiled: numba engine, the paper's kernels, the event methods as here."""
        cls = type(self)
        return (self.engine == "numba" and type(self.kernels) is PaperKernels
                and cls._impact_round is Plant._impact_round and cls._rebalance is Plant._rebalance
                and _compiled_ready())

    def _impacts_compiled(self, kin: Kinematics, n: int, flush: bool) -> None:
        """:meth:`_impacts` with the paper's kernels as one compiled call (same draws, same results)."""
        self._run_compiled(kin, [], n_new=n, flush=flush)

    def _run_compiled(self, kin: Kinematics, steps: list, n_new: int = 0, flush: bool = True) -> None:
        """Run the steps (mean new impacts, :meth:`_step_params`) of :meth:`_run`, then the flush, compiled.

        Without steps: ``n_new`` impacts and one round (every round with ``flush``), as :meth:`_impacts`.
        """
        from . import _compiled as cc  # numba is imported on the first compiled step only

        if getattr(self, "_seen", None) is None or self._seen.size != self.M:
            self._seen = np.zeros(self.M, dtype=np.bool_)
        self.s = np.ascontiguousarray(self.s, dtype=float)
        self.r = np.ascontiguousarray(self.r, dtype=float)
        base = self._static_params(kin, cc)
        rows = [dyn for _, dyn in steps] + [self._step_params()]
        p = np.repeat(base[None, :], len(rows), axis=0)
        p[:, cc.P_SIGMA:cc.P_ETA_EQ + 1] = rows
        lam = np.array([m for m, _ in steps], dtype=float)
        qi, qj, qv, n_imp, n_bond, n_frac = cc.run_steps(self.rng, self.s, self.r, *self._queue, lam, p, self._seen,
                                                         n_new, flush, self._sampler_tables())
        self._queue = (qi, qj, qv)
        self.counts.impacts += n_imp
        self.counts.bonds += n_bond
        self.counts.fractures += n_frac

    def _sampler_tables(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The tables of the tabulated samplers: energy main and tail, Beta(alpha + 1, 2), Beta(beta + 1, 2)."""
        if self.kernels.samplers != "tabulated":
            dummy = np.zeros(2)
            return dummy, dummy, dummy, dummy
        from ..physics import samplers as tab

        st = self.card.stochastic
        return (*tab.energy_tables(), tab.beta_a2_table(st.alpha + 1.0), tab.beta_a2_table(st.beta + 1.0))

    def _step_params(self) -> tuple[float, float, float, float]:
        """sigma_eff, u_bond, u_frac and the rounding efficiency at the current temperature and hardening."""
        card = self.card
        part = card.partition
        u_bond, u_frac = thermal.thresholds(card.material.bond_threshold_J_per_m, self.temperature_C, self.hardening,
                                            card.thermal)
        eta = part.equiaxing_efficiency * max(0.0, 1.0 - part.equiaxing_hardening * self.hardening)
        return (self.effective_yield_stress(), u_bond, u_frac, eta)

    def _static_params(self, kin: Kinematics, cc) -> np.ndarray:
        """The float parameters of :func:`bmctl.plant._compiled.impacts` that stay fixed over an interval."""
        from .kernels import dissipation_coefficients

        st, mat, part = self.card.stochastic, self.card.material, self.card.partition
        a, b = dissipation_coefficients(st.alpha, st.beta)
        p = np.zeros(cc.N_PARAMS)
        p[cc.P_THETA] = kin.energy_scale
        p[cc.P_TRAPPED] = kin.trapped_fraction * self.total_area  # (6)
        p[cc.P_SQRT_A], p[cc.P_SQRT_B] = math.sqrt(a), math.sqrt(b)
        p[cc.P_ZETA_B], p[cc.P_XI_A] = st.alpha + 1.0, st.beta + 1.0  # (9)
        p[cc.P_STRAIN_EFF], p[cc.P_MAX_STRAIN] = part.strain_efficiency, part.max_strain
        p[cc.P_MODULUS], p[cc.P_SHARPNESS] = mat.elastic_modulus_Pa, part.threshold_sharpness
        p[cc.P_GAMMA], p[cc.P_DELTA] = self._gamma, self._delta
        p[cc.P_TABULATED] = 1.0 if self.kernels.samplers == "tabulated" else 0.0
        return p

    def _impact_round(self, kin: Kinematics, i: np.ndarray, j: np.ndarray, v: np.ndarray) -> None:
        """Impacts on pairs (i, j) that share no slot (rebalancing slots v included)."""
        out = self.kernels.collide(self, kin, self.s[i], self.r[i], self.s[j], self.r[j], self.rng)
        bond, frac = out.bond, out.frac

        # write back: survivors of shape change, bonded into slot i, fragment 1 in place
        idx = np.concatenate([i, j])
        self.r[idx] = out.r
        self.s[i[bond]] = out.s_bond
        self.r[i[bond]] = out.r_bond
        fidx = idx[frac]
        self.s[fidx] = out.s1
        self.r[fidx] = out.r1
        self._rebalance(j[bond], out.s2, out.r2, v[bond], np.concatenate([v, v])[frac])
        self.counts.impacts += i.size
        self.counts.bonds += int(bond.sum())
        self.counts.fractures += int(frac.sum())

    def _rebalance(self, free: np.ndarray, s_new: np.ndarray, r_new: np.ndarray,
                   src: np.ndarray, dst: np.ndarray) -> None:
        """Constant-number step: freed slots take new fragments, then copies; extra fragments replace.

        ``free``: slots freed by bonds, with ``src`` their clone sources; ``s_new``, ``r_new``:
        the fragments that need a slot, with ``dst`` their victim slots. A slot left free
        takes a copy of the particle in its source slot; a fragment left over replaces the
        particle in its victim slot (both drawn uniformly with the impact). The two parts of
        one pair that both broke share a victim slot; the second draws another.
        """
        k = min(free.size, s_new.size)
        self.s[free[:k]] = s_new[:k]
        self.r[free[:k]] = r_new[:k]
        if free.size > k:  # more bonds than fractures: copy the clone sources into the free slots
            holes, src = free[k:], src[k:]
            self.s[holes] = self.s[src]
            self.r[holes] = self.r[src]
        elif s_new.size > k:  # more fractures: the extra fragments replace the particles in their victim slots
            dst = dst[k:].copy()
            _, first = np.unique(dst, return_index=True)
            twice = np.ones(dst.size, dtype=bool)
            twice[first] = False
            if twice.any():
                dst[twice] = self.rng.integers(0, self.M, size=int(twice.sum()))
            self.s[dst] = s_new[k:]
            self.r[dst] = r_new[k:]

    # --- observation -----------------------------------------------------------------------
    def moments(self) -> dict:
        """Mean/std/mode of s (um) and r, plus time, temperature and hardening."""
        m = moments(self.s, self.r)
        m.update(t_h=self.t_s / 3600.0, temperature_c=self.temperature_C, hardening=self.hardening)
        return m

    def raster(self) -> np.ndarray:
        """Population fractions p(s, r) on the paper's raster (1 um x 0.01)."""
        return raster(self.s, self.r, self.card.simulation.s_max_um)

    def sample(self, n: int, rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Draw ``n`` particles as a micrograph sees them (number-weighted, without replacement).

        Parameters
        ----------
        n : int
            Number of particles; ``n`` are returned, drawn with replacement when n > M.
        rng : numpy.random.Generator, optional
            Generator to draw with (default: the plant's own).

        Returns
        -------
        s_um, r : ndarray
            Sizes (um) and aspect ratios. For segmentation noise and resolution limits use
            :func:`bmctl.measure.sampler.micrograph_sample` on the population.
        """
        if isinstance(n, bool) or not isinstance(n, numbers.Integral) or n < 1:
            raise InputError(f"sample: n must be a whole number >= 1 (got {n!r})")
        if rng is not None and not isinstance(rng, np.random.Generator):
            raise TypeError(f"sample: rng must be a numpy.random.Generator or None (got {type(rng).__name__})")
        g = self.rng if rng is None else rng
        k = g.choice(self.M, size=n, replace=n > self.M)
        return self.s[k] / UM, self.r[k].copy()

    def snapshot(self) -> dict:
        """The full state (arrays, clocks, counters, generator state) as a plain dict."""
        return {
            "s": self.s.copy(),
            "r": self.r.copy(),
            "t_s": self.t_s,
            "temperature_C": self.temperature_C,
            "hardening": self.hardening,
            "total_area": self.total_area,
            "counts": (self.counts.impacts, self.counts.bonds, self.counts.fractures),
            "rng": self.rng.bit_generator.state,
        }

    def restore(self, snap: dict) -> None:
        """Restore a state produced by :meth:`snapshot` (the generator state included); a state
        that lacks an entry or does not convert is refused before anything is changed."""
        missing = [k for k in _SNAPSHOT_KEYS if not isinstance(snap, dict) or k not in snap]
        if missing:
            raise ValueError(f"state: lacks {', '.join(missing)} (expected a dict from Plant.snapshot or get_state)")
        s, r = np.array(snap["s"], dtype=float), np.array(snap["r"], dtype=float)
        if s.ndim != 1 or s.shape != r.shape:
            raise ValueError(f"state: s and r must be 1-D arrays of one length (got shapes {s.shape} and {r.shape})")
        if not (np.all(np.isfinite(s)) and np.all(s > 0) and np.all((r >= 0) & (r < 1))):
            raise ValueError("state: every s must be finite and > 0 (m) and every r in [0, 1)")
        values = (float(snap["t_s"]), float(snap["temperature_C"]), float(snap["hardening"]),
                  float(snap["total_area"]), EventCounts(*(int(c) for c in snap["counts"])))
        if not (all(map(math.isfinite, values[:4])) and values[0] >= 0 and 0 <= values[2] <= 1 and values[3] > 0):
            raise ValueError(f"state: t_s >= 0, temperature_C, hardening in [0, 1] and total_area > 0 must be finite "
                             f"(got {values[:4]})")
        self.rng.bit_generator.state = snap["rng"]  # refuses a foreign state before anything else is set
        self.s, self.r = s, r
        self.t_s, self.temperature_C, self.hardening, self.total_area, self.counts = values

    @property
    def temperature_c(self) -> float:
        """Vial temperature now (degC); the :class:`bmctl.loop.Mill` reading."""
        return self.temperature_C

    def get_state(self) -> dict:
        """The full state as plain data (:meth:`snapshot` plus the queued impacts), for checkpoints."""
        state = self.snapshot()
        state["counts"] = list(state["counts"])
        state["queue"] = [q.copy() for q in self._queue]
        return state

    def set_state(self, state: dict) -> None:
        """Restore a state from :meth:`get_state` (refused whole, as :meth:`restore`)."""
        if not isinstance(state, dict) or "queue" not in state:
            raise ValueError("state: lacks queue (expected a dict from Plant.get_state)")
        queue = tuple(np.asarray(q, dtype=np.int64) for q in state["queue"])
        m = np.asarray(state.get("s", ())).size  # the slots of the state's population
        # the compiled events read and write the slots the queue names: unchecked, a bad index is memory
        if (len(queue) != 3 or any(q.ndim != 1 or q.shape != queue[0].shape for q in queue)
                or any(q.size and (int(q.min()) < 0 or int(q.max()) >= m) for q in queue)):
            raise ValueError(f"state: queue must be three 1-D index arrays of one length, each index in [0, {m})")
        self.restore(state)
        self._queue = queue


#: the entries of :meth:`Plant.snapshot`
_SNAPSHOT_KEYS = ("s", "r", "t_s", "temperature_C", "hardening", "total_area", "counts", "rng")

_READY = {"warm": False, "checked": -math.inf}
_RECHECK_S = 30.0


def _compiled_ready() -> bool:
    """Whether the compiled kernels are in the on-disk cache; if not, compile them in the background.

    Until the cache is warm the numba engine runs the numpy code, which gives the same results:
    a first run on a fresh install is never slower than the numpy engine (the compile, once,
    takes a background process; docs/performance.md). Set ``BMCTL_COMPILE=now`` to compile in
    this process instead.
    """
    if _READY["warm"]:
        return True
    import os
    import time

    from . import _compiled as cc

    if os.environ.get("BMCTL_COMPILE", "") == "now":
        _READY["warm"] = True
        return True
    now = time.monotonic()
    if now - _READY["checked"] < _RECHECK_S:
        return False
    _READY["checked"] = now
    if cc.cache_is_warm():
        _READY["warm"] = True
    else:
        cc.compile_in_background()
    return _READY["warm"]


def _first_round(i: np.ndarray, j: np.ndarray, v: np.ndarray, M: int) -> np.ndarray:
    """Mask of the queued impacts k that come first in the queue for each of i[k], j[k], v[k].

    The selected impacts share no slot; every impact left out shares a slot with an
    earlier one, so running rounds of first impacts keeps each slot's impacts in order.
    """
    k = np.arange(i.size)
    first = np.full(M, i.size, dtype=np.int64)
    for slots in (v, j, i):
        np.minimum.at(first, slots, k)
    return (first[i] == k) & (first[j] == k) & (first[v] == k)


def _check_input(rpm: float, hours: float, milling: float, rpm_max: float) -> None:
    from ..limits import HOURS_MAX

    for name, val in (("rpm", rpm), ("hours", hours), ("milling", milling)):
        if isinstance(val, (bool, np.bool_)) or not isinstance(val, numbers.Real):  # "300", None, [300], 3j
            raise TypeError(f"{name}: must be a number (got {type(val).__name__})")
        if not math.isfinite(val):
            raise InputError(f"{name}: must be a finite number (got {val})")
    if rpm < 0 or rpm > rpm_max:
        raise InputError(f"rpm: must be in [0, {rpm_max:g}] (got {rpm:g})")
    if not 0 <= hours <= HOURS_MAX:  # one batch at most: a typo of 1e9 h ran for half a day
        raise InputError(f"hours: must be in [0, {HOURS_MAX:g}] (got {hours:g})")
    if not 0 <= milling <= 1:
        raise InputError(f"milling: must be in [0, 1] (got {milling:g})")


def make_plant(card: ModelCard | str | Path, seed: int | None = None, particles: int | None = None,
               rng: np.random.Generator | None = None, engine: str = "numba") -> Plant:
    """Create a :class:`Plant` from a model card (object or TOML path).

    Parameters
    ----------
    card : ModelCard or path-like
        The model card.
    seed : int, optional
        Seed of the plant's ``numpy.random.Generator`` (ignored when ``rng`` is given).
    particles : int, optional
        Number of simulated particles M.
    rng : numpy.random.Generator, optional
        Use this generator instead of a new one.
    engine : {"numba", "numpy"}, optional
        See :class:`Plant`.

    Returns
    -------
    Plant

    Raises
    ------
    TypeError
        ``card`` neither a path nor a :class:`~bmctl.config.ModelCard`.

    Examples
    --------
    >>> from bmctl.plant import make_plant
    >>> p = make_plant("models/alni-1to1-300rpm-lab.toml", seed=0, particles=500)  # doctest: +SKIP
    >>> p.M  # doctest: +SKIP
    500
    """
    if rng is None and seed is not None and not isinstance(seed, (np.random.SeedSequence, np.random.BitGenerator,
                                                                  np.random.Generator)) \
            and (isinstance(seed, bool) or not isinstance(seed, numbers.Integral) or seed < 0):
        raise InputError(f"seed: must be a non-negative integer (got {seed!r})")
    if not isinstance(card, (ModelCard, str, os.PathLike)):
        raise TypeError(f"card: must be a model card path (str or os.PathLike) or a ModelCard object "
                        f"(got {type(card).__name__})")
    if not isinstance(card, ModelCard):
        card = load_card(card)
    return Plant(card, rng if rng is not None else np.random.default_rng(seed), particles, engine=engine)


__all__ = ["Plant", "make_plant", "default_card", "Record", "EventCounts", "card_schedule"]
