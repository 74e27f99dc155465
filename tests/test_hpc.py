"""Clusters: --files-from, --skip-existing (a killed run re-run), --scheduler-file with
external workers whose Taichi pools are capped, SLURM_CPUS_PER_TASK, the SLURMCluster helper."""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from astropy.io import fits

from ipc_taichi.cluster import worker_threads
from ipc_taichi.errors import IPCInputError
from ipc_taichi.hpc import (
    available_cores,
    joining_cap,
    read_file_list,
    slurm_cluster,
    thread_caps,
)
from ipc_taichi.reference import couple_reference, decouple_reference
from tests.helpers import CPU_ENV, optional, run_cli

pytestmark = pytest.mark.filterwarnings(
    "ignore::ResourceWarning", "ignore:Port 8787:UserWarning",
    "ignore:.*clean up.*:UserWarning")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# subprocesses (the CLI, dask scheduler and workers) import this tree's ipc_taichi
ENV = dict(CPU_ENV, PYTHONPATH=ROOT + os.pathsep + CPU_ENV.get("PYTHONPATH", ""))
ENV.pop("IPC_TAICHI_THREADS", None)
ENV.pop("SLURM_CPUS_PER_TASK", None)


def _inputs(folder, n, rng, shape=(12, 14)):
    """``n`` small coupled frames in ``folder`` and their list file."""
    folder.mkdir(exist_ok=True)
    paths = []
    for k in range(n):
        path = folder / f"f{k:04d}.fits"
        fits.writeto(path, couple_reference(rng.uniform(0, 50000, shape)))
        paths.append(str(path))
    listing = folder / "list.txt"
    listing.write_text("# inputs\n\n" + "\n".join(f"  {p}" for p in paths) + "\n")
    return paths, listing


def _stamp(path):
    st = os.stat(path)
    return st.st_ino, st.st_mtime_ns, st.st_size


def test_available_cores_and_default_threads(monkeypatch):
    monkeypatch.setenv("SLURM_CPUS_PER_TASK", "6")
    assert available_cores() == 6
    assert worker_threads(2) == 3 and worker_threads(4) == 1 and worker_threads(12) == 1
    monkeypatch.setenv("SLURM_CPUS_PER_TASK", "x")
    with pytest.raises(IPCInputError, match="SLURM_CPUS_PER_TASK='x'"):
        available_cores()
    monkeypatch.delenv("SLURM_CPUS_PER_TASK")
    assert available_cores() == len(os.sched_getaffinity(0))


def test_thread_caps_share_cpus_per_host():
    eight, low, high = list(range(8)), [0, 1, 2, 3], [4, 5, 6, 7]
    facts = {"a": ("n1", eight, None, None), "b": ("n1", eight, None, None),  # --nworkers 2
             "c": ("n2", low, None, None), "d": ("n2", high, None, None),  # srun-bound tasks
             "e": ("n3", eight, "3", None),  # the user's own cap is kept
             "f": ("n4", eight, None, "2")}  # Slurm gave it fewer CPUs than the mask
    assert thread_caps(facts) == {"a": 4, "b": 4, "c": 4, "d": 4, "e": 3, "f": 2}
    many = {str(k): ("n", [0, 1], None, None) for k in range(5)}
    assert set(thread_caps(many).values()) == {1}


def test_joining_cap(monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 8)
    every = list(range(8))
    assert joining_cap(("n", every, None, None), 4) == 2  # shares the host's CPUs
    assert joining_cap(("n", every, None, None), 16) == 1
    assert joining_cap(("n", [4, 5, 6], None, None), 4) == 3  # bound to its own CPUs
    assert joining_cap(("n", every, "5", None), 4) == 5  # its own setting
    assert joining_cap(("n", every, None, "2"), 1) == 2  # Slurm gave it 2


def test_read_file_list(tmp_path):
    listing = tmp_path / "l.txt"
    listing.write_text("# header\n a.fits \n\n#b.fits\nc d.fits\n")
    assert read_file_list(str(listing)) == ["a.fits", "c d.fits"]
    with pytest.raises(IPCInputError, match=r"^--files-from .*missing.txt: cannot read"):
        read_file_list(str(tmp_path / "missing.txt"))
    (tmp_path / "empty.txt").write_text("# nothing\n")
    with pytest.raises(IPCInputError, match="lists no files"):
        read_file_list(str(tmp_path / "empty.txt"))


