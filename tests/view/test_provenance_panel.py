"""The view's provenance panel (lightsim.view.provenance_panel) in a real browser: a
click and a drag on the screen show the region's path classes — the same table
``lightsim report --provenance-box`` computes — and the lamp picture; bad boxes and the
access token on its routes."""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from lightsim.cli.main import main
from lightsim.luminaires.provenance_report import (
    REGIONS_FILE,
    read_regions,
    region_breakdown,
    region_overview,
    region_picture,
)
from lightsim.view.provenance_panel import serve_provenance

from support import browser_page

LOWBEAM = Path(__file__).resolve().parents[2] / "luminaires" / "examples" / "lowbeam.glb"


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("prov") / "run"
    with pytest.raises(SystemExit) as exc:
        main(["simulate", str(LOWBEAM), "--photons", "80000", "--regulation",
              "r112-b-passing", "--provenance", "--resolution", "160x64", "--outputs",
              "json", "--out", str(out), "--quiet"])
    assert exc.value.code == 0
    assert (out / REGIONS_FILE).exists()
    return out


@pytest.fixture()
def server(run_dir):
    store = read_regions(run_dir / REGIONS_FILE)
    srv = serve_provenance({**region_overview(store), "run": run_dir.name},
                           lambda box: region_breakdown(run_dir, box, store=store),
                           lambda box: region_picture(run_dir, region_breakdown(
                               run_dir, box, store=store), store))
    yield srv
    srv.stop()


def _get(server, path: str) -> tuple[int, bytes]:
    req = urllib.request.Request(server.url.replace("/?", f"/{path}&"
                                                    if "?" in path else f"/{path}?"))
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return r.status, r.read()
    except urllib.error.HTTPError as exc:
        return exc.code, exc.read()


def test_routes_and_bad_boxes(server, run_dir):
    code, body = _get(server, "breakdown?box=-8,-1,0.5,2")
    assert code == 200
    got = json.loads(body)
    want = region_breakdown(run_dir, (-8, -1, 0.5, 2))
    assert [c["class"] for c in got["classes"]] == [c["class"] for c in want["classes"]]
    assert got["value_lx"] == pytest.approx(want["value_lx"], rel=1e-12)
    code, body = _get(server, "lamp.png?box=-8,-1,0.5,2")
    assert code == 200 and body[:8] == b"\x89PNG\r\n\x1a\n"
    for box, why in (("1,0,0,1", "region box"), ("a,b", "box must be"),
                     ("70,80,0,1", "holds no cell"), ("", "box must be")):
        code, body = _get(server, f"breakdown?box={box}")
        assert code == 400 and why in json.loads(body)["text"], body
        assert "\n" not in json.loads(body)["text"]


def test_panel_needs_the_access_token(server):
    base = f"http://127.0.0.1:{server.port}"
    for path in ("/screen", "/breakdown?box=-1,1,-1,1", "/lamp.png?box=-1,1,-1,1"):
        with pytest.raises(urllib.error.HTTPError) as exc:
            urllib.request.urlopen(base + path, timeout=30)
        assert exc.value.code == 403


@pytest.mark.timeout(180)
def test_click_and_drag_show_the_breakdown_in_the_browser(server, run_dir):
    with browser_page(server.url, (1400, 900)) as (page, errors):
        page.wait_for_function("window.prov.ready", timeout=60_000)
        screen = page.evaluate("window.prov.screen")
        he, ve = screen["h_edges_deg"], screen["v_edges_deg"]
        box = page.locator("#screen").bounding_box()

        def at(h, v):  # page position of the screen point (h, v) in degrees
            c = sum(1 for x in he[1:-1] if x <= h)
            r = sum(1 for x in ve[1:-1] if x >= v)
            return (box["x"] + (c + 0.5) / (len(he) - 1) * box["width"],
                    box["y"] + (r + 0.5) / (len(ve) - 1) * box["height"])

        def rows():
            return page.eval_on_selector_all(
                "#classes tr.class-row", "rs => rs.map(r => Array.from(r.cells).map("
                "c => c.textContent))")

        # a click: the cell under it
        page.mouse.click(*at(-2.0, 0.6))
        page.wait_for_function("window.prov.breakdowns >= 1 && window.prov.lamps >= 1",
                               timeout=60_000)
        clicked = page.evaluate("window.prov.last")
        h0, h1, v0, v1 = clicked["covered_deg"]
        assert h0 <= -2.0 <= h1 and v0 <= 0.6 <= v1
        c = sum(1 for x in he[1:-1] if x <= -2.0)
        assert (h0, h1) == pytest.approx((he[c], he[c + 1]))  # the one cell under it
        table = rows()
        want = region_breakdown(run_dir, tuple(float(x) for x in
                                               page.evaluate("window.prov.box").split(",")))
        assert [r[0].split(" (")[0] if r[0].startswith("other") else r[0] for r in table] == [
            c["class"] if c["class"] != "other" else "other" for c in want["classes"]]
        assert sum(float(r[3].rstrip(" %")) for r in table) == pytest.approx(100, abs=0.5)
        # a drag: the box of cells from press to release
        x0, y0 = at(-8.0, 2.0)
        x1, y1 = at(-1.0, 0.5)
        page.mouse.move(x0, y0)
        page.mouse.down()
        page.mouse.move(x1, y1, steps=6)
        page.mouse.up()
        page.wait_for_function("window.prov.breakdowns >= 2 && window.prov.lamps >= 2",
                               timeout=60_000)
        dragged = page.evaluate("window.prov.last")
        h0, h1, v0, v1 = dragged["covered_deg"]
        assert h0 <= -8.0 and h1 >= -1.0 and v0 <= 0.5 and v1 >= 2.0
        want = region_breakdown(run_dir, (h0 + 1e-6, h1 - 1e-6, v0 + 1e-6, v1 - 1e-6))
        assert dragged["value_lx"] == pytest.approx(want["value_lx"], rel=1e-12)
        lo, hi = dragged["interval_lx"]
        assert lo <= dragged["sum_lx"] <= hi
        assert len(rows()) == len(want["classes"]) >= 2
        title = page.text_content("#title")
        assert "lx" in title and "classes add up to" in title
        assert page.evaluate("document.getElementById('lamp').naturalWidth") > 200
        assert errors == []
