"""Batch meshing on Dask (issue 9): manifests and sweeps, a real ``dask scheduler`` with
two ``dask worker`` processes on 127.0.0.1, a worker killed mid-batch, resume after an
interrupt, failed rows, the per-worker signed-distance cache and ``scale_radius``."""

from __future__ import annotations

import csv
import json
import signal
import socket
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip("distributed", reason="dask[distributed] is not installed")

import vmesh  # noqa: E402
from vmesh import batch  # noqa: E402
from vmesh.cache import PrefixCache  # noqa: E402

from conftest import ROOT, synthetic_case  # noqa: E402

SURFACE, SKELETON = synthetic_case("y_bifurcation")
#: A cheap mesh (about 1 s a row on a warm worker); histograms off.
CHEAP = ["--set", "mesh_transfinite.element_length=0.75", "--set", "compute_quality.histogram=''"]
SCALES = [0.9, 1.0, 1.1]
LAYERS = [0.005, 0.01, 0.02, 0.04]
#: the layers of the sweep batch: three per radius scale, so that 9 rows outnumber the 6
#: signed distances two workers may build (one per worker and scale): the test that rows of
#: one scale share a signed distance can fail
SWEEP_LAYERS = LAYERS[1:]
#: the killed-worker batch's layers: two per scale (6 rows) show the resume as well as 12
KILL_LAYERS = LAYERS[1:3]


# ---------------------------------------------------------------------------
# a real scheduler and two workers on the loopback interface
# ---------------------------------------------------------------------------
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class DaskProcesses:
    """``dask scheduler`` and ``dask worker`` subprocesses on 127.0.0.1 (no nanny, so
    that killing a worker really loses it)."""

    def __init__(self, logs: Path):
        self.logs = logs
        self.port = _free_port()
        self.address = f"tcp://127.0.0.1:{self.port}"
        self.workers: dict[str, subprocess.Popen] = {}
        self.scheduler = self._spawn("scheduler", ["scheduler", "--host", "127.0.0.1", "--port", str(self.port), "--no-dashboard"])
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            if self.scheduler.poll() is not None:
                raise RuntimeError(f"dask scheduler exited: {(logs / 'scheduler.log').read_text()[-2000:]}")
            try:
                socket.create_connection(("127.0.0.1", self.port), timeout=1).close()
                return
            except OSError:
                time.sleep(0.2)
        raise RuntimeError("dask scheduler did not start within 60 s")

    def _spawn(self, name, args):
        log = open(self.logs / f"{name}.log", "ab")
        # ``python -m dask`` is the ``dask`` command, run by this interpreter
        return subprocess.Popen([sys.executable, "-m", "dask", *args], stdout=log, stderr=subprocess.STDOUT, cwd=ROOT)

    def start_worker(self, name: str) -> None:
        self.workers[name] = self._spawn(
            name, ["worker", self.address, "--name", name, "--nthreads", "1", "--no-nanny", "--host", "127.0.0.1", "--no-dashboard", "--death-timeout", "30"]
        )

    def alive(self) -> list[str]:
        return [n for n, p in self.workers.items() if p.poll() is None]

    def ensure_workers(self, names=("w1", "w2"), timeout=60.0) -> None:
        """Start the named workers that are not running and wait until the scheduler has them."""
        for n in names:
            if n not in self.alive():
                self.start_worker(n)
        with distributed.Client(self.address, timeout=30) as client:
            deadline = time.monotonic() + timeout
            while time.monotonic() < deadline:
                have = {w["name"] for w in client.scheduler_info()["workers"].values()}
                if set(names) <= have:
                    return
                time.sleep(0.2)
        raise RuntimeError(f"workers {names} did not connect within {timeout} s")

    def kill_worker(self, name: str) -> None:
        p = self.workers[name]
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=10)

    def close(self) -> None:
        """SIGTERM everything, give it 5 s in all, then SIGKILL what is left."""
        procs = [*self.workers.values(), self.scheduler]
        for p in procs:
            if p.poll() is None:
                p.terminate()
        deadline = time.monotonic() + 5.0
        for p in procs:
            try:
                p.wait(timeout=max(deadline - time.monotonic(), 0.1))
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout=10)


