"""``lightsim luminaire …``: build luminaire scenes and list the bulb presets.

Click commands only: parse, call :mod:`lightsim.luminaires`, print. Sizes on the command line
are in millimetres (as on drawings); the library works in metres. Input problems raise
:class:`lightsim.errors.InputError` (one line, exit code 2).
"""

from __future__ import annotations

from pathlib import Path

import click

from lightsim.errors import InputError
from lightsim.io.rayfile import write_rayfile
from lightsim.luminaires.bulbs import BULBS
from lightsim.luminaires.cad_example import write_example
from lightsim.luminaires.headlight import write_headlight
from lightsim.luminaires.matrix import MatrixParams, write_matrix
from lightsim.luminaires.projector import ProjectorParams, write_projector
from lightsim.luminaires.rayfiles import lambertian_square
from lightsim.materialmap import MaterialMap, read_material_map
from lightsim.partlist import list_parts

MM = 1e-3
_P = ProjectorParams()
_M = MatrixParams()


@click.group()
def luminaire() -> None:
    """Luminaires: the parametric filament headlight, the LED projector and matrix
    examples, the bulb presets, a lamp file's parts."""


@luminaire.command()
@click.argument("out", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--bulb", default="H4-low", show_default=True,
              help="Bulb preset: H4-low, H4-high, H1, H3 or H7 (see `luminaire bulbs`).")
@click.option("--focal-length", "focal_length_mm", type=float, default=25.0, show_default=True,
              help="Paraboloid focal length in mm.")
@click.option("--aperture", "aperture_mm", type=float, default=160.0, show_default=True,
              help="Reflector aperture (rim) diameter in mm.")
@click.option("--lens", type=click.Choice(["fluted", "clear", "none"], case_sensitive=False),
              default="fluted", show_default=True,
              help="Cover lens: vertical flutes that spread the beam sideways, clear, or none.")
@click.option("--flute-spread", "flute_spread_deg", type=float, default=8.0, show_default=True,
              help="Largest horizontal deflection by a flute, in degrees (fluted lens).")
@click.option("--flux", "flux_lm", type=float, default=None,
              help="Luminous flux of the filament in lm [default: the preset's].")
@click.option("--emission", type=click.Choice(["isotropic", "lambertian"], case_sensitive=False),
              default="isotropic", show_default=True, help="Angular emission of the filament.")
@click.option("--traffic", type=click.Choice(["right", "left"], case_sensitive=False),
              default="right", show_default=True,
              help="Traffic side; left mirrors the passing beam's 15° step-up.")
def headlight(
    out: Path,
    bulb: str,
    focal_length_mm: float,
    aperture_mm: float,
    lens: str,
    flute_spread_deg: float,
    flux_lm: float | None,
    emission: str,
    traffic: str,
) -> None:
    """Write the parametric headlight (reflector, bulb, shield, lens, filament) to OUT.glb.

    Axes: +Y up, the lamp shines along +Z, reflector vertex at the origin, focus at
    (0, 0, f); H on the wall (the driver's right) is world −X.
    """
    if out.suffix.lower() != ".glb":
        raise InputError(f"output {out} must be a .glb file")
    if not out.parent.exists() and str(out.parent) != "":
        raise InputError(f"output folder {out.parent} does not exist")
    summary = write_headlight(
        out,
        bulb=bulb,
        focal_length_m=focal_length_mm * MM,
        aperture_m=aperture_mm * MM,
        lens=lens.lower(),
        flux_lm=flux_lm,
        emission=emission.lower(),
        traffic=traffic.lower(),
        flute_spread_deg=flute_spread_deg,
    )
    triangles = summary["triangles"]
    click.echo(
        f"wrote {out} ({summary['bytes'] / 1e6:.2f} MB): bulb {summary['bulb']}, "
        f"{summary['flux_lm']:g} lm {emission.lower()}, f = {focal_length_mm:g} mm, "
        f"aperture {aperture_mm:g} mm, lens {lens.lower()}, {traffic.lower()}-hand traffic"
    )
    width = max(len(name) for name in triangles)
    for name, count in triangles.items():
        click.echo(f"  {name:<{width}}  {count:>7,d} triangles")
    click.echo(f"  {'total':<{width}}  {sum(triangles.values()):>7,d} triangles")


