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
``--coverage``         –      off         the regulation-point coverage study instead:
                                          synthetic sharp cut-off lamps, 95 % intervals
                                          against exact aperture means
``--lamps``            –      40          lamps in the coverage study
``--aperture``         deg    0.15        detector aperture of the coverage study
``--spt-points``       –      off         SPT aimed at the test points (coverage study)
=====================  =====  ==========  ================================================

``lightsim converge SCENE``
======================  =====  ===============  ============================================
option                  unit   default          meaning
======================  =====  ===============  ============================================
``--budgets``           s      0.25,0.5,…,8     time budgets (``--full``: up to 64)
``--photons``           –      none             photon budgets instead (e.g. 250k,1M,4M;
                                                reproducible whatever the machine's load)
``--estimator``         –      all five         knnM=4, knnM=1, bin, radius, knnM=4SPT
``--out``               –      converge-out     folder for converge.csv/.json/.png
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
import time
from collections.abc import Sequence

import click

from lightsim.engine.config import RunConfig
from lightsim.errors import InputError
from lightsim.options import click_option, lookup


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
              help="Synthetic lamps in the coverage study.")
@click.option("--aperture", type=float, default=0.15, show_default=True,
              help="Detector aperture (deg) of the coverage study.")
@click.option("--spt-points", is_flag=True, help="Coverage study with SPT aimed at the points.")
@click.option("--quiet", "-q", is_flag=True, help="Only the table.")
def validate(full: bool, stability: bool, run_all: bool, cases: tuple[str, ...],
             estimators: tuple[str, ...], photons: int | None, seed: int,
             json_path: str | None, coverage: bool, lamps: int, aperture: float,
             spt_points: bool, quiet: bool) -> None:
    """Check the simulator against exact answers (and stiff, extreme cases).

    Prints case, quantity, expected, measured, error, uncertainty and pass for every
    check; exits with code 1 if any check fails.
    """
    if coverage:
        _coverage(lamps, photons or 1_000_000, aperture, spt_points, seed,
                  json_path, quiet)
        return
    from lightsim.validation import analytic
    from lightsim.validation import stability as stab
    from lightsim.validation.analytic import TABLE_COLUMNS, SuiteSettings, table_rows

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
        from lightsim.io.summary import write_json

        doc.update({"passed": not failed, "seconds": seconds, "n_checks": len(checks),
                    "n_failed": len(failed)})
        write_json(json_path, doc)
        if not quiet:
            click.echo(f"wrote {json_path}")
    if failed:
        raise SystemExit(1)


def _budgets(text: str | None, full: bool) -> list[float]:
    from lightsim.validation.converge import FULL_BUDGETS, QUICK_BUDGETS

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


@click.command()
@click.argument("scene")
@click.option("--budgets", help="Time budgets in s, comma-separated (default 0.25 … 8; "
                                "--full: 0.25 … 64).")
@click.option("--full", is_flag=True, help="Budgets up to a minute.")
@click.option("--photons", "photon_budgets",
              help="Photon budgets instead of seconds, comma-separated (250k, 1M, 4e6).")
@click.option("--estimator", "estimators", multiple=True,
              help="knnM=4, knnM=1, bin, radius, knnM=4SPT (repeatable; default all).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), default="converge-out",
              show_default=True, help="Folder for converge.csv/.json/.png.")
@click_option(lookup(RunConfig, "frame_photons"), default=50_000)
@click.option("--resolution", help="Wall pixels WxH (scene files: default 160x64).")
@click.option("--reference-factor", type=float, default=20.0, show_default=True,
              help="Reference run length / longest budget (scene files).")
@click_option(lookup(RunConfig, "seed"))
@click.option("--quiet", "-q", is_flag=True)
def converge(scene: str, budgets: str | None, full: bool, photon_budgets: str | None,
             estimators: tuple[str, ...], out_dir: str, frame_photons: int,
             resolution: str | None, reference_factor: float, seed: int, quiet: bool) -> None:
    """Error against run time for every estimator on SCENE.

    SCENE is analytic:NAME (isotropic, paraboloid, slab, slab-absorbing, lambertian:
    compared with the exact answer) or a scene file (compared with a bin reference run
    --reference-factor times longer than the longest budget).
    """
    from lightsim.validation import converge as cv

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


def _coverage(lamps: int, photons: int, aperture: float, spt: bool, seed: int,
              json_path: str | None, quiet: bool) -> None:
    """``validate --coverage``: print the rate, the worst biases and a per-point table."""
    from lightsim.validation.coverage import COVERAGE_BAND, coverage_study

    if lamps < 1:
        raise InputError(f"--lamps must be at least 1, got {lamps}")
    if photons < 1000:
        raise InputError(f"--photons must be at least 1000, got {photons}")
    if not (math.isfinite(aperture) and 0 < aperture <= 2):
        raise InputError(f"--aperture must be in (0, 2] degrees, got {aperture}")

    def progress(n: int, run) -> None:
        if not quiet:
            click.echo(f"  lamp {n + 1}/{lamps}: {run.seconds:.1f} s", err=True)

    res = coverage_study(lamps, photons, aperture_deg=aperture, spt=spt, seed=seed,
                         progress=progress)
    lo, hi = res.band()
    ok = lo <= res.rate <= hi
    rows = [[name, f"{p['coverage']:.1%}", f"{p['mean_bias_halfwidths']:+.2f}"]
            for name, p in res.per_point.items()]
    _print_table(f"lightsim validate --coverage: {res.lamps} lamps × {photons:,} photons, "
                 f"aperture {aperture:g}°{' with SPT' if spt else ''} "
                 f"(truth: the file's bilinear intensity), {res.seconds:.0f} s",
                 ["point", "coverage", "mean bias (half-widths)"], rows)
    click.echo(f"coverage {res.covered}/{res.evaluations} = {res.rate:.1%} "
               f"(target {COVERAGE_BAND[0]:.0%}–{COVERAGE_BAND[1]:.0%}, accepted "
               f"{lo:.1%}–{hi:.1%} for this many evaluations): {'pass' if ok else 'FAIL'}")
    click.echo(f"worst evaluation: {res.worst_bias_point} off by {res.worst_bias:.2f} "
               f"half-widths; worst point on average: {res.worst_mean_point} "
               f"{res.worst_mean_bias:+.2f} half-widths")
    if json_path:
        from lightsim.io.summary import write_json

        write_json(json_path, {"coverage": res.to_dict(), "passed": ok,
                               "accepted_band": [lo, hi]})
    if not ok:
        raise SystemExit(1)
