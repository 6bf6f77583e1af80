"""The one interface the server drives its clients through (paper section 4).

Two implementations: :class:`~lightsim.engine.local.LocalBackend` (clients in this
process) and :class:`~lightsim.engine.ray_backend.RayBackend` (clients as Ray actors on
this machine or a cluster). Every call reaches every client; answers come back in client
order and per set in set order, so the server's result does not depend on where a set
lives.
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from lightsim.engine.results import ClientFrame, RenderRequest, ShootResult


@runtime_checkable
class Backend(Protocol):
    """What the server needs from its clients."""

    def shoot(self, total: int | None = None) -> list[ShootResult]:
        """Every client shoots one frame of photons into its sets and inserts them
        (``total``: photons over all sets of a partial frame)."""

    def render(self, request: RenderRequest) -> list[ClientFrame]:
        """Every set's estimates asked for by ``request`` (lx)."""

    def probe(self, points_hv: np.ndarray) -> dict[int, np.ndarray]:
        """{set: (P, C) lx} at wall points (h, v in m), in set order."""

    def apply(self, changes: list[tuple]) -> None:
        """Interaction changes (:func:`~lightsim.engine.client.apply_changes`); the
        photons are discarded."""

    def stats(self) -> dict[int, dict[str, Any]]:
        """Per-set counters and bookkeeping (unnormalised ledger), in set order."""

    def per_source(self) -> list[tuple[np.ndarray, np.ndarray, dict[int, np.ndarray]] | None]:
        """Each client's ΣΦ, ΣΦ² per emitter group and pixel and its sets' all-group pixel sums
        (``--per-source``), or None."""

    def apertures(self) -> dict[int, np.ndarray | None]:
        """Per-set detector-aperture counts, in set order."""

    def paths(self) -> dict[int, Any]:
        """Per-set aperture flux per path signature (``--provenance``), in set order."""

    def counters(self) -> dict[int, int]:
        """Frames shot per set (with the seed, all a replay needs)."""

    def replay(self, counters: dict[int, int], partial: dict[int, int] | None = None
               ) -> None:
        """Rebuild every set by re-shooting its frames (see :meth:`Session.checkpoint`)."""

    def close(self) -> None:
        """Release the clients (embree scenes, actors, a Ray runtime this started)."""
