"""The option table: every run option declared once (lightsim.options) reaches ``simulate
--help`` with its unit and default, the command line, the checkpoint and summary.json
unchanged; nonsense values exit 2 with one line; ``--resume`` refuses conflicting options."""

from __future__ import annotations

import dataclasses
import json
import math
from typing import Any

import click
import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from lightsim import options
from lightsim.cli.main import cli
from lightsim.cli.simulate import simulate
from lightsim.engine.config import (
    MAX_RADIUS_FACTOR,
    SUPPORTED,
    SUPPORTED_FIELDS,
    RunConfig,
    supported_text,
)
from lightsim.engine.estimator import effective_radii
from lightsim.errors import InputError
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart
from lightsim.options import Option
from lightsim.scene import SceneSettings, load_scene
from lightsim.simulate import SimulateOptions, read_checkpoint, run_simulation
from lightsim.validation import converge as cv
from lightsim.view.controls import CONFIG_CONTROLS, SPEC_BY_NAME

from support import run_cli, write_point_lamp

COMMAND_ONLY = {"scene_file", "resume_dir", "explain", "quiet"}  # not run options
SIM = options.table(SimulateOptions)
RUN = options.table(RunConfig)
CLI = [o for o in SIM + RUN if o.on_cli]


@pytest.fixture(scope="module")
def lamp(tmp_path_factory):
    """An isotropic 1000 lm point-like source 2 m from the wall, a grey plate behind it."""
    plate = trimesh.creation.box(bounds=[[-0.2, -0.2, -0.3], [0.2, 0.2, -0.29]])
    return write_point_lamp(
        tmp_path_factory.mktemp("lamp") / "point.glb",
        GltfPart("plate", np.asarray(plate.vertices), np.asarray(plate.faces), None,
                 GltfMaterial("grey", base_color=(0.5, 0.5, 0.5))))


TINY = ["--photons", "8000", "--frame-photons", "4000", "-M", "2", "--resolution", "16x8",
        "--wall-distance", "2", "--wall-size", "4x2", "--estimator", "bin", "--quiet"]


# -- a valid value other than the default, and nonsense, for any record ---------------------
STRUCTURED = {  # internal settings holding tuples of tuples (set by the regulation check)
    "extra_probes": ((0.5, -0.25), (1.0, 0.0)), "apertures": ((-1.5, 0.5), (0.0, 0.0)),
    "aperture_targets": (0, 1), "aperture_raster": (-5.0, 5.0, -2.0, 1.0),
    "guide_targets": ((0, -3.0, -1.0, -1.0, 0.5, 1.0),)}


def _other(opt: Option) -> Any:
    """A valid value ≠ the default, derived from the record alone (or STRUCTURED)."""
    d = opt.default
    if opt.name in STRUCTURED:
        return STRUCTURED[opt.name]
    assert opt.kind != "tuple", opt.name
    if opt.kind == "names":
        return tuple(opt.choices[:1])
    if opt.choices is not None:
        return next(c for c in opt.choices if c != d and c is not None)
    if opt.kind in ("flag", "onoff"):
        return not d if isinstance(d, bool) else True
    if opt.kind == "assign":
        return {"lens": "glass:1.5", "bezel": "diffuse:0.2"}
    if opt.suffixes:
        return "beam" + opt.suffixes[-1]
    if opt.kind in ("pair", "triple"):
        n = 2 if opt.kind == "pair" else 3
        base = d if d is not None else (1,) * n
        return tuple(opt.cast(v + 2) for v in base)
    if opt.cast is str:
        return "lamp.toml" if opt.kind == "file" else "other-value"
    lo = 0 if opt.low is None else opt.low
    if opt.cast is int:
        value = (d if d is not None else int(lo)) + 1
        return min(value, int(opt.high)) if opt.high is not None and value > opt.high else value
    hi = opt.high if opt.high is not None else (d if d else lo) * 2 + 1
    value = (lo + hi) / 2 if d is None else (d + hi) / 2
    return value if value != d else (lo + value) / 2


