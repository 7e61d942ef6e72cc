"""The kernels compiled ahead of first use (kanagen/precompile.py, build_kernels.py) and the
seeding of an empty cache from them (common/jit.py: seed)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from kanagen.common import jit

ROOT = Path(__file__).resolve().parents[1]


TARGET = {"numba": "0.68.1", "numpy": "2.4", "python": "3.11", "processor": ["x", "cpu", "+f"]}
DIGEST = "0123456789abcdef"


def _shipped(tmp_path, target=TARGET) -> Path:
    """A shipped kernels' folder of digest :data:`DIGEST` compiled for ``target``, read-only
    as an installed package may be."""
    shipped = tmp_path / "kernels"
    engine = shipped / DIGEST / "kanagen_engine"
    engine.mkdir(parents=True)
    (engine / "a.nbi").write_bytes(b"index")
    (shipped / DIGEST / jit.SHIPPED_MANIFEST).write_text(json.dumps(target))
    for path in (engine / "a.nbi", engine, shipped / DIGEST):
        path.chmod(0o444 if path.is_file() else 0o555)
    return shipped


def test_an_empty_cache_is_seeded_from_the_shipped_kernels(tmp_path):
    shipped = _shipped(tmp_path)
    cache = tmp_path / "cache" / "kanagen" / "numba" / DIGEST
    assert jit.seed(cache, shipped, TARGET)
    assert (cache / "kanagen_engine" / "a.nbi").read_bytes() == b"index"
    assert not (cache / jit.SHIPPED_MANIFEST).exists()  # numba's files only
    for path in (cache, cache / "kanagen_engine", cache / "kanagen_engine" / "a.nbi"):
        assert path.stat().st_mode & 0o200, path  # the user's to write (numba writes there)
    assert sorted(p.name for p in cache.parent.iterdir()) == [DIGEST]  # no partial copy
    (cache / "kanagen_engine" / "a.nbi").write_bytes(b"compiled here")
    assert not jit.seed(cache, shipped, TARGET)  # a cache that exists is the user's
    assert (cache / "kanagen_engine" / "a.nbi").read_bytes() == b"compiled here"
    other = cache.with_name("fedcba9876543210")
    assert not jit.seed(other, shipped, TARGET)  # no kernels shipped for those sources
    assert not other.exists()


@pytest.mark.parametrize("field", sorted(TARGET))
def test_kernels_compiled_for_another_process_are_not_seeded(tmp_path, field):
    """Kernels of another numba, NumPy, Python or processor are not copied: the cache stays
    absent, and the first use compiles and says so (an empty cache is announced)."""
    shipped = _shipped(tmp_path)
    cache = tmp_path / "cache" / DIGEST
    assert not jit.seed(cache, shipped, {**TARGET, field: "other"})
    assert not cache.exists()
    (shipped / DIGEST).chmod(0o755)
    (shipped / DIGEST / jit.SHIPPED_MANIFEST).unlink()  # no manifest: not seeded either
    assert not jit.seed(cache, shipped, TARGET)
    assert not cache.exists()


def test_seeding_never_raises(tmp_path):
    shipped = _shipped(tmp_path)
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    assert not jit.seed(blocked / "numba" / DIGEST, shipped, TARGET)  # its parent: a file


def test_the_running_process_is_described_as_numba_keys_its_cache():
    from numba.core.registry import cpu_target

    target = jit.kernel_target()
    assert target["numba"] == jit.NUMBA.__version__
    assert target["processor"] == list(cpu_target.target_context.codegen().magic_tuple())
    assert json.loads(json.dumps(target)) == target  # as the manifest reads back


def test_seeding_prunes_the_caches_of_other_sources_and_only_stale_partial_copies(tmp_path):
    shipped = _shipped(tmp_path)
    folder = tmp_path / "numba"
    old = [folder / f"{i:016x}" for i in range(jit.KEEP_OTHERS + 2)]
    for i, f in enumerate(old):
        f.mkdir(parents=True)
        (f / "x.nbi").write_bytes(b"")
        os.utime(f / "x.nbi", (1e9 + i, 1e9 + i))
    killed = folder / f"{DIGEST}.seeding-12345"  # a copy its process did not finish
    killed.mkdir()
    os.utime(killed, (1e9, 1e9))
    copying = folder / f"{DIGEST}.seeding-{os.getpid()}"  # another process copying now,
    copying.mkdir()  # whatever its name
    (copying / "part").write_bytes(b"")
    assert jit.seed(folder / DIGEST, shipped, TARGET)
    left = sorted(p.name for p in folder.iterdir())
    assert left == sorted([DIGEST, copying.name, *(f.name for f in old[-jit.KEEP_OTHERS:])])
    assert (copying / "part").exists()


@pytest.mark.skipif(jit.NUMBA is None or jit.jit.disabled, reason="kernels run interpreted")
def test_a_first_fit_loads_the_shipped_kernels_instead_of_compiling(tmp_path):
    """A copy of the package whose ``kernels/<digest>`` holds this machine's compiled kernels
    (what the wheel's build step ships), run in a process whose cache is empty: the cache is
    seeded, the engine's kernels are loaded from it (their index files are not written
    again, as a compile would), and no compile is announced."""
    source = Path(jit.NUMBA.config.CACHE_DIR)
    if not (source / "kanagen_engine").is_dir():
        pytest.skip("no kernels compiled in this process's cache")
    package = tmp_path / "package"
    for name in ("kanagen", "common", "runtime", "generated", "modelspec", "codegen"):
        shutil.copytree(ROOT / name, package / name,
                        ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copytree(source, package / "kernels" / source.name,
                    ignore=shutil.ignore_patterns("*.seeding-*"))
    (package / "kernels" / source.name / jit.SHIPPED_MANIFEST).write_text(
        json.dumps(jit.kernel_target()))  # what the build step writes
    indexes = {p.relative_to(source): p.read_bytes()
               for p in (source / "kanagen_engine").glob("*.nbi")}
    env = dict(os.environ, XDG_CACHE_HOME=str(tmp_path / "xdg"),
               KANAGEN_CACHE=str(tmp_path / "specs"), KANAGEN_BACKEND="numpy")
    env.pop("NUMBA_CACHE_DIR", None)
    code = ("import numpy as np, kanagen\n"
            "fam = kanagen.load('conic')\n"
            "t = np.linspace(0.0, np.pi, 12)\n"
            "xy = np.c_[100 + 50 * np.cos(t), 80 + 30 * np.sin(t)]\n"
            "print(kanagen.fit(fam, 'conic', data={'point': xy}).success)\n"
            "from kanagen.common.jit import NUMBA\n"
            "print(NUMBA.config.CACHE_DIR)\n")
    out = subprocess.run([sys.executable, "-c", code], env=env, cwd=package,
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    success, cache = out.stdout.split()[-2:]
    assert success == "True"
    assert Path(cache) == tmp_path / "xdg" / "kanagen" / "numba" / source.name
    assert "compiling the estimator's kernels" not in out.stderr
    for name, content in indexes.items():
        assert (Path(cache) / name).read_bytes() == content, name


def test_an_installed_kanagen_ships_the_kernels_of_its_sources():
    """The wheel's build step ran: an installed kanagen (the one ``pip install .`` made of
    these sources; CI installs it so) holds the engine's kernels under their digest."""
    import json
    from importlib import metadata

    # pip's install (a RECORD), not the metadata a build leaves in the checkout
    installed = [d for d in metadata.distributions(name="kanagen") if d.read_text("RECORD")]
    if not installed:
        pytest.skip("kanagen is not installed by pip")
    dist = installed[0]
    direct = json.loads(dist.read_text("direct_url.json") or "{}")
    if direct.get("dir_info", {}).get("editable"):
        pytest.skip("an editable install ships no kernels (they compile at first use)")
    digest = jit._sources_digest(Path(dist.locate_file("kanagen")))
    if digest != jit._sources_digest():
        pytest.skip("the installed kanagen's kernels are of other sources than these")
    folder = f"kanagen/kernels/{digest}/kanagen_engine/"
    if os.environ.get("KANAGEN_PRECOMPILE", "1").strip() == "0":
        pytest.skip("KANAGEN_PRECOMPILE=0: the build step was skipped")
    assert any(str(f).startswith(folder) and str(f).endswith(".nbi")
               for f in dist.files or ()), f"no {folder}*.nbi in the installed kanagen"
    manifest = f"kanagen/kernels/{digest}/{jit.SHIPPED_MANIFEST}"
    assert any(str(f) == manifest for f in dist.files or ()), f"no {manifest}"


