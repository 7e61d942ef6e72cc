"""Hostile input against kanagen (issue 15): what each costs to refuse, and that nothing runs.

Each spec of :data:`SPECS` is read in a fresh process under a 1 GB address-space limit; the
table gives the time the refusal took (after import), the process's peak memory and the
first line of the error. A spec that must work (a polynomial of thousands of terms) is marked
``accept``. The other rows: data files a batch must record as failed, and the file-name
injection (item 1).

    python benchmarks/hostile.py            # the table, and PASS/FAIL per floor
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

BASE = """\
name: h
parameter: {a: 1.0, b: 0.5}
channels:
  pt:
    components: [x, y]
    equations: [EQ]
models:
  m: {}
"""


def _spec(equation: str) -> str:
    return BASE.replace("EQ", equation)


def _alias_bomb(levels: int = 9, width: int = 9) -> str:
    lines = ["a0: &a0 [x" + ", x" * (width - 1) + "]"]
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * width) + "]"
              for i in range(1, levels)]
    return "\n".join(lines) + "\n" + _spec("y - a*x")


def _define_chain(levels: int = 15) -> str:
    chain = "define:\n  d0: x + a\n" + "".join(f"  d{i}: d{i - 1}*d{i - 1} + d{i - 1}\n"
                                                for i in range(1, levels))
    return BASE.replace("channels:", chain + "channels:").replace("[EQ]",
                                                                  f"[y - d{levels - 1}]")


def _polynomial(terms: int) -> str:
    """A polynomial of ``terms`` distinct monomials (what must work)."""
    return _spec(" + ".join(f"{i + 1}*a*x**{i % 55}*y**{i // 55}" for i in range(terms))
                 + " - y")


def _det(size: int) -> str:
    rows = ", ".join("[" + ", ".join(f"x*{i} + a*{j} + {i * j}" for j in range(size)) + "]"
                     for i in range(size))
    return BASE.replace("channels:", f"define:\n  M: [{rows}]\nchannels:").replace(
        "[EQ]", "[y - det(M)]")


#: name -> (spec text, "refuse" or "accept")
SPECS: dict[str, tuple[str, str]] = {
    "YAML alias bomb (9 x 9)": (_alias_bomb(), "refuse"),
    "recursive YAML alias": ("a: &a [*a]\n" + _spec("y - a*x"), "refuse"),
    "YAML merge key": ("base: &base {x: 1}\nother:\n  <<: *base\n" + _spec("y - a*x"),
                       "refuse"),
    "spec of 25 MB": (BASE.replace("models:", "description: |\n" + ("  " + "z" * 100 + "\n")
                                   * 250_000 + "models:").replace("[EQ]", "[y - a*x]"),
                      "refuse"),
    "nested powers ((x**64)**64)**64": (_spec("((x**64)**64)**64 - a"), "refuse"),
    "nested number powers": (_spec("(((9**64)**64)**64)**64 - a"), "refuse"),
    "6-term or of ands (CNF)": (BASE.replace(
        "  m: {}", "  m:\n    constraints:\n      k: " + " or ".join(
            f"(a > {i} and b > {i})" for i in range(1, 7))).replace("[EQ]", "[y - a*x - b]"),
        "refuse"),
    "det of a 9x9 matrix": (_det(9), "refuse"),
    "15 define levels": (_define_chain(15), "refuse"),
    "sqrt(-1)": (_spec("y - a*x - sqrt(-1)"), "refuse"),
    "log(-1)": (_spec("y - a*x - log(-1)"), "refuse"),
    "(-8)**(1/3)": (_spec("y - a*x - (-8)**(1/3)"), "refuse"),
    "exp(exp(exp(1000)))": (_spec("y - a*exp(exp(exp(1000)))"), "refuse"),
    "sin nested 150 deep": (_spec("y - " + "sin(" * 150 + "x" + ")" * 150), "refuse"),
    "family name of 300 characters": (_spec("y - a*x").replace("name: h", "name: " + "f" * 300),
                                      "refuse"),
    "name ending in a newline": (_spec("y - a*x").replace("name: h", 'name: "line\\n"'),
                                 "refuse"),
    "polynomial of 600 terms": (_polynomial(600), "accept"),
    "polynomial of 3000 terms": (_polynomial(3000), "accept"),
}

_CHILD = textwrap.dedent("""\
    import json, resource, sys, time
    resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))
    import kanagen
    import kanagen.runtime.family  # the runtime's imports (numba's compiler) are not the spec's
    from kanagen.modelspec import SpecError
    text = open(sys.argv[1], encoding="utf-8").read()
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    started = time.perf_counter()
    try:
        kanagen.load_text(text, source="hostile.yaml")
        outcome, message, line = "accept", "", None
    except SpecError as exc:
        outcome, message, line = "refuse", str(exc), exc.line
    except BaseException as exc:
        outcome, message, line = "crash", f"{type(exc).__name__}: {exc}", None
    seconds = time.perf_counter() - started
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"outcome": outcome, "message": message.splitlines()[0][:160]
                      if message else "", "line": line, "seconds": seconds, "mb": peak,
                      "base_mb": base}))
    """)


def run_spec(text: str, timeout: float = 120.0) -> dict:
    """Read ``text`` with kanagen in a fresh process: outcome, first error line, seconds
    (after import), peak MB and the MB the imports alone took (``base_mb``)."""
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "hostile.yaml"
        path.write_text(text, encoding="utf-8")
        env = {**os.environ, "KANAGEN_CACHE": str(Path(folder) / "cache")}
        try:
            done = subprocess.run([sys.executable, "-c", _CHILD, str(path)], env=env,
                                  capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return {"outcome": "timeout", "message": f"over {timeout:.0f} s", "line": None,
                    "seconds": timeout, "mb": float("nan")}
        try:
            return json.loads(done.stdout.strip().splitlines()[-1])
        except (IndexError, ValueError):
            return {"outcome": "crash", "message": done.stderr.strip()[-160:], "line": None,
                    "seconds": float("nan"), "mb": float("nan")}


def bad_data_files(folder: Path) -> dict[str, str]:
    """One unreadable dataset of each kind in ``folder``: file name -> what its error must
    say (issue 15 item 3)."""
    import zipfile

    import numpy as np

    folder.mkdir(parents=True, exist_ok=True)
    (folder / "field.csv").write_text("x,y\n1," + "9" * 200_000 + "\n")
    (folder / "corrupt.npz").write_bytes(b"PK\x03\x04" + bytes(range(256)) * 2)
    np.save(folder / "renamed.npy", np.ones((5, 2)))
    (folder / "renamed.npy").rename(folder / "renamed.npz")
    (folder / "nested.json").write_text("[" * 100_000 + "]" * 100_000)
    (folder / "latin1.csv").write_bytes("x,y\n1,2\n\xe9,3\n".encode("latin-1"))
    np.savez(folder / "complex.npz", point=np.ones((4, 2)) * (1 + 2j))
    np.savez(folder / "bools.npz", point=np.ones((4, 2), dtype=bool))
    (folder / "twice.csv").write_text("x,y,x\n1,2,3\n")
    (folder / "text.json").write_text(json.dumps({"point": [["1", "2"], ["3", "4"]]}))
    with zipfile.ZipFile(folder / "pickled.npz", "w") as z:
        z.writestr("point.npy", b"\x93NUMPY\x01\x00v\x00{'descr': '|O', 'fortran_order': "
                                b"False, 'shape': (2,), }" + b" " * 60 + b"\n\x80\x04N.")
    return {"field.csv": "not CSV", "corrupt.npz": "cannot read data",
            "renamed.npz": "not an .npz archive", "nested.json": "nested too deeply",
            "latin1.csv": "not UTF-8", "complex.npz": "complex", "bools.npz": "booleans",
            "twice.csv": "named twice", "text.json": "list of rows of numbers",
            "pickled.npz": "cannot read data"}


def _batch_table(folder: Path) -> bool:
    """A batch over good datasets and one unreadable file of each kind, then two concurrent
    batches on a new database."""
    import numpy as np

    import kanagen

    spec = str(Path(__file__).resolve().parents[1] / "examples" / "conic_lattice.yaml")
    data = folder / "data"
    reasons = bad_data_files(data)
    t = np.linspace(0.3, 2.5, 20)
    for k in range(4):
        xy = np.c_[100 * np.cos(t) + 10 * k, 60 * np.sin(t)]
        np.savetxt(data / f"good{k}.csv", xy, delimiter=",", header="x,y", comments="")
    summary = kanagen.batch(spec, str(data / "*"), db=folder / "a.sqlite", workers=1,
                            scale=4.0, max_samples=20)
    rows = {Path(r["dataset"]).name: r for r in kanagen.read_results(folder / "a.sqlite")}
    recorded = all(rows[n]["status"] == "error" and why in rows[n]["message"]
                   for n, why in reasons.items())
    print(f"\nbatch over {summary.datasets} files ({len(reasons)} unreadable): "
          f"{summary.ok + summary.no_model} estimated, {summary.errors} recorded as failed "
          f"with their reason: {'PASS' if recorded and summary.errors == len(reasons) else 'FAIL'}")
    for name in reasons:
        print(f"  {name:14s} {rows[name]['message'][len(str(data)) + 1:][:90]}")
    runs = [subprocess.Popen([sys.executable, "-m", "kanagen", "batch", spec,
                              str(data / "good*.csv"), "--db", str(folder / "b.sqlite"),
                              "--workers", "1", "--scale", "4", "--max-samples", "20"],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
             for _ in range(2)]
    counts = []
    for run in runs:
        out, _ = run.communicate(timeout=600)
        counts.append(int(out.strip().splitlines()[-1].split(": ")[1].split(" estimated")[0]))
    once = sum(counts) == 4 and len(kanagen.read_results(folder / "b.sqlite")) == 4
    print(f"two concurrent batches on a new database over 4 datasets: estimated {counts[0]} "
          f"+ {counts[1]} = {sum(counts)}: {'PASS' if once else 'FAIL'}")
    return recorded and once


def _file_name_table(folder: Path) -> bool:
    """A spec whose file name would close the module docstring and run a statement."""
    payload = 'x"""\nimport pathlib; pathlib.Path("MARKER").touch()\n""".yaml'
    spec = folder / payload
    spec.write_text(BASE.replace("EQ", "y - a*x - b"), encoding="utf-8")
    env = {**os.environ, "KANAGEN_CACHE": str(folder / "cache")}
    done = subprocess.run([sys.executable, "-m", "kanagen", "build", str(spec), "-o",
                           str(folder / "gen")], cwd=folder, env=env, capture_output=True,
                          text=True, timeout=120)
    ran = (folder / "MARKER").exists()
    ok = done.returncode == 0 and not ran
    print(f"spec file named {payload!r}: built, code run: {ran}: {'PASS' if ok else 'FAIL'}")
    return ok


def main() -> int:
    print(f"{'case':34s} {'wanted':7s} {'got':8s} {'s':>6s} {'MB':>6s}  message")
    ok = True
    for name, (text, wanted) in SPECS.items():
        started = time.perf_counter()
        r = run_spec(text)
        r.setdefault("seconds", time.perf_counter() - started)
        good = r["outcome"] == wanted and (wanted == "accept" or (
            r["seconds"] < 2.0 and r["mb"] < 500 and r["line"] is not None
            or "bytes" in r["message"] or "characters" in r["message"]))
        ok &= good
        print(f"{name:34s} {wanted:7s} {r['outcome']:8s} {r['seconds']:6.2f} {r['mb']:6.0f}  "
              f"{'' if good else 'FAIL '}{r['message'][:90]}")
    print(f"\nhostile specs: {'PASS' if ok else 'FAIL'} (each refused in under 2 s and 500 MB "
          "with its file and line; the polynomials accepted)")
    with tempfile.TemporaryDirectory() as folder:
        ok &= _file_name_table(Path(folder))
    with tempfile.TemporaryDirectory() as folder:
        ok &= _batch_table(Path(folder))
    print(f"\nissue 15 floors: {'PASS' if ok else 'FAIL'}")
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