@pytest.fixture(scope="module")
def dask_procs(tmp_path_factory):
    procs = DaskProcesses(tmp_path_factory.mktemp("dask_logs"))
    try:
        procs.ensure_workers(("w1", "w2"))
        yield procs
    finally:
        procs.close()


def vmesh_batch(*args, timeout=180):
    return subprocess.run([sys.executable, "-m", "vmesh", "batch", *map(str, args)], capture_output=True, text=True, timeout=timeout, cwd=ROOT)


def start_batch(*args):
    return subprocess.Popen([sys.executable, "-m", "vmesh", "batch", *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)


@contextmanager
def running_batch(*args):
    """``start_batch(*args)``, killed when the block ends and it still runs."""
    proc = start_batch(*args)
    try:
        yield proc
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(timeout=10)


def wait_for_rows(out: Path, n: int, proc, timeout=90.0) -> list[Path]:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        done = list(out.glob(f"*/{batch.ROW_FILE}"))
        if len(done) >= n:
            return done
        if proc.poll() is not None:
            raise AssertionError(f"batch ended before {n} rows were done: {proc.stderr.read()[-2000:]}")
        time.sleep(0.05)
    raise AssertionError(f"fewer than {n} rows done after {timeout} s")


def sweep_toml(path: Path, layers=SWEEP_LAYERS) -> Path:
    path.write_text(
        f"""
chain = "batch_sweep"

[defaults]
skeleton = "{SKELETON}"

[[sweep]]
name = "y_s{{scale_radius.scale}}_t{{mesh_transfinite.first_layer}}"
surface = "{SURFACE}"

[sweep.product]
scale_radius.scale = {SCALES}
"mesh_transfinite.first_layer" = {layers}
"""
    )
    return path


def sweep_csv(path: Path, extra_rows=(), scales=SCALES, layers=LAYERS) -> Path:
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["name", "surface", "skeleton", "scale_radius.scale", "mesh_transfinite.first_layer"])
        for s in scales:
            for t in layers:
                w.writerow([f"row_s{s}_t{t}", SURFACE, SKELETON, s, t])
        for r in extra_rows:
            w.writerow(r)
    return path


def check_meshes(out: Path, summary: list[dict]) -> None:
    """Every ok row has a valid hexahedral mesh whose numbers match the summary."""
    import pyvista as pv

    for r in summary:
        assert r["status"] == "ok", r
        mesh = pv.read(out / r["name"] / "mesh.vtu")
        assert mesh.n_cells == int(r["elements"]) > 0
        sj = np.asarray(mesh.cell_data["scaled_jacobian"])
        assert sj.min() > 0 and abs(sj.min() - float(r["sj_min"])) < 1e-5 and abs(sj.mean() - float(r["sj_mean"])) < 1e-5
        report = json.loads((out / r["name"] / "report.json").read_text())
        assert report["counts"]["elements"] == int(r["elements"])


# ---------------------------------------------------------------------------
# on a real scheduler
# ---------------------------------------------------------------------------
@pytest.mark.slow
def test_sweep_on_dask_scheduler(dask_procs, tmp_path):
    dask_procs.ensure_workers()
    manifest = sweep_toml(tmp_path / "sweep.toml")
    out = tmp_path / "out"
    r = vmesh_batch(manifest, "--chain", "batch_sweep", "--out", out, "--scheduler", dask_procs.address, "--workers", 2, "--cache-entries", 3, *CHEAP)
    assert r.returncode == 0, r.stderr[-3000:]
    n = len(SCALES) * len(SWEEP_LAYERS)
    assert f"{n} rows: {n} ok, 0 failed" in r.stdout
    summary = batch.read_summary(out / "summary.csv")
    assert [s["name"] for s in summary] == [f"y_s{s:g}_t{t:g}" for s in SCALES for t in SWEEP_LAYERS]
    assert list(summary[0])[: len(batch.SUMMARY_COLUMNS)] == list(batch.SUMMARY_COLUMNS)
    for s in summary:
        assert s["error"] == "" and float(s["seconds"]) > 0 and s["resumed"] == "false" and s["worker"] in ("w1", "w2")
    check_meshes(out, summary)
    assert {s["worker"] for s in summary} == {"w1", "w2"}
    # the radius scale changes the vessel: the (planar) bifurcation's thickness is 2 r
    import pyvista as pv

    for s in summary:
        b = pv.read(out / s["name"] / "mesh.vtu").bounds
        assert (b[5] - b[4]) / 6.0 == pytest.approx(float(s["scale_radius.scale"]), rel=0.02)
    # the boundary-layer thickness changes the mesh: a different mean quality per layer and scale
    for scale in SCALES:
        assert len({s["sj_mean"] for s in summary if float(s["scale_radius.scale"]) == scale}) == len(SWEEP_LAYERS)
    # one signed distance per worker and radius scale (all three fit the cache), not one per row
    built = [s for s in summary if s["sdf_reused"] == "false"]
    assert len(SCALES) <= len(built) <= 2 * len(SCALES) < len(summary)
    assert not (out / batch.STAGING).exists()


