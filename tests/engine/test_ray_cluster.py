"""Ray clusters as Ray sets them up: token authentication, every CPU used, a second Ray
on the machine, a lost worker node and a lost head — on real Ray nodes started with
``ray start`` inside a loopback-only network namespace (tests/netns.py).
"""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np
import pytest

from lightsim.engine.ray_backend import RayCluster, actor_count
from lightsim.io.exr import read_exr
from lightsim.luminaires.gltf_writer import GltfMaterial, GltfPart, write_glb
from lightsim.validation.scenes import primitives as prim

from netns import run_in_netns

pytestmark = pytest.mark.ray

PORT = 6393
COMMON = ("--photons 160000 --frame-photons 20000 -M 2 --wall-distance 2 --wall-size 4x4 "
          "--resolution 32x32 --quiet")
RAY = (shutil.which("ray", path=str(Path(sys.executable).parent))
       or f'{sys.executable} -c "from ray.scripts.scripts import main; main()"')
HEAD = (f"{RAY} start --head --port={PORT} --num-cpus=1 --include-dashboard=false "
        "--disable-usage-stats >> $T/ray.log 2>&1 || exit 20")
# the worker node's processes are those `ray start` leaves running as daemons; they and
# everything they start are the node (the head's workers are the head raylet's children)
WORKER = f"""
before=$(ps -eo pid= | sort)
# a joining node does not pick up the token by itself: Ray wants the mode said (the head
# turns it on where a token exists; the driver, lightsim, picks it up as address="auto")
[ -f "$HOME/.ray/auth_token" ] && export_mode="RAY_AUTH_MODE=token" || export_mode=
env $export_mode {RAY} start --address=127.0.0.1:{PORT} --num-cpus=1 >> $T/ray.log 2>&1 || exit 21
for p in $(comm -13 <(echo "$before") <(ps -eo pid= | sort)); do
    [ "$(ps -o ppid= -p $p 2>/dev/null | tr -d ' ')" = 1 ] && echo $p
done > "$T/node_pids"
"""
STOP = f"trap '{RAY} stop --force >/dev/null 2>&1 || true' EXIT"

# the fault, injected into the real `lightsim simulate` command: after the given frame,
# SIGKILL the listed processes and every descendant of theirs
FAULT_SCRIPT = """
import os, signal, sys
from pathlib import Path
import lightsim.cli.simulate as command

after, pid_file = int(sys.argv[1]), Path(sys.argv[2])
real = command.run_simulation

def tree(roots):
    children = {}
    for st in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = st.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        children.setdefault(int(fields[1]), []).append(int(st.parent.name))
    out, todo = [], list(roots)
    while todo:
        p = todo.pop()
        out.append(p)
        todo.extend(children.get(p, []))
    return out

def run_simulation(opts, *, progress=None, **kw):
    frames = [0]
    def on_frame(est):
        frames[0] += 1
        if frames[0] == after:
            roots = [int(p) for p in pid_file.read_text().split()]
            for p in tree(roots):
                try:
                    os.kill(p, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            print(f"KILLED {len(roots)} after frame {after}", file=sys.stderr, flush=True)
        if progress is not None:
            progress(est)
    return real(opts, progress=on_frame, **kw)

command.run_simulation = run_simulation
from lightsim.cli.main import main
main(sys.argv[3:])
"""


def _lamp(path: Path) -> Path:
    """A point source in a metal paraboloid, as a GLB (the loader adds the wall)."""
    mirror = prim.paraboloid(0.5, 0.6, 0.9, radial=24, azimuthal=96)
    src = prim.point_source(1000.0, radius=1e-3, centre=(0, 0, 0.5))
    write_glb(path, [
        GltfPart(src.name, src.vertices, src.faces, src.normals,
                 GltfMaterial("f", emissive=(1, 1, 1)),
                 extras={"lightsim": {"flux_lm": src.flux_lm}}),
        GltfPart(mirror.name, mirror.vertices, mirror.faces, mirror.normals,
                 GltfMaterial("m", base_color=(0.9, 0.9, 0.9), metallic=1.0))])
    return path


def _lux(out: Path) -> np.ndarray:
    return read_exr(out / "wall_lux.exr")[0]["Y"]


@pytest.fixture
def ray_tmp():
    """A private, short RAY_TMPDIR (Ray's socket paths must stay under 108 bytes)."""
    path = Path(tempfile.mkdtemp(prefix="lsray", dir="/tmp"))
    yield path
    shutil.rmtree(path, ignore_errors=True)


def _setup(tmp_path: Path, ray_tmp: Path) -> tuple[str, str]:
    """(environment lines, simulate command) for a namespace script."""
    lamp = _lamp(tmp_path / "lamp.glb")
    (tmp_path / "home").mkdir()
    env = (f"set -u\nT={tmp_path}\nexport HOME=$T/home RAY_TMPDIR={ray_tmp}\n{STOP}\n")
    return env, f"{sys.executable} -m lightsim.cli.main simulate {lamp} {COMMON}"