def _text(opt: Option, value: Any) -> list[str]:
    """The command-line words that set ``opt`` to ``value``."""
    flag = opt.flag[0]
    if opt.kind == "flag":
        return [flag] if value else []
    if opt.kind == "onoff":
        on, _, off = flag.partition("/")
        return [on if value else off]
    if opt.kind == "assign":
        return [w for k, v in value.items() for w in (flag, f"{k}={v}")]
    if opt.kind == "pair":
        return [flag, "x".join(str(v) for v in value)]
    if opt.kind == "triple":
        return [flag, ",".join(repr(v) for v in value)]
    if opt.kind == "names":
        return [flag, ",".join(value)]
    return [flag, repr(value) if isinstance(value, float) else str(value)]


def _others() -> tuple[SimulateOptions, RunConfig]:
    sim = {o.name: _other(o) for o in SIM if o.name != "scene_path"}
    run = {o.name: _other(o) for o in RUN}
    run["frame_photons"] = 10_000  # ≥ the interleave sets (a cross-field check)
    return SimulateOptions("lamp.glb", config={}, **sim), RunConfig(**run)


def _parse(argv: list[str]) -> dict[str, Any]:
    """The values click hands to ``simulate`` for ``argv`` (nothing is run)."""
    with simulate.make_context("simulate", argv) as ctx:
        return {k: v for k, v in ctx.params.items() if k not in COMMAND_ONLY}


# -- the table is complete both ways ----------------------------------------------------------
def test_every_field_is_declared_and_every_flagless_one_says_who_sets_it():
    for cls in (SimulateOptions, RunConfig):
        declared = {o.name for o in options.table(cls)}
        fields = {f.name for f in dataclasses.fields(cls)} - {"config"}
        assert declared == fields, cls  # config is RunConfig itself
        for o in options.table(cls):
            assert o.help.strip(), o.name
            assert o.on_cli or o.internal, f"{o.name}: neither a flag nor who sets it"


def test_command_line_options_are_exactly_the_table():
    params = {p.name for p in simulate.params} - COMMAND_ONLY
    assert params == {o.name for o in CLI}
    assert not {o.name for o in SIM} & {o.name for o in RUN}  # one namespace
    flags = [f for o in CLI for f in o.flag]
    assert len(flags) == len(set(flags))


def test_help_shows_every_option_with_unit_range_and_default():
    res = CliRunner().invoke(simulate, ["--help"], terminal_width=10_000,
                             max_content_width=10_000)
    assert res.exit_code == 0, res.output
    text = " ".join(res.output.split())  # an option's help may start on the next line
    for o in CLI:
        shown = o.help_text()
        assert text.count(shown) == 1, (o.name, shown)
        i = text.index(shown)
        flags = text[max(0, i - 70):i]  # the option's own column stands just before it
        assert f"{o.flag[0].split('/')[0]} " in flags, (o.name, flags)
        assert f"default: {o.default_str()}]" in shown
        if o.unit:
            assert f"[{o.unit};" in shown
        if o.range_text():
            assert f"; {o.range_text()};" in shown or f"[{o.range_text()};" in shown


def test_max_radius_help_says_what_the_estimator_does(lamp):
    """The auto max radius in --help comes from MAX_RADIUS_FACTOR; the estimator uses it."""
    wall = load_scene(str(lamp), SceneSettings(wall_distance=2.0, wall_size=(4.0, 2.0),
                      resolution=(16, 8))).wall
    help_text = options.lookup(RunConfig, "max_radius").help_text()
    for mode, factor in MAX_RADIUS_FACTOR.items():
        assert f"{factor:g} × ({mode})" in help_text
        r_min, r_max = effective_radii(RunConfig(min_radius=0.01, final=mode), wall, mode)
        assert r_min == 0.01 and r_max == pytest.approx(factor * 0.01, rel=1e-12)
    assert set(MAX_RADIUS_FACTOR) == set(options.lookup(RunConfig, "final").choices)


