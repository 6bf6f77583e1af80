"""``lightsim validate`` and ``lightsim converge``: parse, run the studies, print.

The physics lives in :mod:`lightsim.validation.analytic`, :mod:`lightsim.validation.stability`
and :mod:`lightsim.validation.converge`; this module only handles options and output.
``validate`` exits with code 1 when a check fails (2 for bad input, as every command).

``lightsim validate``
=====================  =====  ==========  ================================================
option                 unit   default     meaning
=====================  =====  ==========  ================================================
``--full``             –      off         10× photons, finer meshes, all estimators
``--stability``        –      off         the stability suite instead of the analytic one
``--all``              –      off         both suites
``--case``             –      all         only the named case(s)
``--estimator``        –      bin, knn    density estimators on the image cases
``--photons``          –      400 000     photons per case
``--seed``             –      1
``--json``             –      none        every check with σ, q and allowance
``--coverage``         –      off         the regulation coverage study instead:
                                          synthetic sharp cut-off lamps, 95 % intervals
                                          and verdicts against exact aperture means
``--lamps``            –      40          lamps in the coverage study (0: only ``--lamp``)
``--counts``           –      --photons   photon counts of the coverage study (250k,1M)
``--lamp``             –      none        a lamp file studied against a long reference
                                          run (repeatable; the shipped lamps:
                                          luminaires/examples/lowbeam.glb, headlight.glb)
``--seeds``            –      8           runs per ``--lamp`` and photon count
``--reference-photons`` –     48M         photons of a ``--lamp``'s reference run
``--reference-dir``    –      temp        folder keeping the reference runs (default
                                          ``lightsim-coverage`` in the temp directory)
``--aperture``         deg    0.15        detector aperture of the coverage study
``--spt-points``       –      off         SPT aimed at the test points (coverage study)
``--guide``            –      off         coverage study with importance-driven emission
                                          (``points``: aimed at the test points and zones)
``--aim-study``        –      off         the re-aim study of the photo comparison
                                          instead (:mod:`lightsim.validation.photo_aim_
                                          study`): does the aim interval cover the truth?
``--aim-sim``          –      synthetic   a simulation the aim study photographs
                                          (repeatable)
``--reaims``           –      50          re-aims per simulation in the aim study
=====================  =====  ==========  ================================================

``lightsim converge SCENE``
======================  =====  ===============  ============================================
option                  unit   default          meaning
======================  =====  ===============  ============================================
``--budgets``           s      0.25,0.5,…,8     time budgets (``--full``: up to 64)
``--photons``           –      none             photon budgets instead (e.g. 250k,1M,4M;
                                                reproducible whatever the machine's load)
``--estimator``         –      all              the lines of
                                                :data:`lightsim.validation.converge.SPECS`
                                                (``--help`` lists their labels)
``--out``               –      converge-out     folder for converge.csv/.json/.png
                                                (``--stop-study``: stop-study.csv/.json/.png)
``--stop-study``        –      off              where ``--target-error`` stops instead
                                                (:mod:`lightsim.validation.stop_study`):
                                                every analytic case, or SCENE's, many seeds
``--targets``           –      0.02             target errors of the stop study (fractions)
``--seeds``             –      20               runs per case and target (stop study)
``--frame-photons``     –      50 000           photons per frame (all sets)
``--resolution``        px     160x64 (files)   wall pixels
``--reference-factor``  –      20               reference length / longest budget
``--seed``              –      1
======================  =====  ===============  ============================================

``--seed`` (both commands) and ``--frame-photons`` are the run options' own records
(:mod:`lightsim.options`): the same help, unit and range as ``simulate``'s.
"""

from __future__ import annotations

import math
import tempfile
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import click

from lightsim.engine.config import RunConfig
from lightsim.errors import InputError
from lightsim.io.summary import write_json
from lightsim.options import click_option, lookup
from lightsim.validation import analytic
from lightsim.validation import converge as cv
from lightsim.validation import stability as stab
from lightsim.validation import stop_study as stops
from lightsim.validation.analytic import TABLE_COLUMNS, SuiteSettings, table_rows
from lightsim.validation.converge import FULL_BUDGETS, QUICK_BUDGETS
from lightsim.validation.coverage import (
    COVERAGE_BAND,
    DEFAULT_CACHE,
    REFERENCE_PHOTONS,
    RULE_KINDS,
    VerdictCount,
    coverage_study,
    shipped_study,
)
from lightsim.validation.photo_aim_study import (
    AimStudySettings,
    AimTrial,
    aim_study,
    refusal_counts,
    summary_line,
    synthetic_simulation,
)
from lightsim.validation.photo_io import load_simulation