def test_the_build_step_ships_no_earlier_builds_kernels(tmp_path, monkeypatch):
    """build/lib outlives a build: its kernels are removed before the step compiles, and
    when the step is skipped or fails the wheel holds none."""
    from setuptools.dist import Distribution

    import build_kernels

    monkeypatch.setattr(build_kernels._build_py, "run", lambda self: None)  # modules copied
    stale = tmp_path / "lib" / "kanagen" / "kernels" / "fedcba9876543210"
    stale.mkdir(parents=True)
    command = build_kernels.build_py(Distribution({"name": "kanagen"}))
    command.build_lib = str(tmp_path / "lib")
    monkeypatch.setenv("KANAGEN_PRECOMPILE", "0")
    command.run()
    assert not stale.parent.exists()
    stale.mkdir(parents=True)
    monkeypatch.setenv("KANAGEN_PRECOMPILE", "1")
    ran = []

    def fails(args, **options):  # the step's child exits with an error
        ran.append(args)
        return subprocess.CompletedProcess(args, 1)

    monkeypatch.setattr(build_kernels.subprocess, "run", fails)
    command.run()  # a warning, not an error, and no kernels
    assert ran and ran[0][1:3] == ["-m", "kanagen.precompile"]
    assert not stale.parent.exists()


def test_the_build_step_workload_runs_every_shipped_family():
    """What the wheel's build step runs (kanagen.precompile): every shipped family's fits
    and search, with no error (here from the warm cache)."""
    import kanagen
    from kanagen.precompile import SHIPPED, precompile

    shipped = sorted(p.stem for p in (ROOT / "generated").glob("*.py")
                     if p.stem != "__init__" and not p.stem.endswith("_casadi"))
    assert sorted(SHIPPED) == shipped
    assert all(kanagen.load(name).name == name for name in SHIPPED)
    assert precompile() == {name: "ok" for name in SHIPPED}


