"""EULUMDAT reading (uneven C angles per symmetry, lamp sets, flux check) and mutated
IES/LDT headers: one clear line, exit 2, never a traceback."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from lightsim.errors import InputError
from lightsim.luminaires.photometric import CandelaGrid, read_ies, read_ldt
from lightsim.scene import SceneSettings, load_scene

from support import run_cli as _run

GAMMA = [0.0, 30.0, 60.0, 90.0, 120.0, 180.0]


def g_profile(g):
    return 400.0 * np.cos(np.radians(np.asarray(g)) / 2) ** 2 + 20.0


def f_sym3(c):
    """Symmetric about the C90–C270 plane: f(C) = f(180° − C)."""
    c = np.radians(np.asarray(c))
    return np.exp(2.5 * np.sin(c)) + 0.5 + 0.4 * np.cos(2 * c)


def ldt_lines(isym: int, c_all, stored_rows, *, dc: float = 0.0, sets=((1, 1000.0),),
              lorl: float | None = None, conv: float = 1.0) -> list[str]:
    """A EULUMDAT file, field by field (1-based field k is ``lines[k-1]``)."""
    mc = len(c_all)
    lines = ["lightsim tests", "1", str(isym), str(mc), f"{dc:g}", str(len(GAMMA)), "0",
             "report", "test luminaire", "n1", "test.ldt", "2026-12-01 tests"]
    lines += ["100", "100", "50", "80", "80", "0", "0", "0", "0"]        # fields 13–21
    lines += ["100", "LORL", f"{conv:g}", "0", str(len(sets))]          # fields 22–26
    for n_l, flux in sets:
        lines += [str(n_l), "LED", f"{flux:g}", "3000", "80", "10"]
    lines += ["0"] * 10
    lines += [f"{c:g}" for c in c_all] + [f"{g:g}" for g in GAMMA]
    for row in stored_rows:
        lines += [f"{x:.9g}" for x in row]
    if lorl is None:
        lorl = 100.0
    lines[22] = f"{lorl:.9g}"
    return lines


def write(tmp_path, lines, name="lamp.ldt"):
    p = tmp_path / name
    p.write_text("\r\n".join(lines) + "\r\n", encoding="latin-1")
    return p


# uneven C planes symmetric about C90–C270: stored from C270 through C0 to C90
FRONT = [270.0, 285.0, 320.0, 345.0, 0.0, 10.0, 30.0, 60.0, 90.0]
C_ALL = sorted({round((180.0 - c) % 360.0, 9) for c in FRONT} | set(FRONT))


def sym3_file(tmp_path, **kw):
    rows = [f_sym3(c) * g_profile(GAMMA) for c in FRONT]  # cd/klm
    return write(tmp_path, ldt_lines(3, C_ALL, rows, **kw))


def test_ldt_symmetry_3_uneven_c_angles(tmp_path):
    assert len(C_ALL) == 16 and C_ALL[12] == 270.0            # index 3·Mc/4 is C270
    exact = CandelaGrid(C_ALL, GAMMA, np.outer(f_sym3(C_ALL), g_profile(GAMMA)), 1000.0)
    p = sym3_file(tmp_path, lorl=100 * exact.total_flux() / 1000.0)
    g = read_ldt(p)
    assert g.warnings == ()                                   # flux matches the header
    assert np.array_equal(g.c_deg, C_ALL)                     # the listed angles are used
    assert np.allclose(g.candela, exact.candela, rtol=1e-8)   # = the analytic function
    assert g.total_flux() == pytest.approx(exact.total_flux(), rel=1e-8)
    # reading the stored planes as evenly spaced (270 + 22.5°·k), as before, is wrong
    even = (270.0 + 360.0 / 16 * np.arange(9)) % 360.0
    rows = g.candela[[C_ALL.index(c) for c in FRONT]]
    pairs = {}
    for ang, row in zip(even, rows):
        for img in (ang, 180.0 - ang):
            pairs.setdefault(round(img % 360.0, 9), row)
    old = CandelaGrid(sorted(pairs), GAMMA, [pairs[k] for k in sorted(pairs)], 1000.0)
    flux_err = old.total_flux() / exact.total_flux() - 1
    shape_err = np.max(np.abs(old.intensity(np.array(C_ALL)[:, None], np.array(GAMMA)[None])
                              - exact.candela)) / exact.max_candela()
    print(f"\nLDT Isym 3, uneven C: flux {g.total_flux():.6g} lm (exact "
          f"{exact.total_flux():.6g}); even-spacing reading: flux {100 * flux_err:+.1f} %, "
          f"shape off by up to {100 * shape_err:.0f} % of the peak")
    assert abs(flux_err) > 0.05 and shape_err > 0.05
    pyldt = pytest.importorskip("pyldt")
    raw = pyldt.LdtReader.read(p, expand_symmetry=False)     # eulumdat-py's parse
    assert raw.header.isym == 3 and raw.header.c_angles == C_ALL
    assert np.allclose(np.asarray(raw.intensities), rows)     # same stored planes, in order


def test_ldt_isym0_uneven_cross_read(tmp_path):
    c = [0.0, 10.0, 25.0, 90.0, 180.0, 200.0, 270.0, 300.0]
    rng = np.random.default_rng(3)
    rows = rng.uniform(10, 500, size=(len(c), len(GAMMA)))
    p = write(tmp_path, ldt_lines(0, c, rows, dc=45.0))      # Dc disagrees with the list
    g = read_ldt(p)
    assert np.array_equal(g.c_deg, c)
    assert np.allclose(g.candela, rows)                       # 1000 lm: cd/klm = cd
    assert any("Dc = 45°" in w for w in g.warnings)
    pyldt = pytest.importorskip("pyldt")
    ref = pyldt.LdtReader.read(p)
    assert np.allclose(np.asarray(ref.intensities), rows)
    photompy = pytest.importorskip("photompy")
    lf = photompy.LDTFile.read(str(p))
    assert np.allclose(lf.photometry.phis, c) and np.allclose(lf.photometry.values, rows)


def test_ldt_symmetry_layout_must_match(tmp_path):
    bad = [0.0, 30.0, 60.0, 100.0, 180.0, 200.0, 260.0, 280.0]  # index 6 is not C270
    rows = np.ones((5, len(GAMMA)))
    with pytest.raises(InputError, match="Isym 3 stores the planes C270"):
        read_ldt(write(tmp_path, ldt_lines(3, bad, rows)))
    with pytest.raises(InputError, match="divisible by 4"):
        read_ldt(write(tmp_path, ldt_lines(4, [0.0, 45.0, 90.0, 180.0, 270.0, 300.0],
                                           np.ones((2, len(GAMMA))))))


def test_ldt_lamp_sets(tmp_path):
    rows = [np.full(len(GAMMA), 100.0)]
    p = write(tmp_path, ldt_lines(1, [0.0], rows, sets=((2, 1000.0), (1, 3000.0))))
    first = read_ldt(p)
    assert first.lamp_lumens == 1000.0 and np.allclose(first.candela, 100.0)  # not 400 cd
    assert any("2 lamp sets" in w and "--lamp-set" in w for w in first.warnings)
    second = read_ldt(p, lamp_set=2)
    assert second.lamp_lumens == 3000.0 and np.allclose(second.candela, 300.0)
    with pytest.raises(InputError, match="lamp set"):
        read_ldt(p, lamp_set=3)
    scene = load_scene(p, SceneSettings(lamp_set=2, resolution=(8, 8)))
    assert scene.total_flux == pytest.approx(second.total_flux())
    assert any("lamp sets" in w for w in scene.warnings)


def test_ldt_flux_disagreement_warning(tmp_path):
    exact = CandelaGrid(C_ALL, GAMMA, np.outer(f_sym3(C_ALL), g_profile(GAMMA)), 1000.0)
    right = 100 * exact.total_flux() / 1000.0
    assert read_ldt(sym3_file(tmp_path, lorl=1.04 * right)).warnings == ()   # within 5 %
    g = read_ldt(sym3_file(tmp_path, lorl=right / 3))                         # 3× off
    assert len(g.warnings) == 1 and "integrate to" in g.warnings[0]
    assert "+200.0 %" in g.warnings[0]


# ---- mutated headers: one line, no traceback -------------------------------------------
def _base_ldt(tmp_path):
    return ldt_lines(3, C_ALL, [f_sym3(c) * g_profile(GAMMA) for c in FRONT])


@pytest.mark.parametrize("field, value, fragment", [
    (4, "inf", "Mc"), (4, "nan", "Mc"), (4, "1e400", "Mc"), (4, "-3", "Mc"),
    (4, "2.5", "Mc"), (4, "1e9", "Mc"), (6, "inf", "Ng"), (6, "nan", "Ng"),
    (6, "100000", "need at least"), (3, "7", "Isym"), (2, "x", "not a number"),
    (5, "-10", "Dc"), (24, "nan", "conversion"), (26, "inf", "lamp sets"),
    (26, "0", "lamp sets"), (29, "inf", "lamp flux"), (29, "0", "lamp flux"),
    (25, "1e999", "tilt"),
])
def test_mutated_ldt_header(tmp_path, field, value, fragment):
    lines = _base_ldt(tmp_path)
    lines[field - 1] = value
    with pytest.raises(InputError) as exc:
        read_ldt(write(tmp_path, lines))
    msg = str(exc.value)
    assert fragment in msg and "\n" not in msg and msg.startswith("LDT file lamp.ldt")


def test_mutated_ldt_angles_and_values(tmp_path):
    lines = _base_ldt(tmp_path)
    k = lines.index("345")                        # a C angle
    for value, fragment in (("inf", "not finite"), ("nan", "not finite")):
        bad = list(lines)
        bad[k] = value
        with pytest.raises(InputError, match=fragment):
            read_ldt(write(tmp_path, bad))
    bad = list(lines)
    bad[-1] = "nan"                               # an intensity
    with pytest.raises(InputError, match="intensities"):
        read_ldt(write(tmp_path, bad))
    bad = list(lines)
    bad[-1] = "1e308"
    bad[23] = "1e10"                              # conversion × value overflows
    with pytest.raises(InputError, match="not finite"):
        read_ldt(write(tmp_path, bad))


IES_OK = ("IESNA:LM-63-2002\n[TEST] t\nTILT=NONE\n1 1000 1 3 2 1 2 0 0 0\n1 1 10\n"
          "0 45 90\n0 180\n10 20 30\n40 50 60\n")


@pytest.mark.parametrize("old, new, fragment", [
    ("1 1000 1 3 2 1 2", "1 1000 1 inf 2 1 2", "vertical angles"),
    ("1 1000 1 3 2 1 2", "1 1000 1 nan 2 1 2", "vertical angles"),
    ("1 1000 1 3 2 1 2", "1 1000 1 3 1e12 1 2", "horizontal angles"),
    ("1 1000 1 3 2 1 2", "1 1000 1 300 2 1 2", "need"),
    ("1 1000 1 3 2 1 2", "1 1000 nan 3 2 1 2", "multiplier"),
    ("1 1000 1 3 2 1 2", "1 1000 0 3 2 1 2", "multiplier"),
    ("1 1000 1 3 2 1 2", "1 1000 1 3 2 1.5 2", "photometric type"),
    ("1 1000 1 3 2 1 2", "1 1000 1 3 2 1 7", "units"),
    ("1 1000 1 3 2 1 2", "1 -5 1 3 2 1 2", "lumens per lamp"),
    ("1 1000 1 3 2 1 2", "inf 1000 1 3 2 1 2", "number of lamps"),
    ("1 1 10", "nan 1 10", "ballast"),
    ("10 20 30", "10 inf 30", "candela"),
    ("0 45 90", "0 45 nan", "vertical angles"),
    ("TILT=NONE\n", "TILT=INCLUDE\n1 inf\n", "TILT"),
])
def test_mutated_ies_header(tmp_path, old, new, fragment):
    p = tmp_path / "bad.ies"
    p.write_text(IES_OK.replace(old, new, 1))
    with pytest.raises(InputError) as exc:
        read_ies(p)
    msg = str(exc.value)
    assert fragment in msg and "\n" not in msg and msg.startswith("IES file bad.ies")


def test_ies_ok_and_warnings(tmp_path):
    p = tmp_path / "ok.ies"
    p.write_text(IES_OK)
    g = read_ies(p)
    assert g.warnings == () and g.shape == (2, 3)
    p.write_text(IES_OK.replace("40 50 60", "40 -1 60"))
    assert any("negative" in w for w in read_ies(p).warnings)
    p.write_text(IES_OK.replace("1 1000 1 3 2 1 2", "1 10 1 3 2 1 2"))
    assert any("efficiency above 100 %" in w for w in read_ies(p).warnings)


@pytest.mark.parametrize("kind", ["ldt", "ies"])
def test_cli_bad_photometric_header_exit_2(tmp_path, capsys, kind):
    if kind == "ldt":
        lines = _base_ldt(tmp_path)
        lines[3] = "inf"
        p = write(tmp_path, lines)
    else:
        p = tmp_path / "bad.ies"
        p.write_text(IES_OK.replace("1 1000 1 3 2 1 2", "1 1000 1 nan 2 1 2"))
    out = tmp_path / "run"
    code, _, err = _run(["simulate", str(p), "--photons", "20000", "--resolution", "16x8",
                         "--out", str(out), "--quiet"], capsys)
    assert code == 2
    lines_err = [x for x in err.splitlines() if x.strip()]
    assert len(lines_err) == 1 and "Traceback" not in err
    assert not out.exists() or not any(out.iterdir())


def test_cli_lamp_set_and_warning_line(tmp_path, capsys):
    rows = [np.full(len(GAMMA), 100.0)]
    p = write(tmp_path, ldt_lines(1, [0.0], rows, sets=((1, 1000.0), (1, 3000.0)), lorl=314))
    out = tmp_path / "run"
    code, _, err = _run(["simulate", str(p), "--photons", "20000", "--resolution", "16x8",
                         "--lamp-set", "2", "--estimator", "bin", "--out", str(out),
                         "--quiet"], capsys)
    assert code == 0, err
    assert "lamp sets" in err and "set 2 (3000 lm)" in err
    code, _, err = _run(["simulate", str(p), "--photons", "20000", "--resolution", "16x8",
                         "--lamp-set", "5", "--out", str(tmp_path / "r2"), "--quiet"], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1


def _mutations(text: str, rng, n: int):
    """Seeded edits of a photometric file: numbers replaced, lines cut/duplicated, bytes."""
    specials = ["inf", "-inf", "nan", "1e400", "-1", "0", "1e9", "2.5", "-0", "x", "", "1e-320"]
    lines = text.split("\n")
    for _ in range(n):
        kind = rng.integers(4)
        ls = list(lines)
        k = int(rng.integers(len(ls)))
        if kind == 0:                                   # one token → a special value
            toks = ls[k].split(" ")
            toks[int(rng.integers(len(toks)))] = specials[int(rng.integers(len(specials)))]
            ls[k] = " ".join(toks)
        elif kind == 1:                                 # truncate
            ls = ls[:k]
        elif kind == 2:                                 # duplicate a line
            ls.insert(k, ls[k])
        else:                                           # flip a byte
            b = bytearray("\n".join(ls).encode("latin-1", "replace"))
            if b:
                b[int(rng.integers(len(b)))] ^= 1 << int(rng.integers(7))
            yield b
            continue
        yield "\n".join(ls).encode("latin-1", "replace")


@pytest.mark.parametrize("kind", ["ies", "ldt"])
def test_seeded_mutation_corpus(tmp_path, kind):
    """Every mutant reads cleanly or fails with one InputError line; no numpy warning."""
    if kind == "ies":
        text = IES_OK
        reader = read_ies
    else:
        text = "\n".join(_base_ldt(tmp_path))
        reader = read_ldt
    rng = np.random.default_rng(13)
    outcome = {"ok": 0, "error": 0}
    for k, data in enumerate(_mutations(text, rng, 60)):
        p = tmp_path / f"m{k}.{kind}"
        p.write_bytes(bytes(data))
        with warnings.catch_warnings():
            warnings.simplefilter("error")              # a leaked RuntimeWarning fails
            try:
                g = reader(p)
            except InputError as exc:
                assert "\n" not in str(exc)
                outcome["error"] += 1
                continue
        assert np.isfinite(g.total_flux()) and np.all(np.isfinite(g.candela))
        outcome["ok"] += 1
    assert outcome["ok"] + outcome["error"] == 60 and outcome["error"] > 0
