"""Several emitters as one: photons are shared out by flux, stratified.

Dimension u[:, 2] first chooses between the mesh emitter and the other sources by flux,
then among the other sources by their fluxes; its remainder is rescaled to [0, 1) and
reused (the mesh emitter picks its triangle with it), so the choice stays stratified
under Halton points.

===============  =====  ===========================================================
attribute        unit   meaning
===============  =====  ===========================================================
``mesh``         –      :class:`~lightsim.emitters.mesh.MeshEmitter` or None
``sources``      –      other emitters (:class:`~lightsim.emitters.base.Emitter`)
``flux_lm``      lm     total flux Φ of all emitters
``mesh_share``   –      fraction of Φ the mesh emitter carries
===============  =====  ===========================================================
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from lightsim.emitters.base import Emitter
from lightsim.emitters.mesh import MeshEmitter


@dataclass
class EmitterMix:
    """All emitters of a scene (see the module docstring)."""

    mesh: MeshEmitter | None
    flux_lm: float
    mesh_share: float = 1.0
    sources: list[Emitter] = field(default_factory=list)

    @classmethod
    def from_scene(cls, scene) -> EmitterMix:
        """The scene's emitter parts: a part with a core ``emitter`` object (a point or
        ray-file source) is sampled by it, the others are emissive triangles."""
        meshes, sources = [], []
        for p in scene.emitters:
            if p.emitter is not None:
                sources.append(p.emitter)
            else:
                meshes.append((p.triangles, p.emission, p.flux_lm))
        total = float(scene.total_flux)
        mesh = MeshEmitter.build(meshes)
        share = mesh.flux_lm / total if mesh is not None else 0.0
        return cls(mesh, total, share, sources)

    def sample(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Origins (n, 3) m and unit directions (n, 3) for sample points u (n, 5)."""
        u = np.ascontiguousarray(u, dtype=np.float64)
        if not self.sources:
            return self.mesh.sample(u)
        origin = np.empty((len(u), 3))
        direction = np.empty((len(u), 3))
        share = self.mesh_share
        mesh = u[:, 2] < share
        if np.any(mesh):
            um = u[mesh].copy()
            um[:, 2] = np.minimum(um[:, 2] / share, np.nextafter(1.0, 0.0))
            origin[mesh], direction[mesh] = self.mesh.sample(um)
        fluxes = np.array([s.flux_lm for s in self.sources])
        edges = share + (1.0 - share) * np.concatenate([[0.0], np.cumsum(fluxes) / fluxes.sum()])
        last = len(self.sources) - 1
        for k, src in enumerate(self.sources):
            sel = (~mesh) & (u[:, 2] >= edges[k]) & ((u[:, 2] < edges[k + 1]) | (k == last))
            if np.any(sel):
                origin[sel], direction[sel] = src.sample(u[sel])
        return origin, direction

    def describe(self) -> str:
        parts = ([self.mesh.describe()] if self.mesh is not None else []) + \
            [s.describe() for s in self.sources]
        return "; ".join(parts)