@luminaire.command()
def bulbs() -> None:
    """List the bulb presets: flux, filament size and position, and where the flux is from.

    Positions are relative to the reflector focus in mm (x, y up, z ahead along the beam).
    Filament sizes are assumptions (UN R37 data sheets were not available).
    """
    header = (
        f"{'preset':<8} {'cat':<4} {'flux lm':>8} {'W':>4} {'filament L×Ø mm':>16} "
        f"{'centre x,y,z mm':>17} {'axis':<5} {'cup':<4} {'tip cap':<7} {'lamp cap':<8}"
    )
    click.echo(header)
    click.echo("-" * len(header))
    for spec in BULBS.values():
        x, y, z = (v / MM for v in spec.filament_offset_m)
        axis = "Z" if spec.filament_axis == (0.0, 0.0, 1.0) else "X"
        size = f"{spec.filament_length_m / MM:.2f}×{spec.filament_diameter_m / MM:.2f}"
        click.echo(
            f"{spec.name:<8} {spec.category:<4} {spec.flux_lm:>8.0f} {spec.power_w:>4.0f} "
            f"{size:>16} {f'{x:+.2f},{y:+.2f},{z:+.2f}':>17} {axis:<5} "
            f"{'yes' if spec.shield_cup else 'no':<4} "
            f"{'yes' if spec.envelope.tip_cap else 'no':<7} {spec.cap:<8}"
        )
    click.echo("\nflux sources (at the 13.2 V test voltage):")
    for spec in BULBS.values():
        click.echo(f"  {spec.name:<8} {spec.flux_source}")
    click.echo("cup = H4 shield cup; tip cap = opaque black cap on the dome. Filament sizes and "
               "positions are stated assumptions (see lightsim.luminaires.bulbs).")


@luminaire.command()
@click.argument("out", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--side", "side_mm", type=float, default=1.0, show_default=True,
              help="Edge of the square Lambertian emitter (LED die) in mm.")
@click.option("--rays", type=int, default=100_000, show_default=True,
              help="Rays in the file (rounded down to a square number).")
@click.option("--flux", "flux_lm", type=float, default=1000.0, show_default=True,
              help="Luminous flux in lm.")
@click.option("--seed", type=int, default=1, show_default=True)
def rayfile(out: Path, side_mm: float, rays: int, flux_lm: float, seed: int) -> None:
    """Write the ray file of a square Lambertian LED die facing +Z (TM-25 for .tm25ray,
    Zemax binary for .dat/.ray)."""
    pos, dirs, flux = lambertian_square(side_mm * MM, rays, flux_lm, seed)
    write_rayfile(out, pos, dirs, flux, f"Lambertian square {side_mm:g} mm")
    click.echo(f"wrote {out}: {len(pos):,} rays, {flux_lm:g} lm, square {side_mm:g} mm, "
               "Lambertian along +Z")


@luminaire.command("cad-example")
@click.argument("out", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--focal-length", "focal_mm", type=float, default=25.0, show_default=True,
              help="Paraboloid focal length in mm.")
@click.option("--aperture", "aperture_mm", type=float, default=160.0, show_default=True,
              help="Reflector aperture diameter in mm.")
@click.option("--flux", "flux_lm", type=float, default=1000.0, show_default=True,
              help="Filament flux in lm (written to the material map).")
def cad_example(out: Path, focal_mm: float, aperture_mm: float, flux_lm: float) -> None:
    """Write an example headlamp as CAD (STEP or IGES by suffix: exact paraboloid
    reflector, axial filament, bulb glass, cover lens) and its material map OUT.toml."""
    mmap = write_example(out, focal_mm, aperture_mm / 2, flux_lm)
    click.echo(f"wrote {out} (reflector, filament, bulb, lens; mm) and {mmap}")


