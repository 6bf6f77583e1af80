"""The view's ADB panel (lightsim.view.adb_panel) in a real browser: a segment toggle and a
dimming slider are re-composed and drawn (the composed map is the weighted sum of the
per-source maps, bit for bit), dragging the road user brings a new mask; and the /mask
route's bad input."""

from __future__ import annotations

import json
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from lightsim.luminaires.adb import panel_solver
from lightsim.persource import compose, read_per_source
from lightsim.simulate import SimulateOptions, run_simulation
from lightsim.view.adb_panel import maps_payload, serve_adb

from support import browser_page

MATRIX = Path(__file__).resolve().parents[2] / "luminaires" / "examples" / "matrix.glb"


@pytest.fixture(scope="module")
def maps(tmp_path_factory):
    out = tmp_path_factory.mktemp("panel") / "run"
    run_simulation(SimulateOptions(scene_path=str(MATRIX), photons=60_000, out_dir=str(out),
                                   resolution=(96, 40), per_source=True, outputs=("json",)))
    return read_per_source(out)


@pytest.fixture()
def server(maps):
    srv = serve_adb(maps, panel_solver(maps))
    yield srv
    srv.stop()


def test_maps_payload_round_trips(maps):
    data = maps_payload(maps)
    n = int.from_bytes(data[:4], "little")
    head = json.loads(data[4:4 + n])
    assert head["names"] == list(maps.names) and (head["width"], head["height"]) == (96, 40)
    lux = np.frombuffer(data[4 + n:], "<f4").reshape(maps.lux.shape)
    assert np.array_equal(lux, maps.lux)


def _post(server, body: bytes) -> tuple[int, dict]:
    req = urllib.request.Request(server.url.replace("/?", "/mask?"), data=body,
                                 headers={"content-type": "application/json",
                                          "host": f"127.0.0.1:{server.port}"})
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


def test_mask_route(server, maps):
    code, res = _post(server, json.dumps({"vehicles": [{"kind": "oncoming", "distance_m": 50,
                                                        "h_deg": -3.0}]}).encode())
    assert code == 200 and len(res["levels_list"]) == 16
    assert all(p["verdict"] in ("pass", "undecided") for p in res["positions"])
    for body, why in ((b"not json", "not a mask request"),
                      (b'{"vehicles": [{"kind": "oncoming", "distance_m": -5, "h_deg": 0}]}',
                       "behind the lamp"),
                      (b'{"vehicles": [], "fixed": {"led_99": 0}}', "no emitter group"),
                      (b'{"vehicles": [], "fixed": {"led_01": 2}}', "from 0 to 1")):
        code, res = _post(server, body)
        assert code == 400 and why in res["text"]


@pytest.mark.timeout(180)
def test_toggle_and_drag_recompose_in_the_browser(server, maps):
    with browser_page(server.url, (1300, 800)) as (page, errors):
        page.wait_for_function("window.adb.ready && window.adb.masks >= 1", timeout=60_000)

        def state():
            return page.evaluate("""() => ({redraws: window.adb.redraws,
                masks: window.adb.masks, ms: window.adb.lastRedrawMs,
                levels: Array.from(window.adb.composedLevels),
                composed: Array.from(window.adb.composed)})""")

        before = state()
        page.click("#seg-led_12")  # off: re-composed and drawn without the server
        page.wait_for_function(f"window.adb.redraws > {before['redraws']}", timeout=10_000)
        after = state()
        k = list(maps.names).index("led_12")
        assert after["levels"][k] == 0.0
        expect = compose(maps.lux, np.array(after["levels"], np.float32)).ravel()
        assert np.array_equal(np.array(after["composed"], np.float32), expect)
        assert not np.array_equal(np.array(after["composed"], np.float32),
                                  np.array(before["composed"], np.float32))
        print(f"toggle drawn {after['ms']:.1f} ms after the click")  # reported, not asserted
        # drag the road user across the screen: a new mask from the server, composed again
        box = page.locator("#map").bounding_box()
        y = box["y"] + 0.45 * box["height"]
        masks = page.evaluate("window.adb.masks")
        page.mouse.move(box["x"] + 0.30 * box["width"], y)
        page.mouse.down()
        page.mouse.move(box["x"] + 0.60 * box["width"], y, steps=5)
        page.mouse.up()
        page.wait_for_function(f"window.adb.masks > {masks}", timeout=30_000)
        page.wait_for_timeout(300)
        dragged = state()
        got = np.array(dragged["composed"], np.float32)
        assert np.array_equal(got, compose(maps.lux, np.array(dragged["levels"],
                                                              np.float32)).ravel())
        assert dragged["levels"][k] == 0.0  # the toggle holds through new masks
        assert errors == []