def _lines(text: str) -> list[str]:
    return [ln for ln in text.splitlines() if ln.strip()]


def test_token_cluster_wrong_token_and_address_fail_fast(tmp_path, ray_tmp):
    """A head started the default way with a token on the machine has token
    authentication on; a wrong token, no token, a wrong address: one line each, named."""
    env, sim = _setup(tmp_path, ray_tmp)
    fast = sim.replace("--photons 160000", "--photons 20000")
    script = env + f"""
        {RAY} get-auth-token --generate >/dev/null 2>&1
        {HEAD}
        for case in wrong none address; do
            t0=$(date +%s%N)
            case $case in
              wrong) RAY_AUTH_TOKEN=0123456789abcdef0123456789abcdef \
                     {fast} --address 127.0.0.1:{PORT} --out $T/o 2> $T/err_$case ;;
              none) HOME=$T {fast} --address 127.0.0.1:{PORT} --out $T/o 2> $T/err_$case ;;
              address) {fast} --address 127.0.0.1:{PORT + 1} --out $T/o 2> $T/err_$case ;;
            esac
            rc=$?; echo "RC $case $rc $(( ($(date +%s%N) - t0) / 1000000 ))"
        done
    """
    res = run_in_netns(textwrap.dedent(script), timeout=300, env={"RAY_AUTH_MODE": None})
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    rc = {ln.split()[1]: (int(ln.split()[2]), float(ln.split()[3]))
          for ln in res.stdout.splitlines() if ln.startswith("RC ")}
    expect = {"wrong": f"the Ray cluster at 127.0.0.1:{PORT} refused this machine's token "
                       "(wrong token)",
              "none": f"the Ray cluster at 127.0.0.1:{PORT} requires an authentication "
                      "token and this machine has none",
              "address": f"cannot reach a Ray cluster at 127.0.0.1:{PORT + 1}: Connection "
                         "refused (wrong address?"}
    for case, text in expect.items():
        err = _lines((tmp_path / f"err_{case}").read_text())
        assert rc[case][0] == 2 and len(err) == 1 and text in err[0], (case, rc, err)
        assert "RAY_AUTH_TOKEN" in err[0] or case == "address"
        # Ray's own connect would wait 20 s and then name a connection failure
        assert rc[case][1] < 15_000, (case, rc[case])  # ms
    assert not (tmp_path / "o").exists()


@pytest.mark.slow
def test_token_cluster_two_nodes_every_cpu(tmp_path, ray_tmp):
    """Token authentication on (Ray's default once a token exists), two nodes; `--address`
    alone runs one actor per CPU, spread over both nodes, and the map is bit for bit the
    local one at the same -M; with more CPUs than sets a note says how to raise -M."""
    env, sim = _setup(tmp_path, ray_tmp)
    script = env + f"""
        {RAY} get-auth-token --generate >/dev/null 2>&1
        {HEAD}
        {WORKER}
        {sim} --address 127.0.0.1:{PORT} --out $T/a 2> $T/err_a || exit 11
        {sim.replace("-M 2", "-M 1")} --address 127.0.0.1:{PORT} --out $T/m1 2> $T/err_m1 \
            || exit 12
        {sim} --out $T/b || exit 13
    """
    res = run_in_netns(textwrap.dedent(script), timeout=600, env={"RAY_AUTH_MODE": None})
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    cluster = json.loads((tmp_path / "a" / "summary.json").read_text())["cluster"]
    assert cluster["nodes"] == 2 and cluster["cpus"] == 2, cluster
    assert cluster["actors"] == 2 and cluster["actors_per_node"] == [1, 1], cluster
    a, b = _lux(tmp_path / "a"), _lux(tmp_path / "b")
    assert a.max() > 0 and np.array_equal(a, b)
    assert _lines((tmp_path / "err_a").read_text()) == []
    note = _lines((tmp_path / "err_m1").read_text())
    assert len(note) == 1, note
    assert "-M 1 gives 1 interleave set, one actor each at most: 1 run" in note[0], note
    assert "-M 2 (4 sets) would use them all" in note[0], note
    m1 = json.loads((tmp_path / "m1" / "summary.json").read_text())
    assert m1["cluster"]["actors"] == 1 and m1["config"]["interleave"] == 1


