"""Does the aim read off a marker photo hold? Random re-aims, photographed and measured.

For a simulated wall, each trial turns the lamp by a random (ΔH, ΔV) within
±``max_reaim_deg`` (:func:`lightsim.render.cutoff.apply_shift`), photographs it on the
default marker board with a random camera (roll, yaw, magnification, blur, noise;
:func:`lightsim.validation.synthetic_photo.photograph_simulation`, written as JPEG and
read back) and measures it with ``lightsim compare``'s own code
(:func:`lightsim.validation.compare.compare_images`). A trial is

* **covered** when the aim is read and its ≈ 95 % interval holds the true ΔV:
  \\|``cutoff.offset_deg`` − ΔV\\| ≤ ``cutoff.interval_deg``;
* **missed** when the aim is read and the interval does not hold ΔV;
* **refused** when the aim is not read, with the reason the report gives (too few
  markers in the frame, markers on one line, …).

The study passes when covered / (covered + missed) ≥ ``goal`` and at least half the
trials are read. Everything is seeded: the same settings give the same trials.

==================  =====  ========  =====================================================
parameter           unit   default   meaning
==================  =====  ========  =====================================================
reaims              –      50        trials per simulation
max_reaim_deg       deg    0.5       |ΔH|, |ΔV| of the re-aim at most (uniform)
max_rotate_deg      deg    3         camera roll at most (uniform ±)
max_tilt_deg        deg    6         camera yaw at most (uniform ±)
scale_spread        –      0.1       magnification × U(1 − s, 1 + s) of the marker scale
blur_px             px     0.5 … 1.5 optics blur σ (uniform)
noise               –      0.002 … 0.01  noise σ at full scale (uniform)
goal                –      0.9       coverage the study must reach
seed                –      1         random seed of the trials
==================  =====  ========  =====================================================
"""

from __future__ import annotations

import tempfile
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lightsim.validation.compare import CompareOptions, compare_images
from lightsim.validation.photo_io import Simulation, load_simulation, read_photo
from lightsim.validation.synthetic_photo import (
    CameraSettings,
    LowBeam,
    lowbeam_lux,
    marker_scale,
    photograph_simulation,
    wall_frame,
    write_result,
)


@dataclass(frozen=True)
class AimStudySettings:
    """The study's settings (module table)."""

    reaims: int = 50
    max_reaim_deg: float = 0.5
    max_rotate_deg: float = 3.0
    max_tilt_deg: float = 6.0
    scale_spread: float = 0.1
    blur_px: tuple[float, float] = (0.5, 1.5)
    noise: tuple[float, float] = (0.002, 0.01)
    goal: float = 0.9
    seed: int = 1


@dataclass
class AimTrial:
    """One re-aim: the truth (deg), the camera, and what the comparison read."""

    dh_deg: float
    dv_deg: float
    camera: dict[str, Any]
    markers_found: list[int]
    read: bool
    offset_deg: float | None
    interval_deg: float | None
    covered: bool | None
    refused: str | None