@pytest.mark.slow
def test_resume_after_interrupt(dask_procs, tmp_path):
    dask_procs.ensure_workers()
    bad = tmp_path / "corrupt.ply"
    bad.write_text("ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")
    manifest = sweep_csv(tmp_path / "rows.csv", extra_rows=[["broken", bad, SKELETON, 1.0, 0.02]], scales=SCALES[1:], layers=LAYERS)
    out = tmp_path / "out"
    args = (manifest, "--chain", "batch_sweep", "--out", out, "--scheduler", dask_procs.address, *CHEAP)
    with running_batch(*args) as proc:
        wait_for_rows(out, 2, proc)
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err[-2000:]
    interrupted = batch.read_summary(out / "summary.csv")
    assert len(interrupted) == 9 and any(s["status"] == "pending" for s in interrupted)
    time.sleep(0.5)
    finished = {p.parent.name: p.stat().st_mtime_ns for p in out.glob(f"*/{batch.ROW_FILE}")}
    assert 2 <= len(finished) < 8
    contents = {n: (out / n / "mesh.vtu").read_bytes() for n in finished}

    r = vmesh_batch(*args)
    assert r.returncode == 1, r.stderr[-3000:]  # the broken row failed
    summary = {s["name"]: s for s in batch.read_summary(out / "summary.csv")}
    assert len(summary) == 9
    for name, mtime in finished.items():  # finished rows were not recomputed
        assert summary[name]["resumed"] == "true" and summary[name]["attempts"] == "0"
        assert (out / name / batch.ROW_FILE).stat().st_mtime_ns == mtime
        assert (out / name / "mesh.vtu").read_bytes() == contents[name]
    rest = [s for n, s in summary.items() if n not in finished and n != "broken"]
    assert rest and all(s["status"] == "ok" for s in rest)
    assert sum(s["resumed"] == "false" for s in rest) >= 1
    check_meshes(out, [s for n, s in summary.items() if n != "broken"])
    # an unreadable row fails once (session 22: no retry), reported with its error; the others go on
    broken = summary["broken"]
    assert broken["status"] == "failed" and broken["attempts"] == "1" and "corrupt.ply" in broken["error"]
    assert not (out / "broken").exists()
    assert "failed: broken:" in r.stderr


@pytest.mark.slow
def test_worker_killed_mid_batch(dask_procs, tmp_path):
    dask_procs.ensure_workers()
    manifest = sweep_csv(tmp_path / "rows.csv", layers=KILL_LAYERS)
    n = len(SCALES) * len(KILL_LAYERS)
    out = tmp_path / "out"
    with running_batch(manifest, "--chain", "batch_sweep", "--out", out, "--scheduler", dask_procs.address, *CHEAP) as proc:
        wait_for_rows(out, 2, proc)
        dask_procs.kill_worker("w2")
        assert len(list(out.glob(f"*/{batch.ROW_FILE}"))) < n  # really mid-batch
        stdout, err = proc.communicate(timeout=180)
    assert proc.returncode == 0, err[-3000:]
    assert f"{n} rows: {n} ok, 0 failed" in stdout
    summary = batch.read_summary(out / "summary.csv")
    assert len(summary) == n
    check_meshes(out, summary)
    assert dask_procs.alive() == ["w1"]