def test_cluster_option_errors(cli, tmp_path):
    listing = tmp_path / "l.txt"
    listing.write_text("a.fits\n")
    r = cli("decouple", "--files-from", listing)
    assert r.returncode == 2 and "give -o OUTDIR" in r.stderr
    r = cli("decouple", "--files-from", tmp_path / "nope.txt", "-o", tmp_path)
    assert r.returncode == 2 and "nope.txt: cannot read" in r.stderr
    r = cli("decouple", "a.fits", "-o", tmp_path, "--skip-existing", "--overwrite")
    assert r.returncode == 2 and "give one" in r.stderr
    r = cli("decouple", "a.fits", "-o", tmp_path, "--scheduler", "tcp://x:1",
            "--scheduler-file", listing)
    assert r.returncode == 2 and "either --scheduler" in r.stderr
    r = cli("decouple")
    assert r.returncode == 2 and "--files-from LIST" in r.stderr


def test_skip_existing_only_what_this_tool_decoupled(cli, tmp_path, rng):
    paths, listing = _inputs(tmp_path / "in", 5, rng)
    out = tmp_path / "out"
    out.mkdir()
    done = [out / f"f{k:04d}_decoupled.fits" for k in range(5)]
    for k in (0, 1):  # an earlier run finished these two
        assert cli("decouple", paths[k], done[k], "--quiet").returncode == 0
    before = {k: (_stamp(done[k]), done[k].read_bytes()) for k in (0, 1)}
    fits.writeto(done[2], fits.getdata(paths[2]))  # a file this tool did not write
    fits.writeto(tmp_path / "c.fits", fits.getdata(paths[3]))
    assert cli("couple", tmp_path / "c.fits", done[3]).returncode == 0  # coupled, not decoupled
    r = cli("decouple", "--files-from", listing, "-o", out, "--skip-existing", "--workers", "1")
    assert r.returncode == 1
    assert r.stderr.count("ipc-taichi: skipped") == 2 and "f0000.fits" in r.stderr
    assert f"{done[2]}: exists" in r.stderr and f"{done[3]}: exists" in r.stderr
    assert "2 of 3 files failed" in r.stderr
    for k in (0, 1):  # skipped: not rewritten
        assert (_stamp(done[k]), done[k].read_bytes()) == before[k]
    assert fits.getheader(done[4])["IPCOP"] == "decouple"
    done[2].unlink()
    done[3].unlink()
    r = cli("decouple", "--files-from", listing, "-o", out, "--skip-existing", "--workers", "1")
    assert r.returncode == 0, r.stderr
    assert "decoupled 2 files" in r.stderr and "(3 skipped: already decoupled)" in r.stderr
    for k in range(5):
        ref = decouple_reference(fits.getdata(paths[k]))[0]
        np.testing.assert_allclose(fits.getdata(done[k]), ref, rtol=1e-9)
    # the one-file form too; all skipped: exit 0
    r = cli("decouple", paths[0], done[0], "--skip-existing")
    assert r.returncode == 0 and "skipped" in r.stderr
    r = cli("decouple", "--files-from", listing, "-o", out, "--skip-existing")
    assert r.returncode == 0 and "(5 skipped" in r.stderr
    for k in (0, 1):
        assert (_stamp(done[k]), done[k].read_bytes()) == before[k]


