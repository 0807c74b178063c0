"""How ``sb3-trlsd reproduce`` runs a figure: the options every figure's ``reproduce(out, how)`` takes."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sb3_trlsd_lab.execution.backends import LOKY, Backend
from sb3_trlsd_lab.execution.protocols import AS_BUILT, Protocol, protocol_record

__all__ = ["Reproduction"]


@dataclass(frozen=True)
class Reproduction:
    """
    The options of a figure's reproduction.

    :param runs: runs per method (None: the figure's own default, the paper's size where it gives one)
    :param seed: seed of the first run; run r uses ``seed + r``
    :param workers: processes the runs are spread over
    :param cache: directory of finished runs, reused and completed (see ``run_jobs``); None: no cache
    :param backend: where the runs go (see ``run_jobs``)
    :param protocol: the choices the paper leaves open (``protocols``), recorded in the figure's JSON
    """

    runs: int | None = None
    seed: int = 0
    workers: int = 1
    cache: Path | None = None
    backend: Backend = LOKY
    protocol: Protocol = AS_BUILT

    def runs_or(self, default: int) -> int:
        """The runs per method: ``runs``, or the figure's ``default`` without it."""
        return self.runs or default

    def run_options(self) -> dict[str, Any]:
        """The keyword arguments of ``transfer_runs`` beyond its runs: cache, backend and protocol."""
        return {"cache": self.cache, "backend": self.backend, "protocol": self.protocol}

    def recorded(self) -> dict[str, Any]:
        """What a figure's JSON parameters say of the reproduction beyond its seed: the protocol."""
        return {"protocol": protocol_record(self.protocol)}