def _print_table(title: str, header: Sequence[str], rows: Sequence[Sequence[str]]) -> None:
    """A plain fixed-width table (readable in logs and narrow terminals alike)."""
    widths = [max(len(h), *(len(r[i]) for r in rows)) if rows else len(h)
              for i, h in enumerate(header)]
    click.echo(title)
    line = "  ".join(h.ljust(w) for h, w in zip(header, widths))
    click.echo(line)
    click.echo("  ".join("-" * w for w in widths))
    for r in rows:
        click.echo("  ".join(c.ljust(w) if i < 2 else c.rjust(w) if i < len(r) - 1 else c
                             for i, (c, w) in enumerate(zip(r, widths))))


@click.command()
@click.option("--full", is_flag=True,
              help="The long study: 10× the photons, finer meshes, every estimator on "
                   "every case (minutes).")
@click.option("--stability", is_flag=True,
              help="Run the stability suite (stiff and extreme cases) instead.")
@click.option("--all", "run_all", is_flag=True, help="Run the analytic and stability suites.")
@click.option("--case", "cases", multiple=True,
              help="Only this case (repeatable); see the table for names.")
@click.option("--estimator", "estimators", multiple=True,
              type=click.Choice(["bin", "knn", "radius"]),
              help="Density estimators for the image cases (default: bin and knn).")
@click.option("--photons", type=int, help="Photons per case (default 400 000; --full 4 M).")
@click_option(lookup(RunConfig, "seed"))
@click.option("--json", "json_path", type=click.Path(dir_okay=False),
              help="Write every check (with its σ and allowance) as JSON.")
@click.option("--coverage", is_flag=True,
              help="Coverage study of the regulation points' 95 % intervals on synthetic "
                   "sharp cut-off lamps with exact answers.")
@click.option("--lamps", type=int, default=40, show_default=True,
              help="Synthetic lamps in the coverage study (0: only the --lamp files).")
@click.option("--counts", help="Photon counts of the coverage study, comma-separated "
                               "(250k,1M; default --photons, or 1M).")
@click.option("--lamp", "lamp_files", multiple=True, type=click.Path(dir_okay=False),
              help="A lamp file (e.g. luminaires/examples/lowbeam.glb) whose verdicts the "
                   "coverage study judges against a long reference run (repeatable).")
@click.option("--seeds", type=int, default=8, show_default=True,
              help="Runs per --lamp and photon count.")
@click.option("--reference-photons", default="48M", show_default=True,
              help="Photons of a --lamp's reference run (made once, then kept).")
@click.option("--reference-dir", type=click.Path(file_okay=False),
              help="Folder keeping the reference runs [default: lightsim-coverage in the "
                   "temporary directory].")
@click.option("--aperture", type=float, default=0.15, show_default=True,
              help="Detector aperture (deg) of the coverage study.")
@click.option("--spt-points", is_flag=True, help="Coverage study with SPT aimed at the points.")
@click.option("--guide", type=click.Choice(["off", "points"]), default="off", show_default=True,
              help="Coverage study with importance-driven emission aimed at the test points "
                   "and zones (as simulate --guide points).")
@click.option("--aim-study", is_flag=True,
              help="Re-aim study of the photo comparison: random re-aims (±0.5°) "
                   "photographed on the marker board by random cameras; does the aim "
                   "interval cover the truth (goal 90 %)?")
@click.option("--aim-sim", "aim_sims", multiple=True, type=click.Path(exists=True),
              help="A simulation (result folder or wall_lux.exr) the aim study photographs "
                   "(repeatable) [default: a synthetic low beam].")
@click.option("--reaims", type=click.IntRange(1, 10_000), default=50, show_default=True,
              help="Re-aims per simulation in the aim study.")
