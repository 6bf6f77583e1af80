"""Plots for a colleague: labels that never overlap, one iso-lux plot per rule set, the
log wall map, the fitted road view and the caption every plot carries."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.image import imread
from matplotlib.text import Text
from test_plots import FRAME, beam, check_png, wall_from_intensity

from lightsim.io import plots as plots_mod
from lightsim.io.errorplot import error_vs_time_plot
from lightsim.io.plots import (
    PlotCaption,
    isolux_plot,
    place_labels,
    road_view_plot,
    wall_lux_plot,
)
from lightsim.luminaires.regulations import evaluate, load_ruleset, probe_points, sample_wall
from lightsim.render.road import road_illuminance
from lightsim.report import engineering_plots, isolux_file, plot_caption

CAPTION = PlotCaption("lowbeam.glb", 7, 1_000_000, "3.1% (noise 2.0%, blur 2.4%)",
                      (("r112-b-passing", "01 series"), ("r149-b-passing", "00 series")),
                      "9.9.9")


def _results(name: str, lux) -> list[dict]:
    rs = load_ruleset(name)
    pr = probe_points(rs, frame=FRAME)
    vals = sample_wall(lux, FRAME, pr.h_deg, pr.v_deg) * np.ones((9, 1))
    return evaluate(rs, pr, vals)


def _text_box(t, r):
    """The drawn text's box (an annotation's own extent includes its leader line)."""
    return Text.get_window_extent(t, r).shrunk(0.98, 0.98)


def _overlaps(texts) -> list[tuple[str, str]]:
    fig = texts[0].figure
    r = fig.canvas.get_renderer()
    boxes = [(t.get_text(), _text_box(t, r)) for t in texts]
    return [(a, b) for i, (a, ba) in enumerate(boxes) for b, bb in boxes[i + 1:]
            if ba.overlaps(bb)]


def test_crowded_labels_do_not_overlap_and_get_leaders():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 3))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.set_xlim(-10, 10)
    ax.set_ylim(-4, 4)
    rng = np.random.default_rng(3)
    # fifteen points within half a degree of each other, plus coincident ones
    pts = [(f"P{i}", *rng.normal(0.0, 0.3, 2), "k") for i in range(15)]
    pts += [("same-a", 2.0, 1.0, "r"), ("same-b", 2.0, 1.0, "g")]
    texts = place_labels(ax, pts)
    fig.draw_without_rendering()
    assert len(texts) == len(pts) and not _overlaps(texts)
    assert any(t.arrow_patch is not None for t in texts)  # leader lines where crowded
    # no label covers a point
    r = fig.canvas.get_renderer()
    for t in texts:
        bb = _text_box(t, r)
        for _, x, y, _ in pts:
            px, py = ax.transData.transform((x, y))
            assert not bb.contains(px, py)
    assert place_labels(ax, []) == []  # nothing to label


def test_isolux_labels_drawn_do_not_overlap(tmp_path, monkeypatch):
    lux = wall_from_intensity(beam)
    drawn = []

    def spy(*args, **kwargs):
        out = place_labels(*args, **kwargs)
        drawn.extend(out)
        return out

    monkeypatch.setattr(plots_mod, "place_labels", spy)
    for name in ("r112-b-passing", "r149-b-passing"):
        drawn.clear()
        results = _results(name, lux)
        check_png(isolux_plot(tmp_path / f"{name}.png", lux, FRAME, results,
                              caption=CAPTION.for_ruleset(0)))
        names = {t.get_text() for t in drawn}
        assert {"50R", "75R", "B50L"} <= names
        assert not _overlaps(drawn), name


def test_one_isolux_plot_per_rule_set(tmp_path):
    lux = wall_from_intensity(beam)
    summary = {"scene": {"source": "/x/lowbeam.glb"}, "seed": 3, "photons": 1000,
               "error_text": "5%", "lightsim_version": "9.9.9",
               "wall": FRAME, "regulation": {}, "regulation:r149-b-passing": {}}
    for key, name in (("regulation", "r112-b-passing"),
                      ("regulation:r149-b-passing", "r149-b-passing")):
        summary[key] = {"ruleset": name, "version": f"v-{name}", "title": name,
                        "results": _results(name, lux)}
    paths = engineering_plots(tmp_path, lux, FRAME, None, summary=summary,
                              which=("wall_lux", "isolux", "road"))
    names = sorted(p.name for p in paths)
    assert names == ["isolux-r149-b-passing.png", "isolux.png", "road.png", "wall_lux.png"]
    for p in paths:
        check_png(p)
    assert summary["isolux"]["files"] == {"r112-b-passing": "isolux.png",
                                          "r149-b-passing": "isolux-r149-b-passing.png"}
    assert isolux_file(0, "a") == "isolux.png" and isolux_file(2, "b") == "isolux-b.png"
    cap = plot_caption(summary)
    assert cap.lamp == "lowbeam.glb" and cap.seed == 3 and cap.photons == 1000
    assert cap.rulesets == (("r112-b-passing", "v-r112-b-passing"),
                            ("r149-b-passing", "v-r149-b-passing"))
    assert cap.for_ruleset(1).rulesets == (("r149-b-passing", "v-r149-b-passing"),)
    # without a rule set: one plot, nothing marked
    (tmp_path / "n").mkdir()
    assert [p.name for p in engineering_plots(tmp_path / "n", lux, FRAME, None,
                                              which=("isolux",))] == ["isolux.png"]


def test_caption_says_what_a_colleague_needs():
    text = CAPTION.text()
    for part in ("lowbeam.glb", "seed 7", "1,000,000 photons", "3.1%", "r112-b-passing",
                 "01 series", "r149-b-passing", "lightsim 9.9.9"):
        assert part in text
    assert PlotCaption.from_any(None) is None
    from dataclasses import asdict

    assert PlotCaption.from_any(asdict(CAPTION)) == CAPTION  # as the plot process gets it
    assert "no rule set" in PlotCaption("a", 1, 1).text()


def test_wall_lux_log_by_default_shows_the_spill(tmp_path):
    lux = wall_from_intensity(beam)
    results = _results("r112-b-passing", lux)
    log_img = check_png(wall_lux_plot(tmp_path / "log.png", lux, FRAME, results,
                                      caption=CAPTION))
    lin_img = check_png(wall_lux_plot(tmp_path / "lin.png", lux, FRAME, results, log=False))

    def lit_share(img):  # share of clearly non-black pixels (inferno's floor is black)
        return float(np.mean(img[..., :3].max(axis=2) > 0.35))

    # the 200 cd spill is ~1 % of the maximum: dark on a linear scale, lit on a log one
    assert lit_share(log_img) > lit_share(lin_img) + 0.15
    # degenerate input gives the placeholder, not a traceback
    check_png(wall_lux_plot(tmp_path / "z.png", np.zeros((110, 300)), FRAME))


def test_road_view_is_fitted_to_the_lit_area(tmp_path):
    lux = wall_from_intensity(beam)
    road = road_illuminance(lux, FRAME, 0.65, (-15.0, 15.0), (0.0, 100.0), 0.25)
    reach = road.reach_m(1.0)
    x0, x1, far = road.lit_box_m(1.0, 0.15)
    assert far == pytest.approx(min(5.0 * np.ceil(reach * 1.15 / 5.0), 100.0))
    assert far % 5 == 0 and far >= reach and x0 == -x1 and x1 % 2 == 0
    lit = np.nan_to_num(road.lux) >= 1.0
    assert np.abs(road.x_m[lit.any(axis=0)]).max() <= x1
    assert road.lit_box_m(1e9) is None  # nothing lit: the whole grid is shown
    drawn = road_view_plot(tmp_path / "road.png", lux, FRAME, caption=CAPTION)
    img = imread(tmp_path / "road.png")
    assert drawn.summary()["reach_m"]["1"] == pytest.approx(reach)
    assert img.shape[0] > img.shape[1]  # a view down the road, not a square of grey


def test_error_plot_carries_the_caption(tmp_path):
    log = [{"seconds": 1.0 * k, "photons": 1000 * k, "rel_error": 0.1 / np.sqrt(k)}
           for k in range(1, 6)]
    error_vs_time_plot(tmp_path / "e.png", log, caption=CAPTION.text())
    error_vs_time_plot(tmp_path / "f.png", log)
    a, b = imread(tmp_path / "e.png"), imread(tmp_path / "f.png")
    assert a.shape[0] > b.shape[0]  # room made for the caption lines