@dataclass
class AimStudyResult:
    """A study's trials and its figures."""

    source: str
    trials: list[AimTrial] = field(default_factory=list)
    goal: float = 0.9

    @property
    def read(self) -> int:
        """Trials whose aim was read."""
        return sum(t.read for t in self.trials)

    @property
    def covered(self) -> int:
        """Read trials whose interval holds the truth."""
        return sum(bool(t.covered) for t in self.trials)

    @property
    def refused(self) -> int:
        """Trials whose aim was not read."""
        return len(self.trials) - self.read

    @property
    def coverage(self) -> float | None:
        """Covered / read (None when none was read)."""
        return self.covered / self.read if self.read else None

    @property
    def passed(self) -> bool:
        """Coverage reaches the goal and at least half the trials were read."""
        return (self.coverage is not None and self.coverage >= self.goal
                and 2 * self.read >= len(self.trials))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready."""
        return {"source": self.source, "trials": [asdict(t) for t in self.trials],
                "read": self.read, "covered": self.covered, "refused": self.refused,
                "coverage": self.coverage, "goal": self.goal, "passed": self.passed}


def aim_study(sim: Simulation, settings: AimStudySettings | None = None,
              traffic: str = "right", workdir: str | Path | None = None,
              progress: Any = None) -> AimStudyResult:
    """Re-aim, photograph and measure ``settings.reaims`` times (module docstring).

    Parameters
    ----------
    sim : Simulation
        The simulated wall (:func:`lightsim.validation.photo_io.load_simulation`).
    settings : AimStudySettings, optional
        The study (module table).
    traffic : {"right", "left"}
        Traffic side of the cut-off.
    workdir : path-like, optional
        Where the photos go (default: a temporary folder, removed afterwards).
    progress : callable, optional
        Called with (trial index, AimTrial) after each trial.

    Returns
    -------
    AimStudyResult
    """
    st = settings or AimStudySettings()
    rng = np.random.default_rng(st.seed)
    base = marker_scale(sim.frame)
    result = AimStudyResult(sim.source, goal=st.goal)
    with tempfile.TemporaryDirectory(prefix="lightsim-aim-") as tmp:
        folder = Path(workdir) if workdir is not None else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for i in range(st.reaims):
            dh, dv = rng.uniform(-st.max_reaim_deg, st.max_reaim_deg, 2)
            scale = base * rng.uniform(1 - st.scale_spread, 1 + st.scale_spread)
            cam = CameraSettings(
                rotate_deg=float(rng.uniform(-st.max_rotate_deg, st.max_rotate_deg)),
                tilt_deg=float(rng.uniform(-st.max_tilt_deg, st.max_tilt_deg)),
                scale=float(scale),
                size=(round(sim.lux.shape[1] * base), round(sim.lux.shape[0] * base)),
                blur_px=float(rng.uniform(*st.blur_px)),
                noise=float(rng.uniform(*st.noise)), seed=i)
            path, _, _ = photograph_simulation(sim, folder / f"reaim-{i:03d}.jpg", cam,
                                               (float(dh), float(dv)), markers=True)
            comp = compare_images(read_photo(path), sim, CompareOptions(traffic=traffic))
            aim = comp.aim
            read = bool(aim is not None and aim.judgeable
                        and aim.cutoff.offset_deg is not None)
            off = aim.cutoff.offset_deg if read else None
            half = aim.cutoff.interval_deg if read else None
            trial = AimTrial(
                float(dh), float(dv),
                {k: v for k, v in asdict(cam).items() if v is not None},
                list((aim.markers or {}).get("found", [])) if aim is not None else [],
                read, off, half,
                None if not read or half is None else bool(abs(off - dv) <= half),
                None if read else (aim.refused or aim.statement if aim is not None
                                   else "no aim section"))
            result.trials.append(trial)
            if progress is not None:
                progress(i, trial)
    return result


def synthetic_simulation(folder: str | Path) -> Simulation:
    """The synthetic passing beam (:class:`~lightsim.validation.synthetic_photo.LowBeam`,
    400 × 160 px on the standard wall) as a result folder in ``folder``: what the study
    measures when no simulation is given."""
    frame = wall_frame((400, 160))
    return load_simulation(write_result(Path(folder) / "synthetic-lowbeam",
                                        lowbeam_lux(frame, LowBeam(texture=0.02)), frame))


def summary_line(result: AimStudyResult) -> str:
    """One line: coverage, reads and refusals, and whether the goal is reached."""
    cov = "–" if result.coverage is None else f"{result.coverage:.0%}"
    return (f"{Path(result.source).parent.name or result.source}: aim interval covers the "
            f"true re-aim in {result.covered} of {result.read} read ({cov}, goal "
            f"{result.goal:.0%}); {result.refused} of {len(result.trials)} refused — "
            + ("pass" if result.passed else "FAIL"))


def refusal_counts(result: AimStudyResult) -> dict[str, int]:
    """How often each reason for not reading the aim came up (marker ids left out)."""
    out: dict[str, int] = {}
    for t in result.trials:
        if t.refused:
            key = t.refused.split(" (ids")[0].split(";")[0]
            out[key] = out.get(key, 0) + 1
    return out
