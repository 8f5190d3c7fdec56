"""`jiggle batch`: jobs from a folder or a manifest, bad input as one line with exit code 2, and on a
LocalCluster of 2 single-threaded worker processes (one for the module) over 3 short CMU clips on
CesiumMan: every job baked, equal bit for bit to the same bakes run one after another in this process,
a broken clip failing alone (exit code 1), --resume running only what is missing, and a worker killed
mid-job: the job is run again elsewhere, goes on from its last chunk and equals an unbroken bake.
"""
import json
import os
import signal
import time

import numpy as np
import pytest
from conftest import asset

from jiggle.sim.app import batch
from jiggle.sim.app.cli import main
from jiggle.sim.bake.baker import PAUSE_ENV, chunk_path
from jiggle.sim.bake.setup import BakeRequest

CLIPS = ("02_03", "05_02", "09_11")
SETTINGS = dict(end=0.5, chunk=4, formats=("npz",))          # 16 frames in 4 chunks: a few seconds a job


def run(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def cesium():
    return str(asset("characters/CesiumMan.glb"))


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    """A folder of the 3 clips (links to the shared assets) and a broken BVH."""
    folder = tmp_path_factory.mktemp("library")
    for c in CLIPS:
        os.symlink(asset(f"mocap/cmu_bvh/{c}.bvh"), folder / f"{c}.bvh")
    (folder / "broken.bvh").write_text("HIERARCHY\nROOT hips\n{ garbage\n")
    return folder


@pytest.fixture(scope="module")
def client():
    distributed = pytest.importorskip("distributed")
    import logging
    cluster = distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                                       dashboard_address="127.0.0.1:0", silence_logs=logging.ERROR)
    c = distributed.Client(cluster)
    yield c
    c.close()
    cluster.close()


@pytest.fixture(scope="module")
def serial(library, cesium, tmp_path_factory):
    """clip -> (bake.npz arrays, key) of the same bake run here, alone, without any rig cache: lazily."""
    from jiggle.sim.bake.baker import bake
    from jiggle.sim.bake.setup import prepare
    done = {}

    def get(clip):
        if clip not in done:
            out = tmp_path_factory.mktemp(f"serial_{clip}")
            setup = prepare(BakeRequest(clip=str(library / f"{clip}.bvh"), character=cesium, **SETTINGS))
            bake(setup, out)
            with np.load(out / "bake.npz") as z:
                done[clip] = ({k: z[k] for k in z.files}, setup.key)
        return done[clip]
    return get


def assert_same_bake(path, reference):
    arrays, _ = reference
    with np.load(path) as z:
        assert sorted(z.files) == sorted(arrays)
        for k in z.files:
            assert np.array_equal(z[k], arrays[k]), k          # bit for bit (dtype and every value)


# ---------------------------------------------------------------------------------------- jobs, bad input
def test_folder_jobs_one_per_clip_and_per_gltf_animation(tmp_path, cesium):
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "walk.bvh").write_text("x")
    (tmp_path / "b").mkdir()
    (tmp_path / "b" / "walk.bvh").write_text("x")
    (tmp_path / "run.amc").write_text("x")
    (tmp_path / "01.asf").write_text("x")                     # a skeleton, not a clip
    os.symlink(cesium, tmp_path / "cesium.glb")                 # one animation: one job
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "old.bvh").write_text("x")              # the output folder is left out
    jobs = batch.find_jobs(str(tmp_path), BakeRequest(end=1.0), str(tmp_path / "out"))
    names = [j.name for j in jobs]
    assert sorted(names) == ["b__walk", "cesium", "run", "walk"], names     # a/walk.bvh came first
    glb = next(j for j in jobs if j.name == "cesium")
    assert glb.request.animation == 0 and glb.request.end == 1.0 and glb.request.clip.endswith("cesium.glb")


