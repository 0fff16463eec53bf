"""Run a real mill: a campaign takes measured samples in, recommends the next rpm and rest, and
keeps every action, sample, estimate, plan and decision in one SQLite log (docs/campaign.md).

Verbs: :func:`init`, :func:`log`, :func:`sample`, :func:`advise`, :func:`decide`, :func:`status`,
:func:`report` (``bmctl campaign <verb>`` calls them); :class:`Campaign` keeps one open.
"""

from .workflow import (CAMPAIGN_FILTER, TWO_MULT_FILTER, Campaign, advise, decide, ensure_coefficients, init, log,
                       report, sample, status)

__all__ = ["Campaign", "init", "log", "sample", "advise", "decide", "status", "report"]
