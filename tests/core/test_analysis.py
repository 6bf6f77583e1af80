"""The run calls its analyses through lightsim.analysis.Analysis (it imports none)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from lightsim.analysis import Analysis, AnalysisReport, FinishedRun
from lightsim.errors import InputError, LightsimError
from lightsim.luminaires.analyses import for_options
from lightsim.luminaires.photometric.analysis import FarfieldAnalysis
from lightsim.luminaires.regulations.check import RegulationAnalysis
from lightsim.simulate import SimulateOptions, run_simulation

LAMP = Path(__file__).resolve().parents[2] / "luminaires" / "examples" / "headlight.glb"


@dataclass
class PeakAnalysis:
    """A user's own analysis: asks for one probe point, reports the brightest pixel."""

    name: str = "peak"
    calls: list[str] = field(default_factory=list)

    def prepare(self, config: Any, scene: Any) -> Any:
        self.calls.append("prepare")
        return config.with_(extra_probes=((0.0, 0.0),))

    def report(self, run: FinishedRun, out: Path) -> AnalysisReport:
        self.calls.append("report")
        assert run.session.config.extra_probes == ((0.0, 0.0),)
        at_hv = run.session.probe(np.zeros((1, 2)))  # every set's estimate at H-V
        (out / "peak.txt").write_text(f"{run.lux.max():.6g}\n")
        return AnalysisReport({"max_lx": float(run.lux.max()),
                               "hv_sets": int(at_hv.values.shape[0]),
                               "cutoff_found": bool(run.cutoff.get("found"))},
                              files=[out / "peak.txt"])


def test_the_run_calls_prepare_then_report(tmp_path):
    peak = PeakAnalysis()
    assert isinstance(peak, Analysis)
    opts = SimulateOptions(str(LAMP), out_dir=str(tmp_path / "run"), photons=20_000,
                           resolution=(80, 32))
    res = run_simulation(opts, analyses=[peak])
    assert peak.calls == ["prepare", "report"]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert summary["peak"]["max_lx"] == pytest.approx(float(res.lux.max()), rel=1e-6)
    assert summary["peak"]["hv_sets"] == 16
    assert "peak.txt" in summary["outputs"]  # written into the output set
    assert (tmp_path / "run" / "peak.txt").is_file()


def test_options_compose_their_analyses():
    base = dict(scene_path=str(LAMP))
    assert for_options(SimulateOptions(**base)) == []
    both = for_options(SimulateOptions(**base, regulation="r112-b-passing", aim=True,
                                       ies="a.ies", ldt="a.ldt"))
    assert [type(a) for a in both] == [RegulationAnalysis, FarfieldAnalysis]
    assert both[0].aim and both[1].ies == "a.ies"
    with pytest.raises(InputError, match="unknown rule set"):
        for_options(SimulateOptions(**base, regulation="no-such-rules"))
    with pytest.raises(InputError, match="--ies-type"):
        for_options(SimulateOptions(**base, ies_type="Z"))


def test_asking_for_a_regulation_without_its_analysis_is_an_error(tmp_path):
    opts = SimulateOptions(str(LAMP), out_dir=str(tmp_path / "x"), photons=1000,
                           regulation="r112-b-passing")
    with pytest.raises(LightsimError, match="for_options"):
        run_simulation(opts)
    assert not (tmp_path / "x").exists()
