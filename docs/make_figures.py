"""Make the manual's pictures (``docs/img/*.png``) from real ``lightsim`` runs.

Every picture is what a user gets from the commands printed beside it: the script runs
the ``lightsim`` command line in a temporary folder and copies the files it wrote (PNG
plots, and screenshots of ``lightsim view`` taken in a headless Chromium through
Playwright), optimised and, where needed, reduced in size so the set stays small.

    python docs/make_figures.py                        # every picture (about 20–30 min)
    python docs/make_figures.py --only view-camera     # one picture (its run runs whole)
    python docs/make_figures.py --only first-run       # every picture of one run
    python docs/make_figures.py --list

Runs and the pictures they give:

================  =====================================  ====================================
run               commands                               pictures (docs/img/…)
================  =====================================  ====================================
``first-run``     ``simulate`` the shipped low beam,     first-run-wall_lux, -isolux, -road,
                  R112 + R149 class B                    -error_vs_time
``compare``       ``simulate`` the shipped headlight,    compare-overlay, compare-contours
                  ``photo`` (synthetic camera),
                  ``compare`` (registration by the beam)
``tolerance``     a small ``tolerance`` study            tolerance
``design``        a small ``design``, then ``simulate``  design-isolux
                  of the lamp it wrote
``view``          ``view`` of the shipped low beam       view-interaction, view-converged,
                  in Chromium                            view-camera
``led-lamps``     ``simulate`` the shipped LED           led-projector-isolux,
                  projector (R149 class B passing) and   led-matrix-isolux
                  matrix high beam (class B driving)
``adb``           ``simulate --per-source`` the matrix   led-adb-isolux
                  beam, ``adb`` with two road users
``road``          ``simulate --road`` the shipped low    road-right-250
                  beam (the road guide's run)
================  =====================================  ====================================

Parameters
----------
=================  ======  ==========  ===============================================
name               unit    default     meaning
=================  ======  ==========  ===============================================
FIRST_RUN_PHOTONS  1       16 000 000  photons of the first run (the pictures' noise)
MAX_WIDTH          px      1300        wider pictures are scaled down
QUANTISE_ABOVE     bytes   300 000     larger PNGs are reduced to 256 colours
VIEW_VIEWPORT      px      1300×900    browser window of the screenshots
CHROMIUM           –       Debian's    ``/usr/bin/chromium``
=================  ======  ==========  ===============================================
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
IMG = ROOT / "docs" / "img"
LOWBEAM = ROOT / "luminaires" / "examples" / "lowbeam.glb"
HEADLIGHT = ROOT / "luminaires" / "examples" / "headlight.glb"
PROJECTOR = ROOT / "luminaires" / "examples" / "projector.glb"
MATRIX = ROOT / "luminaires" / "examples" / "matrix.glb"
CHROMIUM = "/usr/bin/chromium"

FIRST_RUN_PHOTONS = 16_000_000
MAX_WIDTH = 1300
QUANTISE_ABOVE = 300_000
VIEW_VIEWPORT = {"width": 1300, "height": 900}
VIEW_WARM_UP_S = 300.0        # kernels compile at the view's start
VIEW_CONVERGE_S = 90.0        # the longest wait for the accumulated map
VIEW_TARGET_ERROR = 0.03      # the accumulated map's error figure worth a picture
VIEW_CAMERA_S = 30.0          # accumulation of the camera tab before its picture


def lightsim_command() -> list[str]:
    """The ``lightsim`` console script beside this interpreter, else the module."""
    script = Path(sys.executable).with_name("lightsim")
    return [str(script)] if script.exists() else [sys.executable, "-m", "lightsim.cli.main"]


def run(args: list[str], cwd: Path) -> None:
    """Run ``lightsim ARGS`` in ``cwd`` (printed first); its output goes to a log file."""
    shown = "lightsim " + " ".join(shlex.quote(_short(a)) for a in args)
    print(f"  $ {shown}", flush=True)
    t0 = time.perf_counter()
    log = cwd / "commands.log"
    with log.open("a") as out:
        out.write(f"$ {shown}\n")
        out.flush()
        done = subprocess.run(lightsim_command() + args, cwd=cwd, stdout=out,
                              stderr=subprocess.STDOUT, check=False)
    if done.returncode != 0:
        tail = log.read_text(errors="replace").splitlines()[-15:]
        raise SystemExit(f"make_figures: `{shown}` failed (exit {done.returncode}):\n"
                         + "\n".join(tail))
    print(f"    {time.perf_counter() - t0:.0f} s", flush=True)


def _short(arg: str) -> str:
    """Paths inside the repository as the manual writes them (relative to its root)."""
    try:
        return str(Path(arg).relative_to(ROOT))
    except ValueError:
        return arg


# -- the runs --------------------------------------------------------------------------------
def first_run(work: Path) -> dict[str, Path]:
    """The getting-started run: the shipped low beam against R112 and R149, class B."""
    run(["simulate", str(LOWBEAM), "--photons", str(FIRST_RUN_PHOTONS), "--resolution",
         "320x128", "--regulation", "r112-b-passing,r149-b-passing", "--out", "first-run",
         "--quiet"], work)
    out = work / "first-run"
    return {f"first-run-{n}": out / f"{n}.png"
            for n in ("wall_lux", "isolux", "road", "error_vs_time")}


def compare(work: Path) -> dict[str, Path]:
    """The compare walk-through: a simulation, a synthetic photo of it, the comparison."""
    run(["simulate", str(HEADLIGHT), "--photons", "4000000", "--out", "h4", "--quiet"], work)
    run(["photo", "h4", "photo.jpg", "--rotate", "6", "--scale", "1.15", "--shift", "12,-6",
         "--tilt", "10", "--blur", "1", "--noise", "0.01", "--vignetting", "0.3", "--gamma",
         "2.2", "--saturate", "0.7", "--seed", "1"], work)
    run(["compare", "photo.jpg", "--sim", "h4", "--out", "cmp", "--homography",
         "--fit-gamma", "--quiet"], work)
    return {"compare-overlay": work / "cmp" / "overlay.png",
            "compare-contours": work / "cmp" / "contours.png"}


def tolerance(work: Path) -> dict[str, Path]:
    """A small bulb-tolerance study of the shipped low beam (12 samples, 2 M photons)."""
    run(["tolerance", str(LOWBEAM), "--regulation", "r112-b-passing", "--samples", "12",
         "--photons", "2000000", "--resolution", "160x64", "--out", "tol", "--quiet"], work)
    return {"tolerance": work / "tol" / "tolerance.png"}


def design(work: Path) -> dict[str, Path]:
    """A small reflector design (3 × 8 facets, one model round), then the lamp it wrote
    simulated against the rule set it was designed for."""
    run(["design", "--regulation", "r112-b-passing", "designed.glb", "--rings", "3",
         "--sectors", "8", "--model-rounds", "1", "--model-photons", "500000",
         "--model-evaluations", "500", "--validate-factor", "0", "--aim-photons", "1000000",
         "--linearity-photons", "0", "--out", "design-check"], work)
    run(["simulate", "designed.glb", "--photons", "4000000", "--resolution", "320x128",
         "--regulation", "r112-b-passing", "--outputs", "isolux,json", "--out", "designed",
         "--quiet"], work)
    return {"design-isolux": work / "designed" / "isolux.png"}


def led_lamps(work: Path) -> dict[str, Path]:
    """The LED guide's runs: the projector's low beam and the matrix beam, all on."""
    run(["simulate", str(PROJECTOR), "--photons", "48000000", "--resolution", "320x128",
         "--regulation", "r149-b-passing", "--outputs", "isolux,json", "--out", "projector",
         "--quiet"], work)
    run(["simulate", str(MATRIX), "--photons", "16000000", "--resolution", "320x128",
         "--regulation", "r149-b-driving", "--outputs", "isolux,json", "--out", "matrix",
         "--quiet"], work)
    return {"led-projector-isolux": work / "projector" / "isolux.png",
            "led-matrix-isolux": work / "matrix" / "isolux.png"}


ADB_TRAFFIC = """[road]
mount_height_m = 0.65