@pytest.mark.timeout(180)
def test_dimming_slider_recomposes_with_its_level(server, maps):
    """A slider held at 0.35 re-composes at once with that weight (before the server
    answers), goes to the server as a fixed level, and a double-click gives the segment
    back to the mask."""
    k = list(maps.names).index("led_07")
    with browser_page(server.url, (1300, 800)) as (page, errors):
        page.wait_for_function("window.adb.ready && window.adb.masks >= 1", timeout=60_000)

        def state():
            return page.evaluate("""() => ({redraws: window.adb.redraws,
                masks: window.adb.masks,
                levels: Array.from(window.adb.composedLevels),
                composed: Array.from(window.adb.composed),
                mask: window.adb.lastMask.levels_list})""")

        before = state()
        assert before["levels"][k] > 0.5  # the road user at 3° L leaves led_07 lit
        page.locator("#dim-led_07").fill("0.35")
        page.wait_for_function(f"window.adb.redraws > {before['redraws']}", timeout=10_000)
        after = state()
        assert after["levels"][k] == np.float32(0.35)
        composed = np.array(after["composed"], np.float32)
        assert np.array_equal(composed, compose(maps.lux, np.array(after["levels"],
                                                                   np.float32)).ravel())
        assert not np.array_equal(composed, np.array(before["composed"], np.float32))
        # the map moved by the change of the weighted sum (a mask may have come meanwhile)
        delta = composed.astype(np.float64) - np.array(before["composed"], np.float64)
        dw = np.array(after["levels"], np.float64) - np.array(before["levels"], np.float64)
        np.testing.assert_allclose(delta, np.tensordot(dw, maps.lux.astype(np.float64), 1)
                                   .ravel(), atol=1e-5 * float(maps.lux.max()) * 16)
        page.wait_for_function(  # the server's answer with the segment fixed
            f"Math.abs(window.adb.lastMask.levels_list[{k}] - 0.35) < 1e-9", timeout=30_000)
        page.wait_for_timeout(300)
        held = state()
        assert held["mask"][k] == pytest.approx(0.35)  # the server kept it fixed
        assert held["levels"][k] == np.float32(0.35)
        assert page.locator("#seg-led_07").get_attribute("class") == "held"
        # a double-click gives the segment back to the mask
        masks = held["masks"]
        page.locator("#dim-led_07").dblclick()
        page.wait_for_function(
            f"window.adb.masks > {masks} && !window.adb.held.has('led_07') && "
            f"window.adb.composedLevels[{k}] === "
            f"Math.fround(window.adb.lastMask.levels_list[{k}])", timeout=30_000)
        page.wait_for_timeout(300)
        released = state()
        assert page.locator("#seg-led_07").get_attribute("class") == ""
        assert released["levels"][k] == np.float32(released["mask"][k])
        assert np.array_equal(np.array(released["composed"], np.float32),
                              compose(maps.lux, np.array(released["levels"],
                                                         np.float32)).ravel())
        assert errors == []


def test_panel_needs_the_access_token(server):
    base = f"http://127.0.0.1:{server.port}"
    for path in ("/maps", "/mask"):
        req = urllib.request.Request(base + path, data=b"{}" if path == "/mask" else None)
        with pytest.raises(urllib.error.HTTPError) as exc:
            urllib.request.urlopen(req, timeout=30)
        assert exc.value.code == 403
    with urllib.request.urlopen(server.url.replace("/?", "/maps?"), timeout=30) as r:
        assert r.status == 200
