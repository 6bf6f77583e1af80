"""A disk that fills while a run writes its outputs, and an output folder that is read-only.

Both on a real small tmpfs mounted in a private mount namespace (``unshare --mount``):
nothing outside the test sees it, and it goes when the namespace ends. Without the
permission for that the tests are skipped with the reason.
"""

from __future__ import annotations

import errno
import json
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from lightsim import simulate
from lightsim.errors import LightsimError
from lightsim.simulate import SimulateOptions, write_failure

from support import write_point_lamp

COMMON = ("--photons 20000 --wall-distance 2 --wall-size 4x4 --resolution 32x32 --quiet")


def _run_in_mount_ns(script: str, timeout: float = 300) -> subprocess.CompletedProcess:
    if shutil.which("unshare") is None:
        pytest.skip("unshare(1) not available: no private mount namespace for a small disk")
    probe = subprocess.run(["unshare", "--mount", "--propagation", "private", "true"],
                           capture_output=True, timeout=20)
    if probe.returncode != 0:
        pytest.skip("no permission for a private mount namespace (unshare --mount): "
                    + probe.stderr.decode(errors="replace").strip())
    return subprocess.run(["unshare", "--mount", "--propagation", "private", "bash", "-c",
                           script], capture_output=True, text=True, timeout=timeout)


def _result(res: subprocess.CompletedProcess) -> dict:
    line = next((ln for ln in res.stdout.splitlines() if ln.startswith("RESULT ")), None)
    assert line is not None, res.stdout[-2000:] + res.stderr[-3000:]
    return json.loads(line[len("RESULT "):])


def test_full_disk_keeps_the_previous_set_or_nothing(tmp_path):
    lamp = write_point_lamp(tmp_path / "lamp.glb")
    disk = tmp_path / "disk"
    disk.mkdir()
    sim = f"{sys.executable} -m lightsim.cli.main simulate {lamp} {COMMON}"
    check = tmp_path / "check.py"
    check.write_text(textwrap.dedent(f"""
        import hashlib, json, os, sys
        from pathlib import Path
        disk = Path("{disk}")
        def digest(d):
            return {{p.name: hashlib.sha256(p.read_bytes()).hexdigest()
                     for p in sorted(Path(d).iterdir()) if p.is_file()}}
        before, after = json.load(open(sys.argv[1])), digest(disk / "run")
        print("RESULT " + json.dumps({{
            "same": before == after, "files": sorted(after),
            "left": sorted(p.name for p in (disk / "run").iterdir() if p.name.startswith(".")),
            "fresh": sorted(os.listdir(disk)),
            "err2": open(sys.argv[2]).read(), "err3": open(sys.argv[3]).read(),
            "rc2": int(sys.argv[4]), "rc3": int(sys.argv[5])}}))
    """))
    digest = ("import hashlib, json, sys; from pathlib import Path; "
              "print(json.dumps({p.name: hashlib.sha256(p.read_bytes()).hexdigest() "
              "for p in sorted(Path(sys.argv[1]).iterdir()) if p.is_file()}))")
    script = f"""
        set -u
        mount -t tmpfs -o size=1m tmpfs {disk}
        {sim} --out {disk}/run || exit 11
        {sys.executable} -c '{digest}' {disk}/run > {tmp_path}/before.json
        # fill the disk, then give back 40 kB: the next set (≈ 200 kB) cannot fit
        dd if=/dev/zero of={disk}/filler bs=4k 2>/dev/null
        truncate -s -40k {disk}/filler
        {sim} --out {disk}/run --seed 7 2> {tmp_path}/err2; rc2=$?
        {sim} --out {disk}/fresh 2> {tmp_path}/err3; rc3=$?
        rm {disk}/filler
        {sys.executable} {check} {tmp_path}/before.json {tmp_path}/err2 {tmp_path}/err3 \
            $rc2 $rc3
        umount {disk}
    """
    res = _run_in_mount_ns(textwrap.dedent(script))
    assert res.returncode == 0, res.stdout[-2000:] + res.stderr[-3000:]
    out = _result(res)
    # a run into a folder holding a complete set: that set is kept, bit for bit
    assert out["rc2"] == 2, out
    err2 = [ln for ln in out["err2"].splitlines() if ln.strip() and "warning" not in ln]
    assert len(err2) == 1 and "no space left on the device" in err2[0], err2
    assert "previous complete set of outputs there is kept" in err2[0], err2
    assert out["same"] and "summary.json" in out["files"], out
    assert out["left"] == [], "no staging folder or temporary file may be left behind"
    # a run into a new folder: nothing at all is left, not even the folder
    assert out["rc3"] == 2, out
    err3 = [ln for ln in out["err3"].splitlines() if ln.strip() and "warning" not in ln]
    assert len(err3) == 1 and "nothing was written there" in err3[0], err3
    assert "Traceback" not in out["err2"] + out["err3"]
    assert "fresh" not in out["fresh"], out["fresh"]


def test_read_only_out_fails_before_any_photon(tmp_path):
    lamp = write_point_lamp(tmp_path / "lamp.glb")
    disk = tmp_path / "ro"
    disk.mkdir()
    # a time budget of an hour: only a check before the run can end this in seconds
    sim = (f"{sys.executable} -m lightsim.cli.main simulate {lamp} --time 3600 "
           "--wall-distance 2 --wall-size 4x4 --resolution 32x32 --quiet")
    script = f"""
        mount -t tmpfs -o size=1m tmpfs {disk}
        mkdir {disk}/existing
        mount -o remount,ro {disk}
        {sim} --out {disk}/existing; echo "RC1 $?"
        {sim} --out {disk}/new/deeper; echo "RC2 $?"
        ls -A {disk}; echo END
        umount {disk}
    """
    res = _run_in_mount_ns(textwrap.dedent(script), timeout=120)
    assert "RC1 2" in res.stdout and "RC2 2" in res.stdout, res.stdout + res.stderr[-3000:]
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert len(lines) == 2, lines  # one line per run
    assert f"output directory {disk}/existing is not writable (Read-only file system)" \
        in lines[0], lines
    assert f"{disk}/new/deeper is not writable" in lines[1], lines
    listing = res.stdout.split("RC2 2", 1)[1].split("END")[0].split()
    assert listing == ["existing"], listing


def test_write_failure_names_what_is_left(tmp_path):
    full = OSError(errno.ENOSPC, "No space left on device")
    assert "nothing was written" in write_failure(tmp_path, full, had_set=False)
    (tmp_path / "summary.json").write_text("{}")
    msg = write_failure(tmp_path, full, had_set=True)
    assert "no space left" in msg and "kept, unchanged" in msg
    (tmp_path / "summary.json").unlink()
    assert "incomplete" in write_failure(tmp_path, OSError(errno.EROFS, "x"), had_set=True)
    assert Path(tmp_path).is_dir()


def test_checkpoint_on_a_full_disk_is_one_line(tmp_path, monkeypatch):
    def full(path, obj, **kw):
        raise OSError(errno.ENOSPC, "No space left on device", str(path))

    class Session:
        def checkpoint(self):
            return {"frames": 1}

    monkeypatch.setattr(simulate, "write_json", full)
    with pytest.raises(LightsimError) as exc:
        simulate.write_checkpoint(tmp_path, SimulateOptions(scene_path="lamp.glb"), Session())
    msg = str(exc.value)
    assert msg == (f"could not write the checkpoint to {tmp_path}: no space left on the "
                   "device: the run cannot be resumed (free space and run again)"), msg