@pytest.mark.slow
def test_workers_beside_a_running_cluster(tmp_path, ray_tmp):
    """`ray start --head` on the machine, then `--workers 2`: a private Ray instance runs
    the actors (`ray.init()` would join the head and refuse the CPU count)."""
    env, sim = _setup(tmp_path, ray_tmp)
    script = env + f"""
        {HEAD}
        {sim} --workers 2 --out $T/w 2> $T/err_w || exit 11
        {RAY} status >/dev/null 2>&1 && echo HEAD_STILL_UP
        {sim} --out $T/b || exit 13
    """
    res = run_in_netns(textwrap.dedent(script), timeout=600, env={"RAY_AUTH_MODE": None})
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    assert "HEAD_STILL_UP" in res.stdout
    cluster = json.loads((tmp_path / "w" / "summary.json").read_text())["cluster"]
    assert cluster["address"] == "local" and cluster["actors"] == 2, cluster
    assert np.array_equal(_lux(tmp_path / "w"), _lux(tmp_path / "b"))


@pytest.mark.slow
def test_lost_worker_node_mid_run(tmp_path, ray_tmp):
    """SIGKILL every process of the worker node after the second of eight frames: the
    run finishes on the head, its actor's sets replayed, bit for bit the fault-free map."""
    env, sim = _setup(tmp_path, ray_tmp)
    fault = tmp_path / "fault.py"
    fault.write_text(FAULT_SCRIPT)
    sim_args = sim.split(" -m lightsim.cli.main ", 1)[1]
    script = env + f"""
        {HEAD}
        {WORKER}
        {sys.executable} {fault} 2 $T/node_pids {sim_args} --address 127.0.0.1:{PORT} \
            --out $T/f 2> $T/err_f || {{ cat $T/err_f >&2; exit 11; }}
        {sim} --out $T/b || exit 13
    """
    res = run_in_netns(textwrap.dedent(script), timeout=900)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    err = (tmp_path / "err_f").read_text()
    assert "KILLED" in err and "Traceback" not in err, err
    cluster = json.loads((tmp_path / "f" / "summary.json").read_text())["cluster"]
    assert cluster["actors_per_node_at_start"] == [1, 1], cluster
    assert cluster["restarts"] >= 1 and cluster["actors_per_node"] == [2], cluster
    f, b = _lux(tmp_path / "f"), _lux(tmp_path / "b")
    assert f.max() > 0 and np.array_equal(f, b)


@pytest.mark.slow
def test_lost_head_checkpoint_and_resume(tmp_path, ray_tmp):
    """SIGKILL the head node's processes after the second frame: one line naming it and
    a checkpoint; `--resume` with the head back ends with the fault-free map."""
    env, sim = _setup(tmp_path, ray_tmp)
    fault = tmp_path / "fault.py"
    fault.write_text(FAULT_SCRIPT)
    sim_args = sim.split(" -m lightsim.cli.main ", 1)[1]
    script = env + f"""
        before=$(ps -eo pid= | sort)
        {HEAD}
        for p in $(comm -13 <(echo "$before") <(ps -eo pid= | sort)); do
            [ "$(ps -o ppid= -p $p 2>/dev/null | tr -d ' ')" = 1 ] && echo $p
        done > $T/head_pids
        timeout 300 {sys.executable} {fault} 2 $T/head_pids {sim_args} \
            --address 127.0.0.1:{PORT} --out $T/h 2> $T/err_h
        echo "RC $?"
        [ -f $T/h/checkpoint.json ] && [ ! -f $T/h/summary.json ] && echo CHECKPOINTED
        {HEAD}
        {sys.executable} -m lightsim.cli.main simulate --resume $T/h --quiet 2> $T/err_r \
            || {{ cat $T/err_r >&2; exit 12; }}
        {sim} --out $T/b || exit 13
    """
    res = run_in_netns(textwrap.dedent(script), timeout=900)
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    assert "RC 2" in res.stdout, res.stdout + (tmp_path / "err_h").read_text()
    err = [ln for ln in _lines((tmp_path / "err_h").read_text()) if "KILLED" not in ln]
    assert len(err) == 1 and "lost the Ray cluster's head node" in err[0], err
    assert "lightsim simulate --resume" in err[0]
    assert "CHECKPOINTED" in res.stdout
    assert np.array_equal(_lux(tmp_path / "h"), _lux(tmp_path / "b"))
    assert not (tmp_path / "h" / "checkpoint.json").exists()


def test_actor_count_uses_every_cpu_up_to_the_sets():
    cluster = RayCluster("head:6379", cpus=20, nodes=3, started=False)
    n, notes = actor_count(cluster, 0, 16)
    assert n == 16 and len(notes) == 1
    assert "its 20 CPUs" in notes[0] and "-M 4 gives 16 interleave sets" in notes[0]
    assert "-M 5 (25 sets) would use them all" in notes[0]
    assert actor_count(RayCluster("h:1", 8, 2, False), 0, 16) == (8, [])
    assert actor_count(RayCluster("h:1", 8, 2, False), 3, 16) == (3, [])
    n, notes = actor_count(RayCluster(None, 2, 1, True), 5, 4)
    assert n == 4 and "--workers 5" in notes[0] and "this run" in notes[0]
    assert actor_count(RayCluster("h:1", 0, 1, False), 0, 16) == (1, [])
