"""Issue 27 item 6: a run you can see and that starts at once.

``ipc-taichi --help`` imports no command's libraries, ``import ipc_taichi``
loads its names on first use, Taichi's offline cache is on and outside the
repository, a Ctrl-C while the libraries load ends in one line and code 130,
and one large product shows a bar of frames (or iterations) on a terminal only.
"""

import os
import pathlib
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from astropy.io import fits

import ipc_taichi
from ipc_taichi import progress
from ipc_taichi.reference import couple_reference

ROOT = pathlib.Path(__file__).resolve().parent.parent
ENV = dict(os.environ, IPC_TAICHI_ARCH="cpu", IPC_TAICHI_PRECISION="f64")
INTERRUPTED = "ipc-taichi: interrupted; unfinished outputs removed"
HEAVY = ("numpy", "taichi", "astropy", "scipy", "dask", "matplotlib", "tqdm", "photutils")


def _loaded_after(code):
    """The heavy libraries loaded after ``code`` runs in a fresh process."""
    probe = (f"import sys\n{code}\n"
             f"print('loaded:' + ','.join(m for m in {HEAVY!r} if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                       timeout=120, env=ENV, cwd=ROOT)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip().splitlines()[-1].removeprefix("loaded:")


def test_help_imports_no_library():
    code = ("from ipc_taichi.cli import main\ntry:\n    main(['--help'])\n"
            "except SystemExit as exc:\n    assert exc.code == 0")
    assert _loaded_after(code) == ""


def test_a_command_builds_only_its_own_options():
    code = ("from ipc_taichi.cli import build_parser\nbuild_parser(['calibrate'])\n"
            "assert 'ipc_taichi.cli.calibrate' in sys.modules\n"
            "assert not {'ipc_taichi.cli.bench', 'ipc_taichi.cli.discover', "
            "'ipc_taichi.cli.frames', 'ipc_taichi.cli.demo'} & set(sys.modules)")
    assert "scipy" not in _loaded_after(code)


def test_a_decouple_loads_only_what_it_needs(tmp_path, rng):
    """Issue 39: parsing a decouple's options starts no Taichi, and the run loads
    NumPy, astropy and Taichi only (no SciPy, Dask, Matplotlib, tqdm, photutils):
    the guard of the lazy imports on the path a one-file job takes (not timed)."""
    src = tmp_path / "in.fits"
    fits.writeto(src, couple_reference(rng.uniform(0, 5000, (16, 16))))
    argv = ["decouple", str(src), str(tmp_path / "out.fits"), "--quiet"]
    code = ("from ipc_taichi.cli import build_parser, main\n"
            f"build_parser(['decouple']).parse_args({argv!r})\n"
            f"assert not {{'taichi', 'scipy', 'dask', 'matplotlib', 'tqdm'}} & set(sys.modules)\n"
            f"assert main({argv!r}) == 0")
    assert _loaded_after(code) == "numpy,taichi,astropy"
    assert (tmp_path / "out.fits").exists()


def test_every_command_is_listed_and_built_from_one_table(capsys):
    from ipc_taichi.cli import build_parser
    from ipc_taichi.cli.commands import COMMANDS

    full = build_parser()
    listed = build_parser(())
    for parser in (full, listed):
        sub = next(a for a in parser._actions if a.dest == "command")
        assert list(sub.choices) == list(COMMANDS)
    with pytest.raises(SystemExit):
        listed.parse_args(["--help"])
    text = capsys.readouterr().out
    assert all(name in text for name in COMMANDS)
    assert "apply IPC to a signal product (forward model): IN -> OUT" in text


def test_the_package_loads_its_names_on_first_use():
    assert _loaded_after("import ipc_taichi") == ""
    assert "numpy" in _loaded_after("import ipc_taichi\nipc_taichi.couple")
    assert ipc_taichi.decouple.__module__ == "ipc_taichi.decoupling"
    # a submodule named as an attribute is imported then, and is that module (this
    # process imported it long ago: asked in a fresh one)
    code = ("assert 'ipc_taichi.runtime' not in sys.modules\n"
            "assert ipc_taichi.runtime is sys.modules['ipc_taichi.runtime']\n"
            "assert ipc_taichi.runtime.current.__module__ == 'ipc_taichi.runtime'\n"
            # every public name resolves (a name that is neither defined nor in a
            # module of the lazy table raises), to one of this package's objects
            "for name in ipc_taichi.__all__:\n"
            "    value = getattr(ipc_taichi, name)\n"
            "    assert getattr(value, '__module__', 'ipc_taichi').startswith('ipc_taichi'), name")
    _loaded_after(f"import ipc_taichi\n{code}")  # fails on a failed assertion in it
    with pytest.raises(AttributeError, match="module 'ipc_taichi' has no attribute 'nope'"):
        getattr(ipc_taichi, "nope")  # noqa: B009


def test_offline_cache_on_in_the_users_cache(cpu):
    import taichi as ti

    cfg = ti.lang.impl.current_cfg()
    assert cfg.offline_cache
    path = pathlib.Path(cfg.offline_cache_file_path).resolve()
    assert ROOT not in path.parents and pathlib.Path.cwd().resolve() not in path.parents


# --- Ctrl-C during start-up ---------------------------------------------------------------


def test_interrupt_while_a_command_loads(cli, monkeypatch):
    """A KeyboardInterrupt raised while a command's modules are imported."""
    class Interrupting:
        def find_spec(self, name, path=None, target=None):
            if name == "ipc_taichi.cli.bench":
                raise KeyboardInterrupt
            return None

    monkeypatch.delitem(sys.modules, "ipc_taichi.cli.bench", raising=False)
    monkeypatch.setattr(sys, "meta_path", [Interrupting(), *sys.meta_path])
    r = cli("bench", "--sizes", "8")
    assert r.returncode == 130
    assert r.stderr == INTERRUPTED + "\n"


def test_interrupt_a_library_swallowed_ends_as_interrupted(cli, monkeypatch):
    from ipc_taichi.cli import demo
    from ipc_taichi.interrupts import request_stop

    def swallowed(args):  # the signal handler recorded it, a library ate the exception
        request_stop(KeyboardInterrupt())
        return 0

    monkeypatch.setattr(demo, "run", swallowed)
    r = cli("demo", "--size", "8")
    assert (r.returncode, r.stderr) == (130, INTERRUPTED + "\n")


def _mapped(pid, name):
    try:
        with open(f"/proc/{pid}/maps") as f:
            return name in f.read()
    except OSError:
        return False


@pytest.mark.skipif(not os.path.exists("/proc/self/maps"), reason="needs /proc")
def test_sigint_early_in_start_up_says_one_line(tmp_path, rng):
    """SIGINT sent while the process imports NumPy (before Taichi is loaded)."""
    src = tmp_path / "in.fits"
    fits.writeto(src, couple_reference(rng.uniform(0, 5000, (16, 16))))
    proc = subprocess.Popen([sys.executable, "-m", "ipc_taichi.cli", "decouple", src,
                             tmp_path / "out.fits"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=ENV)
    deadline = time.time() + 60
    while not _mapped(proc.pid, "_multiarray_umath") and time.time() < deadline:
        time.sleep(0.002)
    early = not _mapped(proc.pid, "taichi_python")
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert early, "Taichi was already loaded: not start-up any more"
    assert proc.returncode == 130, err
    assert err == INTERRUPTED + "\n"
    assert sorted(os.listdir(tmp_path)) == ["in.fits"]


# --- progress on a terminal ---------------------------------------------------------------


@pytest.fixture
def terminal(monkeypatch):
    """stderr is a terminal; bars are drawn at once."""
    monkeypatch.setattr(progress, "DELAY", 0.0)

    def on():
        monkeypatch.setattr(sys.stderr, "isatty", lambda: True)
    return on


def _ramp(tmp_path, rng, frames=4, size=24):
    path = tmp_path / "ramp.fits"
    truth = np.cumsum(rng.uniform(0, 3000, (frames, size, size)), axis=0)
    fits.writeto(path, np.stack([couple_reference(f) for f in truth]))
    return path


def test_a_ramp_shows_each_frame_on_a_terminal(cli, tmp_path, rng, terminal):
    src = _ramp(tmp_path, rng)
    terminal()
    r = cli("decouple", src, tmp_path / "out.fits")
    assert r.returncode == 0, r.stderr
    for k in range(1, 5):
        assert f"{k}/4 [" in r.stderr, r.stderr
    assert "5/4" not in r.stderr and "frame/s" in r.stderr
    assert r.stderr.rstrip().splitlines()[-1].startswith("ipc-taichi: decoupled ")


def test_a_lone_frame_shows_each_iteration(cli, tmp_path, rng, terminal):
    src = _ramp(tmp_path, rng, frames=1)
    terminal()
    r = cli("decouple", src, tmp_path / "out.fits", "--tol", 0, "--max-iter", 3)
    assert r.returncode == 0, r.stderr
    assert all(f"{q}/3 [" in r.stderr for q in (1, 2, 3)) and "iteration/s" in r.stderr


@pytest.mark.parametrize("quiet", [False, True])
def test_no_bar_off_a_terminal_or_when_quiet(cli, tmp_path, rng, terminal, quiet):
    src = _ramp(tmp_path, rng)
    if quiet:
        terminal()
    r = cli("decouple", src, tmp_path / "out.fits", *(["--quiet"] if quiet else []))
    assert r.returncode == 0, r.stderr
    expected = 0 if quiet else 1  # the summary line only
    assert len(r.stderr.splitlines()) == expected, r.stderr
    assert "\r" not in r.stderr


def test_a_bar_waits_for_slow_work():
    """Quick work draws nothing: the bar appears only after ``DELAY`` seconds."""
    class Terminal:
        def __init__(self):
            self.text = ""

        def write(self, s):
            self.text += s

        def flush(self):
            pass

        def isatty(self):
            return True

    stream = Terminal()
    with progress.TerminalProgress("decouple", stream, delay=30.0) as bar:
        for k in range(1, 5):
            bar(k, 4)
    assert stream.text == ""
    with progress.TerminalProgress("decouple", stream, delay=0.0) as bar:
        bar(1, 4)
        bar(1, 20, "iteration")  # another total: a new bar
    assert "1/4" in stream.text and "1/20" in stream.text
    assert progress.terminal_progress("x", stream=stream) is not None
    assert progress.terminal_progress("x", quiet=True, stream=stream) is None
    assert progress.reporters(True, 4, 20) == (None, None)


# --- the benchmark's start-up rows --------------------------------------------------------


def test_startup_rows_measure_fresh_processes_and_the_summary_line():
    from ipc_taichi.bench import render_section
    from ipc_taichi.bench.startup import TARGET_RATIO, TARGETS_S, measure_startup

    section = measure_startup(repeats=1, sizes=(16,), bytecode=False)  # no compile of it all
    help_row, python_row, decouple_row = section["rows"]
    assert help_row["command"] == "ipc-taichi --help"
    assert python_row["what"] == "python" and "(16x16)" in python_row["command"]
    assert decouple_row["command"].startswith("ipc-taichi decouple (16x16, arch ")
    for row in section["rows"]:
        assert 0 < row["min [s]"] <= row["median [s]"] <= row["max [s]"] < 120
        assert 0 < row["CPU median [s]"] < 120
    assert help_row["met"] == ("yes" if help_row["median [s]"] < TARGETS_S["help"] else "no")
    assert decouple_row["target [s]"] == "" == decouple_row["met"]  # 16x16: no target
    (ratio,) = section["ratios"][16]  # one interleaved pair: its own ratio
    assert ratio == decouple_row["median [s]"] / python_row["median [s]"]
    assert decouple_row["x fresh Python"] == f"{ratio:.2f}x" and TARGET_RATIO == 2.0
    cpu_ratio = decouple_row["CPU median [s]"] / python_row["CPU median [s]"]
    assert decouple_row["CPU x fresh Python"] == f"{cpu_ratio:.2f}x"
    assert section["summary_line_ok"]
    assert any(n.startswith("Summary line: 1 on stderr, `ipc-taichi: decoupled $TMP/in16.fits")
               and n.endswith("with --quiet 0 lines") for n in section["notes"])
    text = render_section(section)
    assert text.startswith("## Start-up") and "| ipc-taichi --help | help |" in text
    assert any(n.startswith("Bytecode: as this process has it") for n in section["notes"])


def test_fresh_processes_read_bytecode_from_the_benchs_cache(monkeypatch, tmp_path):
    from ipc_taichi.bench.startup import fresh_env

    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    env = fresh_env(tmp_path)
    assert "PYTHONDONTWRITEBYTECODE" not in env and env["PYTHONPYCACHEPREFIX"] == str(tmp_path)
    assert env["ENABLE_TAICHI_HEADER_PRINT"] == "False"
    kept = fresh_env()
    assert kept["PYTHONDONTWRITEBYTECODE"] == "1" and "PYTHONPYCACHEPREFIX" not in kept


def test_a_run_exits_frozen_with_taichis_cache_written(tmp_path):
    """Issue 39: the command line's exit handler ends the runtime (Taichi writes its
    offline cache, which it would otherwise do only when the collector destroys its
    program) and then freezes every object, so that the exit skips them; ti.init
    starts no version check (no network at run time)."""
    script = tmp_path / "probe.py"
    script.write_text(
        "import atexit, gc, os\n"
        "atexit.register(lambda: print('frozen', gc.get_freeze_count() > 0, flush=True))\n"
        "import taichi as ti\n"
        "from ipc_taichi import runtime\n"
        "from ipc_taichi.cli import main\n"
        "try:\n"
        "    main(['--version'])  # registers the exit handler\n"
        "except SystemExit:\n"
        "    pass\n"
        "runtime.init('cpu', 'f64')\n"
        "print('version check', os.environ.get('TI_SKIP_VERSION_CHECK'), flush=True)\n"
        "@ti.kernel\n"
        "def twice(a: ti.types.ndarray(dtype=ti.f64, ndim=1)):\n"
        "    for i in a:\n"
        "        a[i] = 2 * a[i]\n"
        "x = ti.ndarray(ti.f64, 4)\n"
        "twice(x)\n")
    cache = tmp_path / "ticache"
    env = {k: v for k, v in ENV.items() if k != "TI_SKIP_VERSION_CHECK"}
    r = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                       timeout=120, cwd=ROOT, env=dict(env, TI_OFFLINE_CACHE_FILE_PATH=str(cache),
                                                       PYTHONPATH=str(ROOT)))
    assert r.returncode == 0, r.stderr
    assert r.stdout.splitlines()[-2:] == ["version check ON", "frozen True"], r.stdout
    written = sorted(p.suffix for p in cache.iterdir())
    assert ".tic" in written and ".tcb" in written, written


def test_a_signal_a_library_turned_into_its_own_error_ends_as_interrupted(capsys):
    """NumPy interrupted while importing its extension raises ImportError: the
    run still ends with the signal's one line and code, and the same error
    without a signal is not ours to say (raised again)."""
    from ipc_taichi import cli
    from ipc_taichi.interrupts import clear_stop, request_stop

    request_stop(KeyboardInterrupt())
    try:
        assert cli._ended(ImportError("numpy._core.multiarray failed to import")) == 130
    finally:
        clear_stop()
    assert capsys.readouterr().err == INTERRUPTED + "\n"
    request_stop(cli.Terminated())
    try:
        assert cli._ended(RuntimeError("a library's own")) == 143
    finally:
        clear_stop()
    with pytest.raises(ImportError):
        cli._ended(ImportError("a real one"))