def test_manifest_jobs_override_the_command_line(tmp_path):
    (tmp_path / "c.bvh").write_text("x")
    (tmp_path / "m.toml").write_text('[[job]]\nclip = "c.bvh"\n\n[[job]]\nclip = "c.bvh"\nname = "soft"\n'
                                     'jiggle = 0.3\nend = 2\ntemplate = "human"\nactivation = "off"\n')
    jobs = batch.manifest_jobs(str(tmp_path / "m.toml"), BakeRequest(jiggle=0.9, end=1.0, fps=24.0,
                                                                     activation="on"))
    assert [j.name for j in jobs] == ["c", "soft"]
    assert (jobs[0].request.activation, jobs[1].request.activation) == ("on", "off")   # --activation, the job's
    assert (jobs[0].request.jiggle, jobs[0].request.end) == (0.9, 1.0)
    assert (jobs[1].request.jiggle, jobs[1].request.end, jobs[1].request.fps) == (0.3, 2.0, 24.0)
    assert jobs[1].request.template == "human" and jobs[1].request.clip == str(tmp_path / "c.bvh")


@pytest.mark.parametrize("text, where", [
    ('[[job]]\nclip = "c.bvh"\n\n[[job]]\nclip = "c.bvh"\nfps = -3\n', "m.toml:6: job 2: fps: must be a positive"),
    ('[[job]]\nclip = "c.bvh"\nspeed = 2\n', "m.toml:3: job 1: speed: unknown key"),
    ('[[job]]\nclip = "missing.bvh"\n', "m.toml:2: job 1: clip: file not found"),
    ('[[job]]\nname = "x"\n', "m.toml:1: job 1: no clip"),
    ('[[job]]\nclip = "c.bvh\n', "m.toml:2: not valid TOML"),
    ('[[job]]\nclip = "c.bvh"\njiggle = "lots"\n', "m.toml:3: job 1: jiggle: expected a number"),
    ('[[job]]\nclip = "c.bvh"\nactivation = "yes"\n', 'm.toml:3: job 1: activation: must be "on" or "off"'),
])
def test_bad_manifest_is_one_line_with_its_line_and_exit_2(capsys, tmp_path, text, where):
    (tmp_path / "c.bvh").write_text("x")
    (tmp_path / "m.toml").write_text(text)
    code, out, err = run(capsys, "batch", tmp_path / "m.toml", "--out", tmp_path / "out")
    assert code == 2 and where in err and len(err.strip().splitlines()) == 1, err


def test_bad_command_line_is_exit_2(capsys, tmp_path):
    code, _, err = run(capsys, "batch", tmp_path / "nothing", "--out", tmp_path / "out")
    assert code == 2 and "no such folder or manifest" in err
    (tmp_path / "empty").mkdir()
    code, _, err = run(capsys, "batch", tmp_path / "empty", "--out", tmp_path / "out")
    assert code == 2 and "no clips here" in err
    (tmp_path / "c.bvh").write_text("x")
    code, _, err = run(capsys, "batch", tmp_path, "--out", tmp_path / "out", "--scheduler", "tcp://127.0.0.1:1",
                       "--workers", "2")
    assert code == 2 and "--workers" in err and "Traceback" not in err
    with pytest.raises(SystemExit) as e:
        main(["batch", str(tmp_path), "--out", str(tmp_path / "out"), "--workers", "0"])
    assert e.value.code == 2


def test_index_rows_link_the_report_and_the_peak_thumbnail(tmp_path):
    jobs = [batch.Job("walk", BakeRequest(), "walk.bvh"), batch.Job("bad", BakeRequest(), "bad.bvh"),
            batch.Job("later", BakeRequest(), "later.bvh")]
    records = {"walk": {"name": "walk", "source": "walk.bvh", "status": "ok", "frames": 16, "time_s": 3.5,
                        "peak_skin_mm": 20.4, "peak_muscle": "belly_fat", "peak_muscle_mm": 57.3,
                        "quality": {"torn_edges": {"value": 1, "limit": 0, "pass": False}},
                        "files": {"peak": "walk/peak.png", "report": "walk/report.html"}},
               "bad": {"name": "bad", "source": "bad.bvh", "status": "failed", "error": "bad.bvh:3: <oops>"}}
    doc = batch.write_index(str(tmp_path), jobs, records)
    assert doc["totals"] == {"jobs": 3, "ok": 1, "failed": 1, "pending": 1, "frames": 16}
    assert json.loads((tmp_path / "index.json").read_text())["jobs"][2]["status"] == "pending"
    page = (tmp_path / "index.html").read_text()
    assert 'src="walk/peak.png"' in page and 'href="walk/report.html"' in page
    assert "&lt;oops&gt;" in page and "<oops>" not in page            # escaped
    assert page.count('th data-k="n"') >= 8 and "addEventListener('click'" in page   # sortable columns