# -- every option round-trips ---------------------------------------------------------------
def test_command_line_gives_every_declared_value():
    sim, run = _others()
    argv = ["lamp.glb"]
    for o in CLI:
        argv += _text(o, getattr(run if o in RUN else sim, o.name))
    opts = SimulateOptions.from_command_line("lamp.glb", _parse(argv))
    for o in SIM:
        if o.on_cli:
            assert getattr(opts, o.name) == getattr(sim, o.name), o.name
    cfg = opts.run_config()
    for o in RUN:
        if o.on_cli:
            assert getattr(cfg, o.name) == getattr(run, o.name), o.name


def test_defaults_on_the_command_line_are_the_declared_ones():
    opts = SimulateOptions.from_command_line("lamp.glb", _parse(["lamp.glb"]))
    assert opts == SimulateOptions("lamp.glb", config=opts.config)
    assert opts.run_config() == RunConfig()


def test_every_setting_round_trips_through_json():
    sim, run = _others()
    sim.config = run.to_dict()
    run_inf = run.with_(max_radius=math.inf)
    for cfg in (run, run_inf, RunConfig()):
        doc = json.loads(json.dumps(cfg.to_dict(), allow_nan=False))
        assert RunConfig.from_dict(doc) == cfg
    doc = json.loads(json.dumps(sim.to_json(), allow_nan=False))
    back = SimulateOptions.from_json(doc)
    assert back == sim and back.run_config() == run


def test_checkpoint_and_summary_hold_every_setting(lamp, tmp_path):
    """A real run, interrupted after one frame: checkpoint.json holds the options and the
    engine config; resumed, summary.json["config"] is the same config."""
    argv = [str(lamp), *TINY, "--out", str(tmp_path / "run"), "--seed", "7", "-k", "9",
            "--part-material", "plate=diffuse:0.3", "--aperture", "0.3"]
    opts = SimulateOptions.from_command_line(str(lamp), _parse(argv))
    frames = {"n": 0}

    def stop() -> bool:
        frames["n"] += 1
        return frames["n"] > 1

    res = run_simulation(opts, should_stop=stop)
    assert res.interrupted
    stored, resume = read_checkpoint(tmp_path / "run")
    assert stored == opts
    # the run decides keep_photons (bins read no photon after their frame)
    config = opts.run_config().with_(keep_photons=False)
    assert RunConfig.from_dict(resume["session"]["config"]) == config
    assert not run_simulation(stored, resume=resume).interrupted
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    assert RunConfig.from_dict(summary["config"]) == config
    assert summary["config"] == config.to_dict()
    assert summary["photons"] == 8000


# -- --resume and the command line ----------------------------------------------------------
@pytest.fixture
def interrupted(lamp, tmp_path):
    out = tmp_path / "run"
    opts = SimulateOptions.from_command_line(
        str(lamp), _parse([str(lamp), *TINY, "--out", str(out)]))
    calls = {"n": 0}

    def stop() -> bool:
        calls["n"] += 1
        return calls["n"] > 1

    assert run_simulation(opts, should_stop=stop).interrupted
    return out