@click.option("--quiet", "-q", is_flag=True, help="Only the table.")
def validate(full: bool, stability: bool, run_all: bool, cases: tuple[str, ...],
             estimators: tuple[str, ...], photons: int | None, seed: int,
             json_path: str | None, coverage: bool, quiet: bool, aim_study: bool,
             aim_sims: tuple[str, ...], reaims: int, **study: object) -> None:
    """Check the simulator against exact answers (and stiff, extreme cases).

    Prints case, quantity, expected, measured, error, uncertainty and pass for every
    check; exits with code 1 if any check fails.
    """
    if aim_study:
        _aim_study(aim_sims, AimStudySettings(reaims=reaims, seed=seed), json_path, quiet)
        return
    if coverage:  # ``study``: the coverage study's options (CoverageSettings)
        _coverage(CoverageSettings.from_options(photons, seed, **study), json_path, quiet)
        return
    if photons is not None and photons < 1000:
        raise InputError(f"--photons must be at least 1000, got {photons}")
    do_analytic = run_all or not stability
    do_stability = run_all or stability
    t0 = time.perf_counter()
    checks: list[analytic.Check] = []
    doc: dict = {}

    def progress(name: str) -> None:
        if not quiet:
            click.echo(f"  running {name} …", err=True)

    if do_analytic:
        kw: dict = {"seed": seed}
        if estimators:
            kw["estimators"] = tuple(estimators)
        if photons is not None:
            kw["photons"] = photons
        settings = SuiteSettings.full_run(**kw) if full else SuiteSettings.fast(**kw)
        names = [c for c in cases if c in analytic.CASE_NAMES] if cases else None
        if cases and not names and not do_stability:
            raise InputError(f"unknown case(s) {', '.join(cases)} (analytic cases: "
                             f"{', '.join(analytic.CASE_NAMES)})")
        if names or not cases:
            res = analytic.run_suite(settings, names, progress)
            checks.extend(res.checks)
            doc["analytic"] = res.to_dict()
            for s in res.skipped:
                click.echo(f"lightsim: note: skipped {s}", err=True)
    if do_stability:
        ssettings = (stab.StabilitySettings.full_run(seed=seed) if full
                     else stab.StabilitySettings(seed=seed,
                                                 **({"photons": photons} if photons else {})))
        names = [c for c in cases if c in stab.CASES] if cases else None
        if cases and not names and not do_analytic:
            raise InputError(f"unknown case(s) {', '.join(cases)} (stability cases: "
                             f"{', '.join(stab.CASES)})")
        if names or not cases:
            sc = stab.run_stability(ssettings, names, progress)
            checks.extend(sc)
            doc["stability"] = {"settings": ssettings.__dict__,
                                "checks": [c.to_dict() for c in sc]}
    seconds = time.perf_counter() - t0
    failed = [c for c in checks if not c.passed]
    title = ("lightsim validate" + (" --full" if full else "")
             + (" (stability)" if do_stability and not do_analytic else "")
             + f": {len(checks) - len(failed)}/{len(checks)} checks passed in {seconds:.1f} s")
    _print_table(title, TABLE_COLUMNS, table_rows(checks))
    if failed:
        click.echo("failed:")
        for c in failed:
            click.echo(f"  {c.case}: {c.quantity}: {c.note}")
    if json_path:
        doc.update({"passed": not failed, "seconds": seconds, "n_checks": len(checks),
                    "n_failed": len(failed)})
        write_json(json_path, doc)
        if not quiet:
            click.echo(f"wrote {json_path}")
    if failed:
        raise SystemExit(1)


def _budgets(text: str | None, full: bool) -> list[float]:
    if text is None:
        return list(FULL_BUDGETS if full else QUICK_BUDGETS)
    try:
        vals = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise InputError(f"--budgets must be seconds separated by commas, got '{text}'") \
            from None
    if not vals or not all(v > 0 and math.isfinite(v) for v in vals):
        raise InputError(f"--budgets must be positive seconds, got '{text}'")
    return vals


def _photon_budgets(text: str) -> list[float]:
    vals = []
    for part in (x.strip().lower() for x in text.split(",") if x.strip()):
        scale = {"k": 1e3, "m": 1e6, "g": 1e9}.get(part[-1:], 1.0)
        try:
            v = float(part[:-1] if scale != 1.0 else part) * scale
        except ValueError:
            raise InputError(f"--photons must be photon counts separated by commas "
                             f"(250k, 1M, 4e6), got '{text}'") from None
        if not (math.isfinite(v) and v >= 1):
            raise InputError(f"--photons must be positive photon counts, got '{text}'")
        vals.append(float(round(v)))
    if not vals:
        raise InputError(f"--photons must list photon counts, got '{text}'")
    return vals


