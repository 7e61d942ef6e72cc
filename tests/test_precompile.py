"""The kernels compiled ahead of first use (kanagen/precompile.py, build_kernels.py) and the
seeding of an empty cache from them (common/jit.py: seed)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from kanagen.common import jit

ROOT = Path(__file__).resolve().parents[1]


def test_an_empty_cache_is_seeded_from_the_shipped_kernels(tmp_path):
    shipped = tmp_path / "kernels"
    (shipped / "0123456789abcdef" / "kanagen_engine").mkdir(parents=True)
    (shipped / "0123456789abcdef" / "kanagen_engine" / "a.nbi").write_bytes(b"index")
    cache = tmp_path / "cache" / "kanagen" / "numba" / "0123456789abcdef"
    assert jit.seed(cache, shipped)
    assert (cache / "kanagen_engine" / "a.nbi").read_bytes() == b"index"
    assert sorted(p.name for p in cache.parent.iterdir()) == ["0123456789abcdef"]  # no partial
    (cache / "kanagen_engine" / "a.nbi").write_bytes(b"compiled here")
    assert not jit.seed(cache, shipped)  # a cache that exists is the user's: left as it is
    assert (cache / "kanagen_engine" / "a.nbi").read_bytes() == b"compiled here"
    other = cache.with_name("fedcba9876543210")
    assert not jit.seed(other, shipped)  # no kernels shipped for those sources
    assert not other.exists()


def test_seeding_prunes_the_caches_of_other_sources(tmp_path):
    shipped = tmp_path / "kernels"
    (shipped / "0123456789abcdef").mkdir(parents=True)
    folder = tmp_path / "numba"
    old = [folder / f"{i:016x}" for i in range(jit.KEEP_OTHERS + 2)]
    for i, f in enumerate(old):
        f.mkdir(parents=True)
        (f / "x.nbi").write_bytes(b"")
        os.utime(f / "x.nbi", (1e9 + i, 1e9 + i))
    killed = folder / "0123456789abcdef.seeding-12345"  # a copy its process did not finish
    killed.mkdir()
    os.utime(killed, (1e9, 1e9))
    recent = folder / "0123456789abcdef.seeding-12346"  # another process copying now
    recent.mkdir()
    assert jit.seed(folder / "0123456789abcdef", shipped)
    left = sorted(p.name for p in folder.iterdir())
    assert left == sorted(["0123456789abcdef", recent.name,
                           *(f.name for f in old[-jit.KEEP_OTHERS:])])


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