@pytest.mark.slow
def test_default_local_cluster(tmp_path):
    """Without --scheduler, ``vmesh batch`` starts (and stops) a local cluster."""
    manifest = sweep_csv(tmp_path / "rows.csv", scales=[1.0], layers=LAYERS[:2])
    out = tmp_path / "out"
    r = vmesh_batch(manifest, "--chain", "batch_sweep", "--out", out, "--workers", 1, *CHEAP)
    assert r.returncode == 0, r.stderr[-3000:]
    assert "2 rows: 2 ok, 0 failed" in r.stdout
    summary = batch.read_summary(out / "summary.csv")
    check_meshes(out, summary)
    assert [s["sdf_reused"] for s in summary] == ["false", "true"]  # one worker: one SDF


# ---------------------------------------------------------------------------
# without a cluster
# ---------------------------------------------------------------------------
def test_sweep_syntax(tmp_path):
    m = tmp_path / "m.toml"
    m.write_text(
        f"""
[defaults]
skeleton = "{SKELETON}"
mesh_transfinite.order = 2

[[row]]
name = "single"
surface = "{SURFACE}"

[[sweep]]
surface = "{SURFACE}"
name = "{{stem}}_{{i}}_{{mesh_transfinite.refinement}}"
[sweep.product]
"mesh_transfinite.refinement" = {{ start = 1, stop = 3, step = 1 }}
"mesh_transfinite.first_layer" = {{ start = 0.01, stop = 0.04, num = 4 }}
[sweep.zip]
"mesh_transfinite.elements_ring" = [2, 3]
"mesh_transfinite.elements_layer" = [3, 4]
"""
    )
    man = batch.read_manifest(m)
    assert len(man) == 1 + 2 * 3 * 4
    assert man.rows[0].name == "single" and man.rows[0].overrides == {"mesh_transfinite.order": 2}
    r = man.rows[1]
    assert r.name == "surface_1_1" and r.skeleton == str(SKELETON)
    assert r.overrides == {
        "mesh_transfinite.order": 2,
        "mesh_transfinite.elements_ring": 2,
        "mesh_transfinite.elements_layer": 3,
        "mesh_transfinite.refinement": 1,
        "mesh_transfinite.first_layer": 0.01,
    }
    assert [x.overrides["mesh_transfinite.first_layer"] for x in man.rows[1:5]] == [0.01, 0.02, 0.03, 0.04]
    assert {(x.overrides["mesh_transfinite.elements_ring"], x.overrides["mesh_transfinite.elements_layer"]) for x in man.rows[1:]} == {(2, 3), (3, 4)}
    tasks = batch.prepare(man, "default")
    # keys identify the resolved chain and inputs: "single" equals the sweep row that sets
    # only defaults (ring 2, layer 3, refinement 1, first_layer 0.02)
    assert len({t.key for t in tasks}) == len(tasks) - 1
    twin = next(t for t in tasks[1:] if t.overrides["mesh_transfinite.refinement"] == 1 and t.overrides["mesh_transfinite.first_layer"] == 0.02 and t.overrides["mesh_transfinite.elements_ring"] == 2)
    assert twin.key == tasks[0].key and twin.name != tasks[0].name
    assert batch.sweep_values({"start": 0.001, "stop": 0.1, "num": 3, "log": True}) == [0.001, 0.01, 0.1]