@luminaire.command()
@click.argument("lamp", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--materials", "materials", type=click.Path(dir_okay=False, path_type=Path),
              default=None, help="Material map (TOML): also show the rule each name gets.")
@click.option("--faces/--no-faces", default=True, show_default=True,
              help="List each CAD part's faces (their addresses part/face).")
def parts(lamp: Path, materials: Path | None, faces: bool) -> None:
    """List LAMP's parts (STEP, IGES, glTF) and CAD faces by the names a material map's
    `match` (and --part-material) can use, with triangles and size in mm."""
    mmap = read_material_map(materials) if materials is not None else None
    entries = list_parts(lamp, mmap)
    n_faces = sum(len(e.faces) for e in entries)
    click.echo(f"{lamp}: {len(entries)} part(s), {n_faces} named face(s)"
               + (f"; rules from {materials}" if mmap is not None else ""))
    names = [e.name for e in entries] + [f.address for e in entries for f in e.faces]
    width = max(len("part / face address") + 1, *(len(n) + 2 for n in names))
    click.echo(f"{'part / face address':<{width}} {'triangles':>9}  {'size x×y×z mm':>22}"
               + ("  rule" if mmap is not None else ""))
    for e in entries:
        size = "×".join(f"{x:.1f}" for x in e.size_mm)
        note = "  (emitter in the file)" if e.emissive else ""
        click.echo(f"{e.name:<{width}} {e.triangles:>9,d}  {size:>22}"
                   + (f"  {_rule_text(mmap, e.rule)}" if mmap is not None else "") + note)
        for f in e.faces if faces else ():
            rule = ""
            if mmap is not None and f.split:
                rule = f"  {_rule_text(mmap, f.rule)} (split off)"
            click.echo(f"  {f.address:<{width - 2}} {f.triangles:>9,d}{'':24}{rule}".rstrip())
    if mmap is not None:
        missing = [e.name for e in entries if e.rule is None]
        if missing:
            click.echo(f"no rule for: {', '.join(missing)} (they keep the file's material)")
    elif not any(e.emissive for e in entries):
        click.echo("no part emits light: give one a rule with kind = \"emitter\" in a "
                   "material map (--materials) or add a bulb with --filament")


def _rule_text(mmap: MaterialMap, number: int | None) -> str:
    """'#2 mirror (reflector*)' for rule ``number`` of ``mmap``, '–' for none."""
    if number is None:
        return "–"
    rule = mmap.rules[number - 1]
    return f"#{number} {rule.kind} ({rule.match})"


def _check_glb(out: Path) -> None:
    if out.suffix.lower() != ".glb":
        raise InputError(f"output {out} must be a .glb file")
    if not out.parent.exists() and str(out.parent) != "":
        raise InputError(f"output folder {out.parent} does not exist")


def _echo_triangles(triangles: dict[str, int]) -> None:
    width = max(len(name) for name in triangles)
    for name, count in triangles.items():
        click.echo(f"  {name:<{width}}  {count:>7,d} triangles")
    click.echo(f"  {'total':<{width}}  {sum(triangles.values()):>7,d} triangles")


@luminaire.command()
@click.argument("out", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--beam", type=click.Choice(["low", "high"], case_sensitive=False),
              default="low", show_default=True,
              help="Low beam (shield up, cut-off with step) or high beam (shield flipped "
                   "down).")
@click.option("--traffic", type=click.Choice(["right", "left"], case_sensitive=False),
              default="right", show_default=True,
              help="Traffic side; left mirrors the cut-off's step.")
@click.option("--led", default=_P.led, show_default=True,
              help="LED preset (LED-1x1: one 1 mm² die, LED-2x1: two).")
@click.option("--flux", "flux_lm", type=float, default=None,
              help="Luminous flux of the LED in lm [default: the example's].")
@click.option("--focal-distance", "focal_mm", type=float, default=_P.focal_distance_m / MM,
              show_default=True,
              help="Distance between the ellipsoid's foci (LED to shield edge) in mm.")