def test_a_second_build_starts_from_the_users_kernels_of_the_same_sources(tmp_path,
                                                                           monkeypatch):
    """``pip install ".[test]"`` after ``pip install .`` builds the wheel again: its step
    starts the fresh cache from the user's cache of the same digest (the first install's
    kernels, seeded at its first use) — only the package's own folders, without locks and
    without the kernels of the user's families — and ships what the workload leaves there;
    with no such cache it starts empty."""
    from kanagen import precompile

    xdg = tmp_path / "xdg"
    mine = xdg / "kanagen" / "numba" / jit._sources_digest()
    for name, content in (("kanagen_engine/a.nbi", b"index"), ("kanagen_engine/a.nbc", b"code"),
                          ("kanagen_runtime/b.nbi", b"index"), ("kanagen_engine/c.lock", b""),
                          ("0123abcd_4567/d.nbi", b"a user's family")):
        (mine / name).parent.mkdir(parents=True, exist_ok=True)
        (mine / name).write_bytes(content)
    monkeypatch.setenv("XDG_CACHE_HOME", str(xdg))
    seen = []

    def child(args, env, **options):  # the step's child: reads the cache, writes the manifest
        cache = Path(env["XDG_CACHE_HOME"]) / "kanagen" / "numba" / mine.name
        seen.append(sorted(str(p.relative_to(cache)) for p in cache.rglob("*") if p.is_file())
                    if cache.is_dir() else [])
        cache.mkdir(parents=True, exist_ok=True)
        (cache / jit.SHIPPED_MANIFEST).write_text("{}")
        return subprocess.CompletedProcess(args, 0)

    monkeypatch.setattr(subprocess, "run", child)
    assert precompile._into(tmp_path / "ship") == 0
    assert seen == [["kanagen_engine/a.nbc", "kanagen_engine/a.nbi", "kanagen_runtime/b.nbi"]]
    shipped = tmp_path / "ship" / mine.name
    assert (shipped / "kanagen_engine" / "a.nbc").read_bytes() == b"code"
    assert (shipped / jit.SHIPPED_MANIFEST).is_file()
    assert (mine / "0123abcd_4567" / "d.nbi").is_file()  # the user's cache is left as it was
    shutil.rmtree(xdg)
    assert precompile._into(tmp_path / "ship") == 0
    assert seen[1] == []


def test_a_process_with_a_warm_cache_compiles_nothing():
    """Every kernel a fit and a robust search run comes from the cache once it holds them —
    the engine's records included (numba's own constructor of a structure is a closure it
    compiles anew in every process: half a second of each first fit; kanagen's is a
    cached kernel). Run twice in fresh processes: the first may fill the cache, the second
    compiles nothing (numba's ``numba:compile`` events)."""
    code = (
        "from numba.core import event\n"
        "compiled = []\n"
        "class Count(event.Listener):\n"
        "    def on_start(self, e): compiled.append(str(e.data.get('dispatcher')))\n"
        "    def on_end(self, e): pass\n"
        "event.register('numba:compile', Count())\n"
        "import numpy as np, kanagen\n"
        "rng = np.random.default_rng(0)\n"
        "t = rng.uniform(0.0, 3.0, 60)\n"
        "xy = np.c_[320 + 120 * np.cos(t), 240 + 70 * np.sin(t)] + rng.normal(0, .5, (60, 2))\n"
        "fam = kanagen.load('conic_lattice', backend='numpy')\n"
        "assert kanagen.fit(fam, 'ellipse', data={'point': xy}).success\n"
        "est = kanagen.Estimator(fam, seed=0)\n"
        "est.add_measures('point', xy)\n"
        "est.run(max_samples=100)\n"
        "print(len(compiled), compiled[:3])\n")
    env = dict(os.environ, KANAGEN_BACKEND="numpy")
    for _ in range(2):
        out = subprocess.run([sys.executable, "-c", code], env=env, cwd=ROOT,
                             capture_output=True, text=True, timeout=900)
        assert out.returncode == 0, out.stderr[-3000:]
    assert out.stdout.split()[0] == "0", out.stdout