def _print_steps(result) -> None:
    """Error against photons and seconds at every step, with estimated / actual."""
    def pct(x):
        return "–" if x is None else f"{x:.2%}"

    def num(x, f="{:+.2f}"):
        return "–" if x is None else f.format(x)

    rows = [[st.estimator, f"{st.photons:,}", f"{st.seconds:.1f}", pct(st.actual),
             pct(st.estimated), pct(st.noise), pct(st.blur), num(st.ratio, "{:.2f}"),
             num(st.slope_photons), num(st.slope_seconds)] for st in result.steps()]
    _print_table("error against photons and seconds (slopes: d log error / d log photons, "
                 "seconds since the previous step; −0.50 = 1/√N)",
                 ("estimator", "photons", "s", "actual", "estimated", "noise", "blur",
                  "est/actual", "slope N", "slope s"), rows)


def _resolution(text: str | None) -> tuple[int, int] | None:
    if text is None:
        return None
    parts = text.lower().replace("×", "x").split("x")
    try:
        w, h = (int(p) for p in parts)
    except ValueError:
        raise InputError(f"--resolution must look like WxH, got '{text}'") from None
    if w < 1 or h < 1:
        raise InputError(f"--resolution must be positive, got '{text}'")
    return w, h


#: the estimator labels ``--estimator`` accepts: the study's own lines (one source)
ESTIMATOR_LABELS = tuple(s.label.replace(" ", "") for s in cv.SPECS)


@click.command()
@click.argument("scene", required=False)
@click.option("--budgets", help="Time budgets in s, comma-separated (default 0.25 … 8; "
                                "--full: 0.25 … 64).")
@click.option("--full", is_flag=True, help="Budgets up to a minute.")
@click.option("--photons", "photon_budgets",
              help="Photon budgets instead of seconds, comma-separated (250k, 1M, 4e6).")
@click.option("--estimator", "estimators", multiple=True,
              help=f"{', '.join(ESTIMATOR_LABELS)} (repeatable; default all).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="converge-out",
              show_default=True,
              help="Folder for converge.csv/.json/.png (--stop-study: stop-study.*).")
@click.option("--stop-study", is_flag=True,
              help="Where --target-error stops instead: every analytic case (or SCENE's) "
                   "stopped at each target over many seeds, scored against the exact "
                   "answer.")
@click.option("--targets", default="0.02", show_default=True,
              help="Target errors of the stop study, fractions, comma-separated.")
@click.option("--seeds", type=int, default=20, show_default=True,
              help="Runs per case and target of the stop study.")
@click_option(lookup(RunConfig, "frame_photons"), default=50_000)
@click.option("--resolution", help="Wall pixels WxH (scene files: default 160x64).")
@click.option("--reference-factor", type=float, default=20.0, show_default=True,
              help="Reference run length / longest budget (scene files).")
