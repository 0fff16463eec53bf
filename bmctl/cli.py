"""The ``bmctl`` command line: one entry point, one module per subcommand.

Each subcommand lives in ``bmctl/commands/<name>.py`` and provides
``configure(parser)`` (adds its arguments) and ``run(args) -> int``.
Bad input anywhere (:class:`bmctl.errors.InputError`, argparse errors) prints
one line ``bmctl: error: ...`` on stderr and exits with status 2, no traceback: whatever the
message quotes (a key or flag holding a newline, a 200,000-character name) is printed with its
control characters escaped and cut to a bounded length (:func:`bmctl.errors.one_line`).
"""

from __future__ import annotations

import argparse
import importlib
import os
import re
import signal
import sys

# bmctl's matrices are small: BLAS worker threads only spin (a 12 h MPC trial: 8.3 s CPU for 6.7 s
# wall with OpenBLAS's default threads, 6.7 s with one). Set before numpy loads; the user's
# setting wins (docs/performance.md).
for _var in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

from .errors import InputError, one_line

#: subcommand -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "simulate": ("bmctl.commands.simulate", "run the stochastic milling plant on a model card"),
    "identify": ("bmctl.commands.identify", "fit the moment model to plant experiments"),
    "linearize": ("bmctl.commands.linearize", "linear analysis of the moment model (python-control)"),
    "verify": ("bmctl.commands.verify", "verify the Monte Carlo engine against analytic solutions"),
    "measure": ("bmctl.commands.measure", "segment micrographs into per-particle size and aspect ratio"),
    "estimate": ("bmctl.commands.estimate", "particle-filter state and parameter estimates from samples"),
    "trial": ("bmctl.commands.trial", "closed-loop trial: plant, sampling, estimator, controller"),
    "whatif": ("bmctl.commands.whatif", "compare rpm schedules on a plant ensemble"),
    "design": ("bmctl.commands.design", "offline open-loop rpm/rest schedule from the MPC problem"),
    "compare": ("bmctl.commands.compare", "measured particle sample against the plant prediction at a time"),
    "card": ("bmctl.commands.card", "model cards: derived masses, kinematics and validity (card show)"),
    "campaign": ("bmctl.commands.campaign", "run a real mill: log, sample, advise, decide, report (SQLite log)"),
    "calibrate": ("bmctl.commands.calibrate", "fit card parameters to measured micrograph series (plant as simulator)"),
}


#: subcommands that estimate their work before starting and take the budget flags (bmctl.work)
BUDGETED = ("simulate", "identify", "linearize", "estimate", "trial", "whatif", "design", "compare", "calibrate",
            "measure")


def _budget_flags(p: argparse.ArgumentParser) -> None:
    from .commands._args import float_arg

    g = p.add_argument_group("work budget (the run is estimated first and refused beyond it)")
    g.add_argument("--budget-cpu-h", type=float_arg("--budget-cpu-h", lo=0.0, hi=1e6, strict=True), default=None,
                   metavar="H", help="CPU hours this run may take (default: BMCTL_BUDGET_CPU_H, else 1)")
    g.add_argument("--budget-memory-gb", type=float_arg("--budget-memory-gb", lo=0.0, hi=1e6, strict=True),
                   default=None, metavar="G",
                   help="memory this run may use, GiB (default: BMCTL_BUDGET_MEMORY_GB, else half of this machine's)")


class _Parser(argparse.ArgumentParser):
    """ArgumentParser whose errors are one line and exit 2."""

    def error(self, message: str):  # noqa: D401 - argparse API
        prefix = "" if self.prog == "bmctl" else f"{self.prog.removeprefix('bmctl ')}: "
        raise InputError(f"{prefix}{message}")