@click.option("--semi-major", "semi_major_mm", type=float, default=_P.semi_major_m / MM,
              show_default=True, help="Semi-major axis of the ellipsoidal reflector in mm.")
@click.option("--lens-diameter", "lens_diameter_mm", type=float,
              default=_P.lens_diameter_m / MM, show_default=True,
              help="Diameter of the aspheric lens in mm.")
@click.option("--lens-distance", "lens_distance_mm", type=float,
              default=_P.lens_distance_m / MM, show_default=True,
              help="Shield edge to the lens's flat back face in mm.")
@click.option("--step", "step_deg", type=float, default=_P.step_deg, show_default=True,
              help="Angle of the cut-off's step in degrees (15; 45 for a kink).")
def projector(out: Path, beam: str, traffic: str, led: str, flux_lm: float | None,
              focal_mm: float, semi_major_mm: float, lens_diameter_mm: float,
              lens_distance_mm: float, step_deg: float) -> None:
    """Write the bi-function LED projector module (LED, ellipsoidal reflector, shield,
    aspheric lens, sign-light prisms) to OUT.glb.

    Axes: +Y up, the lamp shines along +Z, the LED at the origin facing up (the
    ellipsoid's first focus), the shield edge at the second focus (0, 0, focal distance).
    """
    _check_glb(out)
    options = {"beam": beam.lower(), "traffic": traffic.lower(), "led": led,
               "focal_distance_m": focal_mm * MM, "semi_major_m": semi_major_mm * MM,
               "lens_diameter_m": lens_diameter_mm * MM,
               "lens_distance_m": lens_distance_mm * MM, "step_deg": step_deg}
    if flux_lm is not None:
        options["flux_lm"] = flux_lm
    summary = write_projector(out, **options)
    click.echo(
        f"wrote {out} ({summary['bytes'] / 1e6:.2f} MB): {summary['led']} "
        f"{summary['flux_lm']:g} lm Lambertian ({summary['luminance_cd_m2'] / 1e6:.0f} "
        f"Mcd/m²), {beam.lower()} beam, {traffic.lower()}-hand traffic, lens f = "
        f"{summary['lens_focal_length_m'] / MM:.1f} mm"
    )
    _echo_triangles(summary["triangles"])


@luminaire.command()
@click.argument("out", type=click.Path(dir_okay=False, path_type=Path))
@click.option("--segments", type=int, default=_M.segments, show_default=True,
              help="Number of LED segments (each lights one vertical stripe).")
@click.option("--span", "span_deg", type=float, default=_M.span_deg, show_default=True,
              help="Total width of the stripes in degrees, centred on H = 0.")
@click.option("--flux", "flux_lm", type=float, default=_M.flux_lm, show_default=True,
              help="Mean luminous flux of a segment in lm (shared by die area).")
@click.option("--only-segment", type=int, default=None,
              help="Build only this segment's die (0 = leftmost stripe).")
def matrix(out: Path, segments: int, span_deg: float, flux_lm: float,
           only_segment: int | None) -> None:
    """Write the matrix LED high beam (a row of LED segments behind one aspheric lens) to
    OUT.glb; segment k is the emitter part led_k (k = 00 lights the leftmost stripe).

    Axes: +Y up, the lamp shines along +Z, the dies in the plane z = 0 on the lens axis.
    """
    _check_glb(out)
    summary = write_matrix(out, segments=segments, span_deg=span_deg, flux_lm=flux_lm,
                           only_segment=only_segment)
    edges = summary["stripes_deg"]
    click.echo(
        f"wrote {out} ({summary['bytes'] / 1e6:.2f} MB): {segments} segments, "
        f"{summary['flux_lm']:g} lm Lambertian ({summary['luminance_cd_m2'] / 1e6:.1f} Mcd/m²), "
        f"stripes {edges[1] - edges[0]:.2f}° wide from H = {edges[0]:g}° to {edges[-1]:g}°, "
        f"lens f = {summary['lens_focal_length_m'] / MM:.1f} mm"
    )
    _echo_triangles(summary["triangles"])