@click_option(lookup(RunConfig, "seed"))
@click.option("--quiet", "-q", is_flag=True)
def converge(scene: str | None, budgets: str | None, full: bool, photon_budgets: str | None,
             estimators: tuple[str, ...], out_dir: str, stop_study: bool, targets: str,
             seeds: int, frame_photons: int, resolution: str | None,
             reference_factor: float, seed: int, quiet: bool) -> None:
    """Error against run time for every estimator on SCENE.

    SCENE is analytic:NAME (isotropic, paraboloid, slab, slab-absorbing, lambertian:
    compared with the exact answer) or a scene file (compared with a bin reference run
    --reference-factor times longer than the longest budget).

    With --stop-study: where --target-error stops, on every analytic case (or SCENE,
    analytic:NAME), --seeds runs per target, against the exact answer: photons at the
    stop, true error / target, and the runs above the target against what the stop's
    confidence allows.
    """
    if stop_study:
        _stop_study(scene, targets, seeds, seed, out_dir, quiet)
        return
    if scene is None:
        raise InputError("converge needs a SCENE (analytic:NAME or a scene file), or "
                         "--stop-study")
    if frame_photons < 16:
        raise InputError(f"--frame-photons must be at least 16, got {frame_photons}")
    if not (reference_factor >= 1 and math.isfinite(reference_factor)):
        raise InputError(f"--reference-factor must be ≥ 1, got {reference_factor}")
    by_photons = photon_budgets is not None
    bl = _photon_budgets(photon_budgets) if by_photons else _budgets(budgets, full)
    for e in estimators:
        cv.spec_by_label(e)

    def progress(line: str) -> None:
        if not quiet:
            click.echo(f"  {line}", err=True)

    result = cv.run_converge(scene, bl, list(estimators) or None, seed=seed,
                             frame_photons=frame_photons, reference_factor=reference_factor,
                             resolution=_resolution(resolution), progress=progress,
                             by_photons=by_photons)
    for s in result.skipped:
        click.echo(f"lightsim: note: skipped {s}", err=True)
    paths = cv.write_outputs(result, out_dir)
    times = result.times("rel_rmse")
    honesty = result.honesty()
    metric = ("noise-corrected relative RMSE vs reference" if result.mode == "reference"
              else "relative RMSE vs exact")
    rows = []
    for label, t in times.items():
        pts = [p for p in result.points if p.estimator == label]
        last = pts[-1]
        key = "rel_rmse_corrected" if result.mode == "reference" else "rel_rmse"

        def fmt(d: dict) -> str:
            if d["seconds"] is None:
                return "not reached"
            return (f"≤ {d['seconds']:.2f} s" if d["how"] == "at first point"
                    else f"{d['seconds']:.2f} s")

        h = honesty.get(label)
        rows.append([label, fmt(t["5%"]), fmt(t["2%"]), fmt(t["1%"]),
                     f"{last.metrics[key]:.2%} @ {last.seconds:.1f} s",
                     f"{last.metrics['rel_l1']:.2%}",
                     "–" if h is None else f"{h:.2f}"])
    _print_table(f"lightsim converge {result.target}: time to reach the error ({metric}, "
                 f"lit region {result.lit_pixels} px)",
                 ("estimator", "5 %", "2 %", "1 %", "last error", "last rel L1",
                  "estimated/actual"), rows)
    _print_steps(result)
    if result.mode == "reference":
        ref = result.reference
        click.echo(f"reference: bin, {ref['photons']:,} photons in {ref['seconds']:.0f} s, "
                   f"its own estimated error {ref['rel_error']:.2%}"
                   if ref.get("rel_error") is not None else "reference: bin")
    click.echo(f"wrote {paths['csv']}, {paths['json']}, {paths['png']}")