# ---------------------------------------------------------------------------------------- on a cluster
@pytest.mark.slow
def test_batch_bakes_the_library_equal_to_serial_bakes_and_a_broken_clip_fails_alone(
        capsys, library, cesium, client, serial, tmp_path):
    out = tmp_path / "lib"
    argv = ["batch", library, "--out", out, "--scheduler", client.scheduler.address, "--character", cesium,
            "--end", "0.5", "--chunk", "4", "--formats", "npz", "--no-render"]
    code, stdout, err = run(capsys, *argv)
    assert code == 1, err
    assert "3 of 4 jobs baked (48 frames), 1 failed:" in stdout and "broken: " in stdout
    index = json.loads((out / "index.json").read_text())
    rows = {r["name"]: r for r in index["jobs"]}
    assert rows["broken"]["status"] == "failed" and "broken.bvh:3" in rows["broken"]["error"]
    for c in CLIPS:
        r = rows[c]
        assert r["status"] == "ok" and r["frames"] == 16 and r["peak_skin_mm"] > 0, r
        assert set(r["quality"]) >= {"final_folded_edges", "torn_edges"} and r["files"]["report"] == f"{c}/report.html"
        # the tissue law's measures reach the index: share of muscle-frames near the reach, its muscle, hard stops
        assert 0.0 <= r["near_limit_pct"] <= 100.0 and r["near_limit_muscle"] and r["hard_stops"] == 0, r
        ref = serial(c)
        assert r["key"] == ref[1]
        assert_same_bake(out / c / "bake.npz", ref)
    # two workers, three jobs on one character: at least one job found its rig fitted already
    assert sum(rows[c]["rig_reused"] for c in CLIPS) >= 1
    assert (out / "index.html").is_file()

    # --resume after losing a job's bake: only that job runs again
    os.remove(out / "05_02" / "bake.json")
    code, stdout, err = run(capsys, *argv, "--resume")
    assert code == 1 and "resuming: 2 of 4 jobs finished earlier, 2 to run" in err, err
    rows = {r["name"]: r for r in json.loads((out / "index.json").read_text())["jobs"]}
    assert rows["02_03"].get("kept") and rows["09_11"].get("kept") and not rows["05_02"].get("kept")
    assert rows["05_02"]["status"] == "ok"
    assert_same_bake(out / "05_02" / "bake.npz", serial("05_02"))


@pytest.mark.slow
def test_a_worker_killed_mid_job_is_replaced_and_the_job_resumes(library, cesium, client, serial, tmp_path):
    job = batch.Job("02_03", BakeRequest(clip=str(library / "02_03.bvh"), character=cesium, **SETTINGS), "02_03.bvh")
    client.run(lambda: os.environ.__setitem__(PAUSE_ENV, "1.5"))        # time to kill between chunks
    try:
        fut = client.submit(batch.run_job, job, str(tmp_path), "none", pure=False, key="jiggle-kill-test")
        deadline = time.monotonic() + 120
        while not os.path.isfile(chunk_path(str(tmp_path / "02_03"), 0)):
            assert time.monotonic() < deadline and not fut.done(), "the bake did not start"
            time.sleep(0.1)
        where = [w for w, keys in client.processing().items() if "jiggle-kill-test" in keys]
        assert len(where) == 1
        pid = client.run(os.getpid, workers=where)[where[0]]
        os.kill(pid, signal.SIGKILL)
        rec = fut.result(timeout=300)
    finally:
        client.run(lambda: os.environ.pop(PAUSE_ENV, None))
    assert rec["status"] == "ok", rec
    assert rec["pid"] != pid and rec["resumed_after_chunks"] >= 1, rec
    assert_same_bake(tmp_path / "02_03" / "bake.npz", serial("02_03"))