def build_parser(available: dict[str, object] | None = None) -> argparse.ArgumentParser:
    """Build the top-level parser; each subcommand's arguments are added only when its module is given.

    Parameters
    ----------
    available : dict, optional
        Subcommand name -> imported module (``configure``, ``run``). Subcommands not in it are
        listed in ``bmctl --help`` from :data:`COMMANDS` without importing their module;
        ``None`` imports every subcommand (see :func:`_modules`).
    """
    if available is None:
        available = _modules()
    parser = _Parser(prog="bmctl", description="Closed-loop control and optimisation of ball milling.")
    from . import __version__

    parser.add_argument("--version", action="version", version=f"bmctl {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    for name, (modname, help_) in COMMANDS.items():
        mod = available.get(name)
        if mod is None:
            sub.add_parser(name, help=help_, description=help_)
            continue
        p = sub.add_parser(name, help=help_, description=(mod.__doc__ or help_).strip().splitlines()[0])
        mod.configure(p)
        if name in BUDGETED:
            _budget_flags(p)
        p.set_defaults(_run=mod.run)
    return parser


def _modules(names=None) -> dict[str, object]:
    """Import the subcommand modules named (all when ``None``) that exist."""
    mods = {}
    for name, (modname, _) in COMMANDS.items():
        if names is not None and name not in names:
            continue
        try:
            mods[name] = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name != modname:
                raise
    return mods


def _chosen(argv: list[str]) -> list[str]:
    """The subcommand named on the command line (the first word that is not an option), if any.

    Only that subcommand's module is imported to build the parser, so ``bmctl --help`` and
    ``bmctl simulate ...`` do not pay for importing the other eight.
    """
    for word in argv:
        if not word.startswith("-"):
            return [word] if word in COMMANDS else []
    return []


def _safe_streams() -> None:
    """Make stdout/stderr whose encoding lacks characters bmctl prints (µ, °, ≤: an ASCII or Latin-1
    locale such as ``LC_ALL=C``) write them as ``\\xb5``-style escapes instead of failing with
    UnicodeEncodeError. The encoding itself stays; a UTF-8 (any UTF) stream is left as it is."""
    import codecs

    for stream in (sys.stdout, sys.stderr):
        try:
            if codecs.lookup(stream.encoding or "ascii").name.startswith("utf"):
                continue
        except (AttributeError, TypeError, LookupError):  # a replacement stream without a usable encoding
            pass
        if callable(getattr(stream, "reconfigure", None)):
            try:
                stream.reconfigure(errors="backslashreplace")
            except (ValueError, OSError, AttributeError):  # closed or detached: nothing to protect
                pass


#: a value that starts with a minus and a digit but is not one number (``-5,60,,``: a list of readings)
_NEGATIVE_LIST = re.compile(r"^-\.?\d[\d.,:eE+-]*$")


def _negative_lists(argv: list[str]) -> list[str]:
    """``--temperatures -5,60`` as ``--temperatures=-5,60``: argparse takes a value that starts with a
    minus and is not a plain number for an option ("expected one argument"); a plain negative number
    it reads as a value already.

    Examples
    --------
    >>> _negative_lists(["estimate", "c.toml", "--temperatures", "-5,60", "--rpm", "-3"])
    ['estimate', 'c.toml', '--temperatures=-5,60', '--rpm', '-3']
    """
    out: list[str] = []
    for i, tok in enumerate(argv):
        if tok == "--":  # the end of the options: the rest as given
            return out + list(argv[i:])
        prev = out[-1] if out else ""
        if (prev.startswith("--") and "=" not in prev and _NEGATIVE_LIST.match(tok)
                and not re.fullmatch(r"-\d+|-\d*\.\d+", tok)):
            out[-1] = f"{prev}={tok}"
        else:
            out.append(tok)
    return out


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``timeout``, a batch scheduler's end of a job), raised where Ctrl-C would be, so
    the same clean-up runs: no temporary file or half-written output is left behind."""


def _on_sigterm(signum, frame) -> None:
    raise Terminated()


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status (0 ok, 2 bad input, 130 interrupted, 141 output pipe closed,
    143 terminated)."""
    _safe_streams()
    try:
        own_process = argv is None
        if argv is None:  # the bmctl command's own process: the numpy field's heap setting; SIGTERM as Ctrl-C
            from .heap import keep_heap  # not via bmctl.moments: that imports numpy

            keep_heap()
            signal.signal(signal.SIGTERM, _on_sigterm)
        argv = _negative_lists(sys.argv[1:] if argv is None else list(argv))
        parser = build_parser(_modules(_chosen(argv)))
        args = parser.parse_args(argv)
        from .work import set_budget

        set_budget(getattr(args, "budget_cpu_h", None), getattr(args, "budget_memory_gb", None))
        rc = int(args._run(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        if own_process:  # the work is done: a Ctrl-C while Python tears down would end it as 130, silently
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
        return rc
    except InputError as exc:
        print(f"bmctl: error: {one_line(str(exc))}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `bmctl ... | head`: the reader left; quiet, as Unix tools are
        import os

        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # no second error when Python flushes stdout at exit
        return 141
    except OSError as exc:  # an output that cannot be written (disk full, permissions): one line, no traceback
        where = exc.filename if exc.filename is not None else "output"
        print(f"bmctl: error: {one_line(f'{where}: {exc.strerror or exc}')}", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, SystemError) as exc:
        if not _interrupt(exc):  # a SystemError of its own is a bug: its traceback is wanted
            raise
        words = sys.argv[1:] if argv is None else list(argv)
        resumable = _chosen(words) == ["trial"] and "--campaign" not in words
        term = _interrupt(exc, Terminated)
        print(f"bmctl: {'terminated (SIGTERM)' if term else 'interrupted (Ctrl-C)'}: no output was left "
              "half-written (each file, or the whole set, is renamed into place only when complete)"
              + ("; carry the trial on with --resume DIR and the same --seed" if resumable else ""), file=sys.stderr)
        sys.unraisablehook = _quiet  # objects a library left half-built when interrupted: no traceback after the line
        return 143 if term else 130


def _quiet(unraisable) -> None:
    """Drop an exception raised where Python cannot raise it (a ``__del__`` of an object whose
    ``__init__`` Ctrl-C cut short), after the one line an interrupted run prints."""


def _interrupt(exc: BaseException, kind: type = KeyboardInterrupt) -> bool:
    """Ctrl-C (or SIGTERM: ``kind`` Terminated), also where compiled (numba) code reports it as a
    SystemError caused by a KeyboardInterrupt."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, kind):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