def _targets(text: str) -> list[float]:
    """'0.02,0.05' → fractions in (0, 1); one clear error otherwise."""
    try:
        out = [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise InputError(f"--targets must be fractions like 0.02,0.05, got '{text}'") from None
    if not out or not all(0 < t < 1 and math.isfinite(t) for t in out):
        raise InputError(f"--targets must lie in (0, 1), got '{text}'")
    return out


def _stop_study(scene: str | None, targets: str, seeds: int, first_seed: int, out_dir: str,
                quiet: bool) -> None:
    """``converge --stop-study``: run, print the per-case table, write the outputs."""
    cases = None
    if scene is not None:
        name = scene.removeprefix("analytic:")
        if name not in stops.CASES:
            raise InputError(f"--stop-study runs on the analytic cases ({', '.join(stops.CASES)}),"
                             f" got '{scene}'")
        cases = [name]
    tl = _targets(targets)
    if seeds < 1:
        raise InputError(f"--seeds must be at least 1, got {seeds}")

    def progress(line: str) -> None:
        if not quiet:
            click.echo(f"  {line}", err=True)

    study = stops.run_study(cases, tl, seeds, first_seed, progress=progress)
    paths = stops.write_outputs(study, out_dir)
    summary = study.summary
    _print_table(f"lightsim converge --stop-study: where --target-error stops (true error "
                 f"against the exact answer over the figure's region; confidence "
                 f"{1 - stops.STOP_ALPHA:.0%})", stops.HEADER, [s.row() for s in summary])
    honest = sum(s.honest for s in summary)
    band = sum(stops.BAND[0] <= s.median_ratio <= stops.BAND[1] for s in summary)
    click.echo(f"{honest}/{len(summary)} cases stop above the target no more often than the "
               f"confidence allows; {band}/{len(summary)} have their median true error in "
               f"{stops.BAND[0]}–{stops.BAND[1]} × the target")
    click.echo(f"wrote {paths['csv']}, {paths['json']}, {paths['png']}")


@dataclass(frozen=True)
class CoverageSettings:
    """What ``validate --coverage`` studies (see the option table)."""

    lamps: int
    counts: list[float]
    lamp_files: tuple[str, ...] = ()
    seeds: int = 8
    reference_photons: float = REFERENCE_PHOTONS
    reference_dir: str | None = None
    aperture: float = 0.15
    spt: bool = False
    seed: int = 1
    guide: bool = False

    @classmethod
    def from_options(cls, photons: int | None, seed: int, *, lamps: int, counts: str | None,
                     lamp_files: tuple[str, ...], seeds: int, reference_photons: str,
                     reference_dir: str | None, aperture: float,
                     spt_points: bool, guide: str = "off") -> CoverageSettings:
        """The settings from ``validate``'s options (photon counts parsed)."""
        return cls(lamps=lamps,
                   counts=_photon_budgets(counts) if counts else [photons or 1_000_000],
                   lamp_files=lamp_files, seeds=seeds,
                   reference_photons=_photon_budgets(reference_photons)[0],
                   reference_dir=reference_dir, aperture=aperture, spt=spt_points,
                   seed=seed, guide=guide == "points")


def _verdict_rows(rules: dict[str, VerdictCount]) -> list[list[str]]:
    """One row per kind of rule: coverage, verdicts and the wrong ones."""
    rows = []
    for kind in RULE_KINDS:
        c = rules.get(kind)
        if c is None or not c.evaluations:
            continue
        cov = f"{c.covered / c.with_truth:.1%}" if c.with_truth else "–"
        rows.append([kind, str(c.evaluations), cov, str(c.decisive), str(c.uncertain),
                     str(c.wrong), f"{c.nominal():.1f}", str(c.allowed())])
    return rows


VERDICT_HEADER = ("rule kind", "evaluations", "coverage", "pass/fail", "uncertain",
                  "wrong", "nominal", "allowed")


def _aim_study(sims: Sequence[str], st: AimStudySettings, json_path: str | None,
               quiet: bool) -> None:
    """``validate --aim-study``: per simulation, the re-aim study's coverage and refusals;
    exit code 1 when a study misses its goal."""
    results = []
    with tempfile.TemporaryDirectory(prefix="lightsim-aim-study-") as tmp:
        for path in sims or [None]:
            sim = load_simulation(path) if path is not None else synthetic_simulation(tmp)

            def progress(i: int, t: AimTrial) -> None:
                if not quiet:
                    got = (f"{t.offset_deg:+.3f} ± {t.interval_deg:.3f}°"
                           + (" covers" if t.covered else " MISSES") if t.read
                           else f"refused: {t.refused}")
                    click.echo(f"  {i + 1:>3}/{st.reaims} re-aim ΔH {t.dh_deg:+.2f}°, ΔV "
                               f"{t.dv_deg:+.2f}°: {len(t.markers_found)} markers, {got}",
                               err=True)

            res = aim_study(sim, st, progress=progress)
            results.append(res)
            click.echo(summary_line(res))
            for reason, n in refusal_counts(res).items():
                click.echo(f"  refused {n}×: {reason}")
    if json_path is not None:
        write_json(json_path, {"aim_study": [r.to_dict() for r in results],
                               "settings": asdict(st)})
    if not all(r.passed for r in results):
        raise SystemExit(1)


def _coverage(st: CoverageSettings, json_path: str | None, quiet: bool) -> None:
    """``validate --coverage``: per photon count the synthetic lamps' point coverage and
    every kind of rule's coverage and wrong verdicts, then every ``--lamp`` against its
    reference run."""
    if st.lamps < 0 or (st.lamps == 0 and not st.lamp_files):
        raise InputError(f"--lamps must be at least 1 (0 with --lamp), got {st.lamps}")
    if min(st.counts) < 1000:
        raise InputError(f"--photons must be at least 1000, got {min(st.counts):,.0f}")
    if not (math.isfinite(st.aperture) and 0 < st.aperture <= 2):
        raise InputError(f"--aperture must be in (0, 2] degrees, got {st.aperture}")
    if st.seeds < 1:
        raise InputError(f"--seeds must be at least 1, got {st.seeds}")
    if st.reference_photons < max(st.counts):
        raise InputError("--reference-photons must be at least the largest photon count")
    for f in st.lamp_files:
        if not Path(f).is_file():
            raise InputError(f"--lamp: no such file: {f}")

    def note(text: str) -> None:
        if not quiet:
            click.echo(f"  {text}", err=True)

    doc: dict = {"synthetic": [], "lamps": []}
    ok = True
    for photons in (int(c) for c in st.counts):
        if not st.lamps:
            break
        res = coverage_study(st.lamps, photons, aperture_deg=st.aperture, spt=st.spt,
                             seed=st.seed, guide=st.guide, progress=lambda n, run, p=photons: note(
                                 f"lamp {n + 1}/{st.lamps} ({p:,} photons): "
                                 f"{run.seconds:.1f} s"))
        lo, hi = res.band()
        good = lo <= res.rate <= hi and all(c.wrong <= c.allowed()
                                            for c in res.rules.values())
        ok &= good
        rows = [[name, f"{p['coverage']:.1%}", f"{p['mean_bias_halfwidths']:+.2f}"]
                for name, p in res.per_point.items()]
        _print_table(f"lightsim validate --coverage: {res.lamps} lamps × {photons:,} "
                     f"photons, aperture {st.aperture:g}°{' with SPT' if st.spt else ''}"
                     f"{' guided' if st.guide else ''} "
                     f"(truth: the file's bilinear intensity), {res.seconds:.0f} s",
                     ["point", "coverage", "mean bias (half-widths)"], rows)
        click.echo(f"coverage {res.covered}/{res.evaluations} = {res.rate:.1%} "
                   f"(target {COVERAGE_BAND[0]:.0%}–{COVERAGE_BAND[1]:.0%}, accepted "
                   f"{lo:.1%}–{hi:.1%} for this many evaluations)")
        click.echo(f"worst evaluation: {res.worst_bias_point} off by {res.worst_bias:.2f} "
                   f"half-widths; worst point on average: {res.worst_mean_point} "
                   f"{res.worst_mean_bias:+.2f} half-widths")
        _print_table(f"rules of {res.lamps} synthetic lamps × {photons:,} photons: interval "
                     f"coverage and wrong verdicts (pass where the truth fails or fail "
                     f"where it passes; nominal α/2 per evaluation): "
                     f"{'pass' if good else 'FAIL'}", VERDICT_HEADER,
                     _verdict_rows(res.rules))
        doc["synthetic"].append({"coverage": res.to_dict(), "passed": good,
                                 "accepted_band": [lo, hi]})
    for lamp in st.lamp_files:
        for photons in (int(c) for c in st.counts):
            res = shipped_study(lamp, photons, st.seeds,
                                reference_photons=int(st.reference_photons),
                                cache_dir=st.reference_dir or DEFAULT_CACHE,
                                aperture_deg=st.aperture, progress=note,
                                guide=st.guide)
            good = all(c.wrong <= c.allowed() for c in res.rules.values())
            ok &= good
            _print_table(f"{Path(lamp).name}: {st.seeds} runs × {photons:,} photons "
                         f"against a {int(st.reference_photons):,}-photon reference "
                         f"(verdicts it decides at 99.9 %), {res.seconds:.0f} s: "
                         f"{'pass' if good else 'FAIL'}", VERDICT_HEADER,
                         _verdict_rows(res.rules))
            for o in res.wrong_examples[:5]:
                click.echo(f"  wrong: {o.ruleset} {o.name} {o.verdict} ({o.value:.4g} in "
                           f"{o.lo:.4g}–{o.hi:.4g}; reference {o.truth:.4g}, "
                           f"{o.truth_verdict})")
            doc["lamps"].append({**res.to_dict(), "passed": good})
    click.echo(f"coverage study: {'pass' if ok else 'FAIL'}")
    if json_path:
        write_json(json_path, {**doc, "passed": ok})
    if not ok:
        raise SystemExit(1)