[[vehicle]]
name = "oncoming car"
kind = "oncoming"
distance_m = 30.0

[[vehicle]]
name = "car ahead"
kind = "preceding"
distance_m = 80.0
"""


def adb(work: Path) -> dict[str, Path]:
    """The LED guide's masking picture: the matrix beam with per-source maps, masked for an
    oncoming car at 30 m and a car ahead at 80 m."""
    run(["simulate", str(MATRIX), "--photons", "16000000", "--resolution", "320x128",
         "--per-source", "--outputs", "json", "--out", "matrix-ps", "--quiet"], work)
    (work / "traffic.toml").write_text(ADB_TRAFFIC, encoding="utf-8")
    run(["adb", "matrix-ps", "--traffic", "traffic.toml"], work)
    return {"led-adb-isolux": work / "matrix-ps" / "adb" / "adb_isolux.png"}


def road(work: Path) -> dict[str, Path]:
    """The road guide's run: the shipped low beam with the road evaluation; its plot of the
    250 m right curve."""
    run(["simulate", str(LOWBEAM), "--photons", "400000", "--road", "--out", "lowbeam-road",
         "--quiet"], work)
    return {"road-right-250": work / "lowbeam-road" / "road_right-250.png"}


_DRAG_JS = """async (seconds) => {
  const V = window.lightsimView;
  const t0 = performance.now();
  let x = 0, last = t0;
  while (performance.now() - t0 < seconds * 1000) {
    if (performance.now() - last >= 50) {   // a slider drag: a change every 50 ms
      x = (x + 1) % 20; V.setControl('aim_h_deg', 0.05 * x); last = performance.now();
    }
    await new Promise((r) => setTimeout(r, 5));
  }
}"""

_CONVERGED_JS = """([edit, target]) => {
  const s = window.lightsimView.status;
  return s && s.edit >= edit && s.error_source === 'written map' && s.rel_error !== null
    && s.rel_error <= target;
}"""


def view(work: Path) -> dict[str, Path]:
    """``lightsim view`` of the shipped low beam in Chromium: during a drag, after the
    photons accumulated, and the camera tab."""
    from playwright.sync_api import TimeoutError as PlaywrightTimeout
    from playwright.sync_api import sync_playwright

    if not Path(CHROMIUM).exists():
        raise SystemExit(f"make_figures: {CHROMIUM}: no Chromium (apt-get install chromium)")
    args = ["view", str(LOWBEAM), "--port", "0", "--out", "view-session"]
    print("  $ lightsim " + " ".join(_short(a) for a in args), flush=True)
    log_path = work / "view.log"
    log = log_path.open("w")
    proc = subprocess.Popen(lightsim_command() + args, cwd=work, stdout=log,
                            stderr=subprocess.STDOUT)
    shots = {name: work / f"{name}.png"
             for name in ("view-interaction", "view-converged", "view-camera")}
    try:
        url = _view_url(proc, log_path)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM,
                                        args=["--no-sandbox", "--headless"])
            page = browser.new_page(viewport=VIEW_VIEWPORT)
            page.goto(url)
            page.wait_for_function("window.lightsimView.wallFrames >= 2 && "
                                   "window.lightsimView.regulation !== null",
                                   timeout=VIEW_WARM_UP_S * 1000)
            page.evaluate(_DRAG_JS, 4.0)
            page.screenshot(path=str(shots["view-interaction"]))
            print("    view-interaction: taken during a drag", flush=True)
            page.evaluate("window.lightsimView.setControl('aim_h_deg', 0)")  # back to 0°
            page.wait_for_timeout(1000)
            edit = page.evaluate("window.lightsimView.status.edit")
            try:
                page.wait_for_function(_CONVERGED_JS, arg=[edit, VIEW_TARGET_ERROR],
                                       timeout=VIEW_CONVERGE_S * 1000)
            except PlaywrightTimeout:
                print(f"    (the map's error did not reach {VIEW_TARGET_ERROR:.0%} in "
                      f"{VIEW_CONVERGE_S:.0f} s: taken as it is)", flush=True)
            page.wait_for_timeout(1500)  # the pooled map that goes with the figure
            page.screenshot(path=str(shots["view-converged"]))
            status = page.evaluate("window.lightsimView.status")
            print(f"    view-converged: {status.get('photons', 0):,} photons, error "
                  f"{status.get('rel_error') or float('nan'):.1%}", flush=True)
            page.click("#tab-camera")
            page.wait_for_function("window.lightsimView.cameraFrames >= 3", timeout=120_000)
            page.wait_for_timeout(VIEW_CAMERA_S * 1000)  # the camera image accumulates
            page.screenshot(path=str(shots["view-camera"]))
            browser.close()
    finally:
        proc.send_signal(signal.SIGINT)  # the command's own Ctrl-C: it stops its session
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        log.close()
    return shots


def _view_url(proc: subprocess.Popen, log: Path) -> str:
    """The page address ``lightsim view`` prints (to ``log``) once its session is warm."""
    deadline = time.monotonic() + VIEW_WARM_UP_S
    while time.monotonic() < deadline:
        m = re.search(r"(http://127\.0\.0\.1:\d+\S*)", log.read_text(errors="replace"))
        if m:
            return m.group(1)
        if proc.poll() is not None:
            raise SystemExit(f"make_figures: lightsim view ended (exit {proc.returncode}):\n"
                             + log.read_text(errors="replace")[-2000:])
        time.sleep(0.5)
    raise SystemExit("make_figures: lightsim view printed no address")


@dataclass(frozen=True)
class Run:
    """One run and the pictures it gives."""

    name: str
    make: Callable[[Path], dict[str, Path]]
    pictures: tuple[str, ...]


RUNS = (
    Run("first-run", first_run, ("first-run-wall_lux", "first-run-isolux", "first-run-road",
                                 "first-run-error_vs_time")),
    Run("compare", compare, ("compare-overlay", "compare-contours")),
    Run("tolerance", tolerance, ("tolerance",)),
    Run("design", design, ("design-isolux",)),
    Run("led-lamps", led_lamps, ("led-projector-isolux", "led-matrix-isolux")),
    Run("adb", adb, ("led-adb-isolux",)),
    Run("road", road, ("road-right-250",)),
    Run("view", view, ("view-interaction", "view-converged", "view-camera")),
)


# -- the pictures ----------------------------------------------------------------------------
def finish(src: Path, dst: Path) -> int:
    """Copy picture ``src`` to ``dst``: RGB, at most :data:`MAX_WIDTH` wide, optimised, and
    reduced to 256 colours when still larger than :data:`QUANTISE_ABOVE` bytes. Returns
    the bytes written."""
    with Image.open(src) as im:
        im.load()
        if im.mode in ("RGBA", "LA", "P"):
            rgba = im.convert("RGBA")
            im = Image.new("RGB", rgba.size, "white")
            im.paste(rgba, mask=rgba.getchannel("A"))
        else:
            im = im.convert("RGB")
    if im.width > MAX_WIDTH:
        im = im.resize((MAX_WIDTH, round(im.height * MAX_WIDTH / im.width)),
                       Image.Resampling.LANCZOS)
    tmp = dst.with_suffix(".tmp.png")
    im.save(tmp, optimize=True)
    if tmp.stat().st_size > QUANTISE_ABOVE:
        im.quantize(colors=256, method=Image.Quantize.MEDIANCUT,
                    dither=Image.Dither.NONE).save(tmp, optimize=True)
    os.replace(tmp, dst)
    return dst.stat().st_size


def selected(only: list[str]) -> list[tuple[Run, tuple[str, ...]]]:
    """The runs to do and the pictures to keep from each, for ``--only`` names (a picture
    or a run; none = everything)."""
    out = []
    for r in RUNS:
        keep = r.pictures if not only or r.name in only else tuple(
            p for p in r.pictures if p in only)
        if keep:
            out.append((r, keep))
    known = {r.name for r in RUNS} | {p for r in RUNS for p in r.pictures}
    unknown = [n for n in only if n not in known]
    if unknown:
        raise SystemExit(f"make_figures: unknown name(s) {', '.join(unknown)}; "
                         f"--list shows them")
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", action="append", default=[], metavar="NAME",
                        help="a picture (e.g. first-run-isolux) or a run (e.g. view); "
                        "repeatable")
    parser.add_argument("--list", action="store_true", help="list runs and pictures")
    parser.add_argument("--keep", metavar="DIR", help="run in DIR and keep what it wrote")
    args = parser.parse_args(argv)
    if args.list:
        for r in RUNS:
            print(f"{r.name}: {', '.join(r.pictures)}")
        return
    todo = selected(args.only)
    total = sum(len(keep) for _, keep in todo)
    IMG.mkdir(parents=True, exist_ok=True)
    work_root = Path(args.keep) if args.keep else Path(tempfile.mkdtemp(prefix="lightsim-fig-"))
    done = 0
    try:
        for r, keep in todo:
            work = work_root / r.name
            work.mkdir(parents=True, exist_ok=True)
            print(f"{r.name}: making {', '.join(keep)}", flush=True)
            made = r.make(work)
            for name in keep:
                done += 1
                size = finish(made[name], IMG / f"{name}.png")
                print(f"[{done}/{total}] docs/img/{name}.png  {size / 1e3:.0f} kB", flush=True)
    finally:
        if not args.keep:
            shutil.rmtree(work_root, ignore_errors=True)
    sizes = sum(p.stat().st_size for p in IMG.glob("*.png"))
    print(f"docs/img: {len(list(IMG.glob('*.png')))} pictures, {sizes / 1e6:.2f} MB")


if __name__ == "__main__":
    main()