@pytest.mark.slow
def test_killed_half_way_then_skip_existing(tmp_path, rng):
    """A few hundred files, the job killed (SIGKILL, workers and all) half-way, then
    re-run with --skip-existing: every file decoupled once, none rewritten, exit 0."""
    n = 240
    paths, listing = _inputs(tmp_path / "in", n, rng, shape=(8, 9))
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "ipc_taichi.cli", "decouple", "--files-from", str(listing),
           "-o", str(out), "--workers", "2", "--quiet"]
    job = subprocess.Popen(cmd, env=ENV, cwd=ROOT, start_new_session=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 240
    finished = lambda: [f for f in os.listdir(out) if f.endswith("_decoupled.fits")
                        and not f.startswith(".tmp")] if out.is_dir() else []
    while len(finished()) < n // 3 and job.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    os.killpg(job.pid, signal.SIGKILL)
    job.wait()
    first = {f: _stamp(out / f) for f in finished()}  # a killed worker's .tmp-* are not
    assert n // 3 <= len(first) < n, "the job was not stopped half-way"
    r = subprocess.run(cmd[:-1] + ["--skip-existing"], env=ENV, cwd=ROOT, capture_output=True,
                       text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stderr.count("ipc-taichi: skipped") == len(first)
    assert r.stderr.count("ipc-taichi: decoupled") == n - len(first)
    assert f"decoupled {n - len(first)} files" in r.stderr
    assert len(finished()) == n
    assert all(_stamp(out / f) == stamp for f, stamp in first.items())  # none rewritten
    for k in (0, n // 2, n - 1):
        ref = decouple_reference(fits.getdata(paths[k]))[0]
        np.testing.assert_allclose(fits.getdata(out / f"f{k:04d}_decoupled.fits"), ref,
                                   rtol=1e-9)


def _start(args, log):
    return subprocess.Popen([sys.executable, "-m", *args], env=ENV, cwd=ROOT,
                            stdout=log, stderr=subprocess.STDOUT, start_new_session=True)


@pytest.mark.slow
def test_scheduler_file_two_external_workers_capped(tmp_path, rng):
    from distributed import Client

    from ipc_taichi.hpc import worker_facts
    from ipc_taichi.workers import taichi_threads

    paths, listing = _inputs(tmp_path / "in", 12, rng)
    sched = tmp_path / "scheduler.json"
    log = open(tmp_path / "dask.log", "w")  # noqa: SIM115 (closed below)
    procs = [_start(["distributed.cli.dask_scheduler", "--scheduler-file", str(sched),
                     "--no-dashboard", "--host", "127.0.0.1"], log)]
    try:
        deadline = time.time() + 60
        while not sched.exists() and time.time() < deadline:
            time.sleep(0.1)
        for _ in range(2):  # started by the user: no IPC_TAICHI_THREADS in their environment
            procs.append(_start(["distributed.cli.dask_worker", "--scheduler-file", str(sched),
                                 "--nthreads", "1", "--no-dashboard"], log))
        with Client(scheduler_file=str(sched), timeout=60) as client:
            client.wait_for_workers(2, timeout=60)
            assert all(v is None for v in client.run(taichi_threads).values())
            expected = thread_caps(client.run(worker_facts))
        out = tmp_path / "out"
        half = tmp_path / "half.txt"
        half.write_text("\n".join(paths[:5]) + "\n")
        r = run_cli("decouple", "--files-from", half, "-o", out, "--scheduler-file", sched,
                    "--quiet", env=ENV)
        assert r.returncode == 0, r.stderr
        first = {f: _stamp(out / f) for f in os.listdir(out)}
        r = run_cli("decouple", "--files-from", listing, "-o", out, "--scheduler-file", sched,
                    "--skip-existing", env=ENV)
        assert r.returncode == 0, r.stderr
        assert r.stderr.count("ipc-taichi: skipped") == 5 and "decoupled 7 files" in r.stderr
        assert all(_stamp(out / f) == s for f, s in first.items())
        assert len(os.listdir(out)) == 12
        with Client(scheduler_file=str(sched), timeout=60) as client:
            caps = client.run(taichi_threads)
        assert len(caps) == 2 and caps == expected
        # capped: the workers of this host share its CPUs instead of each taking all
        cpus = len(os.sched_getaffinity(0))
        assert all(c == max(1, cpus // 2) for c in caps.values())
        # a worker that joins now is capped by the plugin, counting the host's 3 workers
        procs.append(_start(["distributed.cli.dask_worker", "--scheduler-file", str(sched),
                             "--nthreads", "1", "--no-dashboard"], log))
        with Client(scheduler_file=str(sched), timeout=60) as client:
            client.wait_for_workers(3, timeout=60)
            now = client.run(lambda: os.environ.get("IPC_TAICHI_THREADS"))
            late = set(now) - set(caps)
            assert len(late) == 1
            assert now[late.pop()] == str(max(1, cpus // 3))
    finally:
        for p in reversed(procs):
            os.killpg(p.pid, signal.SIGTERM)
        for p in procs:
            p.wait(timeout=30)
        log.close()


def test_slurm_cluster_job_script():
    pytest.importorskip("dask_jobqueue", reason=optional("dask_jobqueue"))
    cluster = slurm_cluster(cpus=16, memory="64GB", processes=4, walltime="02:00:00",
                            queue="normal", account="nircam")
    try:
        script = cluster.job_script()
    finally:
        cluster.close()
    lines = script.splitlines()
    assert "#SBATCH --cpus-per-task=16" in lines
    assert "#SBATCH -p normal" in lines and "#SBATCH -A nircam" in lines
    assert "#SBATCH -t 02:00:00" in lines
    assert any(line.startswith("#SBATCH --mem=") for line in lines)
    assert "export IPC_TAICHI_THREADS=4" in lines  # 16 CPUs shared by 4 workers
    command = lines[-1]
    assert sys.executable in command and "distributed.cli.dask_worker" in command
    assert "--nthreads 1" in command and "--nworkers 4" in command
    with pytest.raises(IPCInputError, match="processes"):
        slurm_cluster(cpus=2, memory="1GB", processes=3)
