"""simulate → IES (Type A) and EULUMDAT → simulate the file: the run's table comes back.

A file is compared with the run it was written from the way ``lightsim simulate`` checks a
lamp: the rule set's rows (every aperture value with its 95 % interval), Imax and the
verdicts. A row whose run value rests on fewer than ``MIN_PHOTONS`` counted photons (a few
weighted photons in a dark test point, or a sum of such points) is left out: a file of
the run's bin size spreads those photons over its bins, and the run's own value there
says little.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from lightsim.luminaires.analyses import for_options
from lightsim.luminaires.photometric import read_photometric
from lightsim.luminaires.photometric.reproduce import MIN_PHOTONS
from lightsim.simulate import SimulateOptions, run_simulation

EXAMPLES = Path(__file__).resolve().parents[3] / "luminaires" / "examples"
RULES = "r112-b-passing"
DECIDED = {"pass", "fail"}


def simulate(scene: Path, out: Path, photons: int, resolution: tuple[int, int],
             **files: object) -> dict:
    opts = SimulateOptions(str(scene), photons=photons, resolution=resolution,
                           regulation=RULES, out_dir=str(out), **files)
    run_simulation(opts, analyses=for_options(opts))
    return json.loads((out / "summary.json").read_text())


def counted(out: Path) -> dict[str, float]:
    """Photons (effective) each rule-set point counted, from the run's probes.npz."""
    data = np.load(out / "probes.npz")
    return dict(zip(data["labels"].tolist(), data["count_stats"][0].tolist(), strict=True))


def mismatches(direct: dict, again: dict, photons: dict[str, float], imax: bool) -> list:
    """Rows of ``again`` outside the two runs' combined interval (or 2 %), Imax outside
    2 % (with ``imax``), and verdicts that differ where both runs decide."""
    bad = []
    mine = {r["name"]: r for r in again["regulation"]["results"]}
    for r in direct["regulation"]["results"]:
        name, v = r["name"], r["value_cd"]
        q = mine[name]
        w = q["value_cd"]
        if name == "Imax":
            if imax and abs(w - v) > 0.02 * v:
                bad.append((name, v, w))
            continue
        members = r.get("points") or [name]  # a sum row counts its points' photons
        if sum(photons.get(p, math.inf) for p in members) < MIN_PHOTONS:
            continue
        (lo, hi), (lo2, hi2) = r["interval_cd"], q["interval_cd"]
        half = math.hypot(hi - v if w > v else v - lo, w - lo2 if w > v else hi2 - w)
        if abs(w - v) > max(half, 0.02 * abs(v)):
            bad.append((name, v, w, half))
        if r["verdict"] in DECIDED and q["verdict"] in DECIDED and r["verdict"] != q["verdict"]:
            bad.append((name, r["verdict"], q["verdict"]))
    return bad


def check_files(direct: dict, out: Path) -> None:
    """The files hold the run's flux, and their own check finds them reproducing it."""
    ff = direct["farfield"]
    assert "does not reproduce" not in ff.get("warning", "")
    ies, ldt = read_photometric(out / "lamp.ies"), read_photometric(out / "lamp.ldt")
    assert ies.photometric_type == "A" and ldt.shape[0] <= 721 and ldt.shape[1] <= 361
    assert ies.total_flux() == pytest.approx(ff["type_a_flux_lm"], rel=1e-4)
    assert ldt.total_flux() == pytest.approx(ff["total_flux_lm"], rel=1e-4)
    e = direct["energy_lm"]
    assert ff["total_flux_lm"] == pytest.approx(e["wall"] + e["escaped"], rel=0.02)
    for check in ff["checks"].values():
        assert check["outside"] == 0
        assert check["peak_cd"] == pytest.approx(check["run_imax_cd"], rel=0.02)
        assert check["run_imax_cd"] == pytest.approx(
            {r["name"]: r for r in direct["regulation"]["results"]}["Imax"]["value_cd"],
            rel=1e-9)


def round_trip(tmp_path: Path, lamp: str, photons: int, file_photons: int,
               resolution: tuple[int, int], farfield_photons: int, imax: bool) -> None:
    out = tmp_path / "direct"
    direct = simulate(EXAMPLES / lamp, out, photons, resolution,
                      ies=str(out / "lamp.ies"), ldt=str(out / "lamp.ldt"),
                      farfield_photons=farfield_photons)
    check_files(direct, out)
    photons_at = counted(out)
    for name in ("lamp.ies", "lamp.ldt"):
        again = simulate(out / name, tmp_path / name.replace(".", "_"), file_photons,
                         resolution)
        assert again["energy_lm"]["wall"] == pytest.approx(direct["energy_lm"]["wall"],
                                                           rel=0.02)
        assert mismatches(direct, again, photons_at, imax) == [], name


def test_headlight_round_trip_quick(tmp_path):
    """A small run: every well-counted row and verdict comes back; Imax as the file's own
    check finds it (a file run this short cannot measure it to 2 %)."""
    round_trip(tmp_path, "headlight.glb", 300_000, 2_000_000, (160, 64), 200_000,
               imax=False)


@pytest.mark.slow
@pytest.mark.parametrize(("lamp", "photons"), [("lowbeam.glb", 4_000_000),
                                               ("headlight.glb", 1_000_000)])
def test_round_trip_of_the_shipped_lamps(tmp_path, lamp, photons):
    """Both shipped lamps at the README's resolution; the files simulated with 8 M photons
    give Imax within 2 %."""
    round_trip(tmp_path, lamp, photons, 8_000_000, (320, 128), 1_000_000, imax=True)