@pytest.mark.parametrize(
    "content, problem",
    [
        (None, "manifest not found"),
        ("skeleton,name\nx.json,a\n", "missing column 'surface'"),
        (f"surface,mesh_transfinite.no_such_param\n{SURFACE},1\n", "column 'mesh_transfinite.no_such_param': filter 'mesh_transfinite' has no parameter"),
        (f"surface,no_such_filter.x\n{SURFACE},\n", "column 'no_such_filter.x': no filter 'no_such_filter'"),
        (f"surface,tag_skeleton.branches\n{SURFACE},true\n", "no filter 'tag_skeleton' in chain 'default' (add a [[step]]"),
        (f"surface,mesh_transfinite.order\n{SURFACE},9\n", "row 1: filter 'mesh_transfinite': parameter 'order' = 9 is above its maximum"),
        ("surface\nnot_there.ply\n", "row 1: surface file not found"),
        (f"name,surface\na,{SURFACE}\na,{SURFACE}\n", "name 'a' is used by row 1 too"),
    ],
)
def test_bad_manifest_one_line_exit_2(tmp_path, capsys, content, problem):
    from vmesh.cli import main

    path = tmp_path / "rows.csv"
    if content is not None:
        path.write_text(content)
    out = tmp_path / "out"
    assert main(["batch", str(path), "--out", str(out), "--workers", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"vmesh: error: {path}: ") and problem in err[0], err
    assert not out.exists()


def test_a_bad_set_value_is_named_as_sets(tmp_path, capsys):
    """``vmesh batch m.csv --set mesh_transfinite.order=two`` was reported as the manifest's
    row 1; it is --set's error (session 19, docs/inputs_and_failures.md)."""
    from vmesh.cli import main

    path = tmp_path / "rows.csv"
    path.write_text(f"surface\n{SURFACE}\n")
    out = tmp_path / "out"
    assert main(["batch", str(path), "--out", str(out), "--workers", "1", "--set", "mesh_transfinite.order=two"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["vmesh: error: --set: filter 'mesh_transfinite': parameter 'order' must be of type int, got str 'two'"]
    assert not out.exists()


def test_sweep_toml_errors(tmp_path):
    m = tmp_path / "m.toml"
    m.write_text(f'[[sweep]]\nsurface = "{SURFACE}"\n[sweep.zip]\n"a.b" = [1, 2]\n"c.d" = [1]\n')
    with pytest.raises(vmesh.InputError, match="zip axes have different lengths"):
        batch.read_manifest(m)
    m.write_text(f'[[sweep]]\nsurface = "{SURFACE}"\nname = "x_{{nope.p}}"\n[sweep.product]\n"a.b" = [1, 2]\n')
    with pytest.raises(vmesh.InputError, match="uses '\\{nope.p\\}'"):
        batch.read_manifest(m)


@pytest.mark.slow
def test_prefix_cache_reuses_the_signed_distance(tmp_path):
    cache = PrefixCache(max_entries=2)
    chain = vmesh.FilterChain.load("batch_sweep").with_overrides({"mesh_transfinite.element_length": 0.75, "compute_quality.histogram": ""})

    def run(name, **over):
        return chain.with_overrides(over).run(surface=SURFACE, skeleton=SKELETON, out_dir=tmp_path / name, cache=cache)

    a = run("a", **{"mesh_transfinite.first_layer": 0.02})
    assert cache.misses == 1 and not any(s.cached for s in a.report.steps)
    b = run("b", **{"mesh_transfinite.first_layer": 0.01})
    cached = [s.filter for s in b.report.steps if s.cached]
    assert cache.hits == 1 and cached == ["scale_radius", "repair_surface", "cap_open_ends", "decimate_surface", "build_sdf"]
    assert b.sdf is a.sdf  # shared, not rebuilt
    assert json.loads((tmp_path / "b" / "report.json").read_text())["steps"][4]["cached"] is True
    c = run("c", **{"mesh_transfinite.first_layer": 0.02})  # same parameters as a: same mesh
    assert np.array_equal(c.mesh.points, a.mesh.points) and c.quality["summary"] == a.quality["summary"]
    d = run("d", **{"scale_radius.scale": 1.1})  # a surface-affecting parameter: its own SDF
    assert cache.misses == 2 and d.sdf is not a.sdf and not any(s.cached for s in d.report.steps)
    # the cache is not changed by later steps
    assert np.array_equal(run("e", **{"mesh_transfinite.first_layer": 0.02}).mesh.points, a.mesh.points)


def test_scale_radius_keeps_the_centerline_and_caps():
    surface, skeleton = vmesh.read_surface(synthetic_case("straight_tube")[0]), vmesh.read_skeleton(synthetic_case("straight_tube")[1])
    ctx = vmesh.FilterChain([("scale_radius", {"scale": 1.25})]).run(surface=surface, skeleton=skeleton)
    v0, v1 = surface.vertices, ctx.surface.vertices
    axis_lo, axis_hi = skeleton.points[skeleton.endpoints].min(axis=0), skeleton.points[skeleton.endpoints].max(axis=0)
    along = int(np.argmax(axis_hi - axis_lo))
    other = [k for k in range(3) if k != along]
    centre = skeleton.points[0, other]
    r0 = np.linalg.norm(v0[:, other] - centre, axis=1)
    r1 = np.linalg.norm(v1[:, other] - centre, axis=1)
    assert np.allclose(r1, 1.25 * r0, atol=1e-6 * r0.max())  # radial distances scale
    assert np.allclose(v1[:, along], v0[:, along], atol=1e-9)  # nothing moves along the axis: caps stay
    assert np.allclose(ctx.skeleton.radii, 1.25 * skeleton.radii) and np.array_equal(ctx.skeleton.points, skeleton.points)
    assert ctx.surface.info().closed and np.array_equal(ctx.surface.faces, surface.faces)
    # scale 1 needs no skeleton and changes nothing
    same = vmesh.FilterChain(["scale_radius"]).run(surface=surface)
    assert np.array_equal(same.surface.vertices, surface.vertices)
    with pytest.raises(vmesh.InputError, match="needs a skeleton"):
        vmesh.FilterChain([("scale_radius", {"scale": 1.1})]).run(surface=surface)


def test_an_unreadable_row_is_not_retried(tmp_path):
    """Session 22: a row whose input cannot be read was retried (``attempts`` 2): the same
    file fails the same way. It fails once with its one-line reason; other failures
    (a meshing error, a lost worker) are still retried."""
    broken = tmp_path / "cut.off"
    broken.write_text("OFF\n40 76 0\n0 0 0\n")  # read with numpy: no VTK import in this fast test
    task = batch.prepare(batch.manifest_from_rows([{"surface": str(broken), "name": "cut"}]), vmesh.FilterChain.load("default"))[0]
    payload = {"name": task.name, "out": str(tmp_path / "out"), "surface": task.row.surface, "skeleton": task.row.skeleton,
               "chain": task.chain_toml, "key": task.key, "overrides": task.overrides}
    res = batch.mesh_row(payload)
    assert res["status"] == "failed" and res["retry"] is False and "cut.off: could not read as OFF: the file ends early" in res["error"] and "\n" not in res["error"]
    assert not batch._retried(res, attempts=1, retries=1)
    assert batch._retried({"status": "failed", "error": "MeshingError: ..."}, attempts=1, retries=1)  # a lost worker's row has no "retry"
    assert not batch._retried({"status": "failed", "retry": True}, attempts=2, retries=1)
    assert "retry" not in batch._summary_row(res, task, attempts=1, resumed=False)


@pytest.mark.slow
def test_python_api_local_cluster(tmp_path):
    """``vmesh.batch.run`` with a client it is given (an in-process cluster: fast to start)."""
    with distributed.Client(processes=False, n_workers=1, threads_per_worker=2, dashboard_address="127.0.0.1:0") as client:
        rows = [{"surface": str(SURFACE), "skeleton": str(SKELETON), "name": f"t{t}", "mesh_transfinite.first_layer": t} for t in (0.01, 0.02)]
        res = batch.run(rows, "default", out=tmp_path / "out", client=client, overrides={"mesh_transfinite.element_length": 0.75, "compute_quality.histogram": ""}, progress=False)
        assert res.n_ok == 2 and res.summary_csv.is_file() and not client.status == "closed"
        again = batch.run(rows, "default", out=tmp_path / "out", client=client, overrides={"mesh_transfinite.element_length": 0.75, "compute_quality.histogram": ""}, progress=False)
        assert again.n_resumed == 2
        # a changed parameter is not a finished row
        changed = batch.run(rows, "default", out=tmp_path / "out", client=client, overrides={"mesh_transfinite.element_length": 0.7, "compute_quality.histogram": ""}, progress=False)
        assert changed.n_resumed == 0 and changed.n_ok == 2


def test_an_unreachable_scheduler_leaves_no_output(tmp_path):
    """Nothing ran: no output folder made for a summary of pending rows (a folder that
    was there keeps its earlier summary)."""
    manifest = [{"surface": str(SURFACE), "skeleton": str(SKELETON), "name": "y"}]
    out = tmp_path / "out"
    with pytest.raises(vmesh.errors.VmeshError, match="cannot reach the Dask scheduler"):
        batch.run(manifest, out=out, scheduler=f"tcp://127.0.0.1:{_free_port()}", connect_timeout=2, progress=False)
    assert not out.exists()
    out.mkdir()
    (out / "summary.csv").write_text("earlier\n")
    with pytest.raises(vmesh.errors.VmeshError, match="cannot reach the Dask scheduler"):
        batch.run(manifest, out=out, scheduler=f"tcp://127.0.0.1:{_free_port()}", connect_timeout=2, progress=False)
    assert (out / "summary.csv").read_text() == "earlier\n"