@pytest.mark.parametrize("extra,match", [
    (["-k", "32"], "-k 64 (not 32)"),
    (["--estimator", "knn"], "--estimator bin (not knn)"),
    (["--resolution", "32x8"], "--resolution 16,8 (not 32,8)"),
    (["--seed", "2", "--linear"], "--log True (not False), --seed 1 (not 2)"),
])
def test_resume_refuses_options_that_conflict_with_the_checkpoint(interrupted, capsys,
                                                                   extra, match):
    before = sorted(p.name for p in interrupted.iterdir())
    code, _, err = run_cli(["simulate", "--resume", str(interrupted), *extra], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("lightsim: error:"), err
    assert "the checkpoint was run with" in lines[0] and match in lines[0], lines[0]
    assert sorted(p.name for p in interrupted.iterdir()) == before  # nothing touched


def test_resume_accepts_matching_options_and_a_new_budget(interrupted, capsys):
    code, _, err = run_cli(["simulate", "--resume", str(interrupted), "-k", "64",
                            "--estimator", "bin", "--photons", "12000", "--quiet"], capsys)
    assert code == 0, err
    summary = json.loads((interrupted / "summary.json").read_text())
    assert summary["photons"] == 12000 and not (interrupted / "checkpoint.json").exists()


def test_resume_replays_with_the_stored_config_or_refuses(interrupted, capsys):
    """The checkpoint's engine config is read: one that the stored options no longer give
    (another lightsim's defaults) is refused rather than replayed differently."""
    path = interrupted / "checkpoint.json"
    doc = json.loads(path.read_text())
    doc["session"]["config"]["max_depth"] = 16
    path.write_text(json.dumps(doc))
    code, _, err = run_cli(["simulate", "--resume", str(interrupted)], capsys)
    assert code == 2 and len(err.strip().splitlines()) == 1, err
    assert "other settings" in err and "max depth 16 (now 32)" in err
    doc["session"]["config"]["max_depth"] = "deep"
    path.write_text(json.dumps(doc))
    code, _, err = run_cli(["simulate", "--resume", str(interrupted)], capsys)
    assert code == 2 and "corrupt checkpoint" in err and "max depth" in err


# -- nonsense → one line, exit 2 ------------------------------------------------------------
def _bad(opt: Option) -> list[Any]:
    """Values outside ``opt``'s declared range or choices."""
    out: list[Any] = []
    if opt.choices is not None:
        return ["nonsense"]
    if opt.kind in ("flag", "onoff", "assign") or opt.cast is str:
        return ["nonsense.txt"] if opt.suffixes else []
    if opt.low is not None:
        out.append(opt.low - 1 if opt.cast is int else (opt.low if opt.low_open else
                                                         opt.low - 0.5))
    if opt.high is not None:
        out.append(opt.high + 1 if opt.cast is int else (opt.high if opt.high_open else
                                                          opt.high + 0.5))
    if opt.cast is float and opt.kind == "value":
        out.append(math.nan)
        if not opt.allow_inf:
            out.append(math.inf)
    return out


BAD_CLI = [(o, v) for o in CLI for v in _bad(o)]


@pytest.mark.parametrize("opt,value", BAD_CLI, ids=[f"{o.flag[0]}={v}" for o, v in BAD_CLI])
def test_nonsense_on_the_command_line_exits_2_with_one_line(lamp, tmp_path, capsys, opt, value):
    out = tmp_path / "o"
    if opt.kind == "pair":
        words = [opt.flag[0], "x".join([str(value)] * 2)]
    elif opt.kind == "triple":
        words = [opt.flag[0], ",".join([str(value)] * 3)]
    else:
        words = [opt.flag[0], str(value)]
    code, _, err = run_cli(["simulate", str(lamp), *words, "--out", str(out), "--quiet"],
                           capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("lightsim: error:"), err
    assert opt.flag[0].split("/")[0] in lines[0] or "Invalid value" in lines[0], lines[0]
    assert not out.exists()


@pytest.mark.parametrize("opt", [o for o in RUN if _bad(o)], ids=lambda o: o.name)
def test_nonsense_in_the_python_api_raises_one_line(opt):
    for value in _bad(opt):
        if opt.kind == "pair":
            value = (value, 1)
        with pytest.raises(InputError) as exc:
            RunConfig(**{opt.name: value})
        assert "\n" not in str(exc.value) and opt.label in str(exc.value)


def test_range_message_names_flag_unit_and_bounds():
    with pytest.raises(InputError, match=r"^--aperture must be 0 … 2 deg, got 3.0$"):
        SimulateOptions("lamp.glb", aperture=3.0)
    with pytest.raises(InputError, match=r"^--interleave must be 1 … 16, got 17$"):
        RunConfig(interleave=17)
    with pytest.raises(InputError, match=r"^--max-radius must be > 0 m, got 0.0$"):
        RunConfig(max_radius=0.0)
    assert RunConfig(max_radius=math.inf).max_radius == math.inf  # the paper's kNN
    with pytest.raises(InputError, match=r"^--min-radius must be finite, got inf$"):
        RunConfig(min_radius=math.inf)
    with pytest.raises(InputError, match="photons per frame"):
        RunConfig(frame_photons=3, interleave=2)


def test_other_commands_share_the_records():
    """Where another command takes a run option, its click option is the record's (help
    with unit and range; its own default shown)."""
    opt = options.lookup(RunConfig, "frame_photons")
    dec = options.click_option(opt, default=20_000)

    @click.command()
    @dec
    def cmd(frame_photons: int) -> None:
        click.echo(str(frame_photons))

    res = CliRunner().invoke(cmd, ["--help"], terminal_width=10_000, max_content_width=10_000)
    assert "Photons per frame (all sets). [≥ 1; default: 20000]" in res.output
    assert CliRunner().invoke(cmd, []).output.strip() == "20000"


@pytest.mark.parametrize("path,name,default", [
    (("view",), "frame_photons", 20_000), (("view",), "resolution", None),
    (("view",), "workers", None), (("view",), "traffic", None),
    (("validate",), "seed", None), (("converge",), "seed", None),
    (("converge",), "frame_photons", 50_000),
    (("bench", "frames"), "frame_photons", 50_000), (("bench", "plan"), "frame_photons", 100_000),
    (("bench", "scaling"), "resolution", None), (("bench", "view"), "frame_photons", 20_000),
])
def test_other_commands_show_the_same_record(path, name, default):
    """Commands that take a run option take its record: the same help, unit and range as
    ``simulate``; only the default may be theirs."""
    cmd: Any = cli
    for word in path:
        cmd = cmd.get_command(None, word)
    opt = next(o for o in CLI if o.name == name)
    if default is not None:
        opt = dataclasses.replace(opt, default=default, default_text=None)
    param = next(p for p in cmd.params if p.name == name)
    assert param.help == opt.help_text() and param.default == (
        opt.default_str() if opt.kind == "pair" else opt.default)
    flags = [f for f in opt.flag if "/" not in f]
    assert set(param.opts) == set(flags)


def test_view_sliders_stay_inside_the_run_config_ranges():
    """The view's k / interleave / frame-photons sliders feed RunConfig: their ranges must be
    ones RunConfig accepts."""
    for name in CONFIG_CONTROLS:
        spec = SPEC_BY_NAME[name]
        for end in (spec.lo, spec.hi):
            assert getattr(RunConfig(**{name: int(end)}), name) == end
        opt = options.lookup(RunConfig, name)
        assert spec.unit == opt.unit, name


# -- the supported estimator settings -------------------------------------------------------
def test_every_supported_estimator_setting_runs_and_the_runners_use_only_those():
    """Every row of SUPPORTED makes a RunConfig (with any value where the estimator does
    not read a setting); the combinations ``converge`` and ``validate`` run are among them."""
    for row in SUPPORTED:
        settings = {f: v for f, v in zip(SUPPORTED_FIELDS, row, strict=True) if v is not None}
        RunConfig(**settings)
        if row[0] == "bin":  # bin reads none of the others
            RunConfig(estimator="bin", bandwidth="knn", final="interleaved", kernel="cone",
                      structure="grid-hi")
    for spec in cv.SPECS:
        RunConfig(**spec.settings)
    for est in ("bin", "knn", "radius"):  # validate's image checks: the kNN model (r_k)
        RunConfig(estimator=est, bandwidth="knn")


@pytest.mark.parametrize("settings", [
    {"kernel": "cone"}, {"structure": "median"}, {"bandwidth": "knn", "final": "interleaved"},
    {"estimator": "radius", "kernel": "epanechnikov"}])
def test_unsupported_estimator_settings_are_refused_with_one_line(settings, lamp, tmp_path,
                                                                   capsys):
    with pytest.raises(InputError) as exc:
        RunConfig(**settings)
    msg = str(exc.value)
    assert "\n" not in msg and "not supported" in msg and supported_text() in msg
    words = [w for k, v in settings.items() for w in (f"--{k}", v)]
    out = tmp_path / "o"
    code, _, err = run_cli(["simulate", str(lamp), *words, "--out", str(out), "--quiet"],
                           capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and "not supported" in lines[0], err
    assert not out.exists()


def test_help_names_the_supported_estimator_settings():
    res = CliRunner().invoke(simulate, ["--help"], terminal_width=10_000,
                             max_content_width=10_000)
    assert supported_text() in " ".join(res.output.split())
