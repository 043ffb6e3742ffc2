"""Ctrl-C at seeded instants spread over whole runs of ``optimize``, ``capture`` (several photos) and ``scan``.

Each command is first run once to its end (its wall time ``D``: the instants are spread over it, and the run must
end with exit code 0 and whole outputs); then, for each of ``--instants`` strata of ``[0, 1.05 D]``, a fresh
process of the command gets SIGINT at a seeded instant drawn in that stratum (the first ones fall while it starts,
the last ones may come after its end). Every run must end in one of three ways (:func:`judge`):

* interrupted: exit code 130; stderr holds only the command's own lines (``mi-svbrdf ...``), the last of them the
  one ``interrupted`` line; no traceback; the output folder holds no temporary file of an unfinished atomic write,
  every file in it is whole (JSON parses, images decode), and it does not exist where the line says nothing was
  written;
* ended first: the command ended before the instant (exit code 0, whole outputs);
* killed as it ended: SIGINT came after the command had reported its outcome (its success line printed), while the
  interpreter shut down: the signal's default action (a shell's exit code 130), nothing else printed.

Never exit code 0 once SIGINT was sent, never a traceback or a second line.

    python benchmarks/bench_sigint.py                     # writes docs/benchmarks/sigint.md
    python benchmarks/bench_sigint.py --instants 3 --seed 7 --out /tmp/sigint.md

``tests/test_sigint.py`` runs a few instants per command with short runs (fast) and this sweep (slow).
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import zlib
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: The page written by default.
PAGE = ROOT / "docs" / "benchmarks" / "sigint.md"
#: The ``mi-svbrdf`` console script of this Python.
MI_SVBRDF = str(Path(sys.executable).with_name("mi-svbrdf"))
#: Seconds a run may take after SIGINT (or in all, when it ends first) before it counts as hung.
TIMEOUT_S = 300.0
#: The commands of the sweep (``-o OUT`` is appended): budget-capped, several photos, the selection's folds.
SWEEP: dict[str, list[str]] = {
    "optimize": ["optimize", "--capture", "example", "--budget-s", "40"],
    "capture": ["capture", "example:multi", "--symmetries", "1"],
    "scan": ["scan", "example", "--budget-s", "2", "--size", "128"],
}
#: The sweep's strata per command (``--instants``; the sweep's wall time grows with it).
INSTANTS = {"optimize": 5, "capture": 4, "scan": 4}
#: The last stratum ends this far past the end of the command's run to its end (instants after the end included).
PAST_END = 1.05
#: A temporary file of :func:`mi_svbrdf.io.atomic.atomic_path` (``.<stem>.tmp<8 hex digits><suffix>``).
ATOMIC_TEMP = re.compile(r"^\..*\.tmp[0-9a-f]{8}(\.[^.]*)?$")
#: The one line of an interrupted command.
INTERRUPTED_LINE = re.compile(r"^mi-svbrdf [\w-]+: interrupted\b")
#: Where an interrupted command's line says its output folder holds nothing of the run.
NOTHING_WRITTEN = ("nothing was written", "nothing of this run was written to", "nothing of this run is in")
#: The line a command prints to stdout when it has written its results (its outcome reported).
SUCCESS_LINE = re.compile(r"wrote \S+/")


@dataclass
class Outcome:
    """One run of a command with SIGINT at ``instant`` seconds after its start."""

    command: str
    instant: float  #: seconds after the start at which SIGINT was due
    sent: bool  #: whether it was sent (False: the command had ended first)
    code: int  #: the exit code (negative: killed by that signal)
    seconds: float  #: the process's wall time
    stdout: str
    stderr: str
    said: float | None = None  #: seconds after the start at which the ``interrupted`` line came
    verdict: str = ""  #: "interrupted", "ended first", "killed as it ended", or "" (see problems)
    problems: list[str] = field(default_factory=list)

    @property
    def line(self) -> str:
        """The last line on stderr."""
        lines = self.stderr.strip().splitlines()
        return lines[-1] if lines else ""

    @property
    def latency(self) -> float | None:
        """Seconds from SIGINT to the process's end."""
        return round(self.seconds - self.instant, 2) if self.sent else None

    @property
    def line_latency(self) -> float | None:
        """Seconds from SIGINT to the ``interrupted`` line."""
        return round(self.said - self.instant, 2) if self.sent and self.said is not None else None


def instants(command: str, count: int, span: float, seed: int = 0, start: float = 0.0) -> list[float]:
    """``count`` seeded instants, one drawn uniformly in each of ``count`` equal strata of ``[start, span]``.

    Examples:
        >>> xs = instants("optimize", 3, 9.0)
        >>> len(xs), all(a < b for a, b in zip(xs, xs[1:])), 0.0 <= xs[0] < 3.0 <= xs[1] < 6.0 <= xs[2] < 9.0
        (3, True, True)
        >>> xs == instants("optimize", 3, 9.0) != instants("optimize", 3, 9.0, seed=1)
        True
    """
    rng = random.Random(zlib.crc32(command.encode()) + 1_000_003 * seed)
    width = (span - start) / count
    return [round(start + (i + rng.random()) * width, 2) for i in range(count)]


def interrupt_at(argv: list[str], instant: float, out: Path) -> Outcome:
    """Run ``mi-svbrdf ARGV -o OUT`` in a new process (its working folder: ``out``'s parent) and send it SIGINT
    ``instant`` seconds after its start, unless it ended first. Its output is read as it comes (the time of its
    ``interrupted`` line is the outcome's :attr:`Outcome.said`)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    proc = subprocess.Popen([MI_SVBRDF, *argv, "-o", str(out)], cwd=out.parent, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    streams: dict[str, list[tuple[float, str]]] = {"stdout": [], "stderr": []}

    def read(name: str) -> None:
        for line in getattr(proc, name):
            streams[name].append((time.monotonic() - start, line))

    readers = [threading.Thread(target=read, args=(name,), daemon=True) for name in streams]
    for reader in readers:
        reader.start()
    try:
        proc.wait(timeout=instant)
        sent = False
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGINT)
        sent = True
    try:
        proc.wait(timeout=TIMEOUT_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()
        streams["stderr"].append((time.monotonic() - start, f"(hung: killed {TIMEOUT_S:g} s after SIGINT)\n"))
    seconds = time.monotonic() - start
    for reader in readers:
        reader.join(timeout=10)
    said = [t for t, line in streams["stderr"] if INTERRUPTED_LINE.match(line)]
    return Outcome(argv[0], instant, sent, proc.returncode, round(seconds, 2),
                   "".join(line for _, line in streams["stdout"]), "".join(line for _, line in streams["stderr"]),
                   said=round(said[-1], 2) if said else None)


def whole_files(out: Path) -> list[str]:
    """What is wrong with the files under ``out``: a temporary file of an unfinished atomic write, a JSON file
    that does not parse, an image that does not decode, an empty file."""
    from PIL import Image

    problems = []
    for path in sorted(p for p in out.rglob("*") if p.is_file()) if out.is_dir() else []:
        rel = path.relative_to(out)
        if ATOMIC_TEMP.match(path.name):
            problems.append(f"{rel}: a temporary file of an unfinished write")
        elif path.stat().st_size == 0:
            problems.append(f"{rel}: empty")
        elif path.suffix == ".json":
            try:
                json.loads(path.read_text())
            except ValueError as exc:
                problems.append(f"{rel}: not JSON ({exc})")
        elif path.suffix.lower() in (".png", ".jpg", ".jpeg", ".gif"):
            try:
                with Image.open(path) as im:
                    im.load()
            except (OSError, SyntaxError) as exc:
                problems.append(f"{rel}: not an image ({exc})")
    return problems


def judge(run: Outcome, out: Path) -> Outcome:
    """Set ``run.verdict`` and ``run.problems`` (the rules of the module docstring); returns ``run``."""
    lines = run.stderr.strip().splitlines()
    problems = [f"stderr: {line}" for line in lines if "Traceback" in line or line.startswith("Exception ignored")]
    problems += whole_files(out)
    if not run.sent:
        run.verdict = "ended first"
        if run.code != 0:
            problems.append(f"ended first with exit code {run.code}")
    elif run.code == 130:
        run.verdict = "interrupted"
        said = [line for line in lines if INTERRUPTED_LINE.match(line)]
        if len(said) != 1 or said[0] != run.line:
            problems.append(f"expected one 'interrupted' line, the last; got {len(said)}: {said}")
        problems += [f"stderr: not the command's line: {line}" for line in lines if not line.startswith("mi-svbrdf ")]
        if any(words in run.line for words in NOTHING_WRITTEN) and out.exists():
            problems.append(f"the line says nothing was written, but {out.name}/ holds "
                            f"{sorted(str(p.relative_to(out)) for p in out.rglob('*'))[:5]}")
    elif run.code == -signal.SIGINT and SUCCESS_LINE.search(run.stdout) and not any(
            INTERRUPTED_LINE.match(line) for line in lines):
        run.verdict = "killed as it ended"  # after the outcome was reported: the default action, exit code 130
    else:
        problems.append(f"SIGINT at {run.instant} s: exit code {run.code}, expected 130")
    run.problems = problems
    return run


def startup_seconds(folder: Path) -> float:
    """Wall time of ``mi-svbrdf optimize`` until its command starts work: imports, the Mitsuba variant, the
    arguments, then a capture that does not exist (exit code 2 at once)."""
    start = time.monotonic()
    res = subprocess.run([MI_SVBRDF, "optimize", "--capture", str(folder / "missing.json"), "-o", str(folder / "o")],
                         cwd=folder, capture_output=True, text=True, timeout=TIMEOUT_S)
    if res.returncode != 2:
        raise RuntimeError(f"startup probe: expected exit code 2 (no such capture), got {res.returncode}: "
                           f"{res.stderr[-500:]}")
    return time.monotonic() - start


def run_to_end(argv: list[str], folder: Path) -> Outcome:
    """The command run to its end (an instant it never reaches); judged as ended first."""
    out = folder / "to_end"
    return judge(interrupt_at(argv, TIMEOUT_S, out), out)


def sweep(commands: dict[str, list[str]], counts: dict[str, int], folder: Path, seed: int = 0,
          say=print) -> tuple[dict[str, Outcome], list[Outcome]]:  # noqa: ANN001
    """For each command: its run to the end, then SIGINT at :func:`instants` over ``[0, PAST_END x`` its time``]``;
    ``say`` gets a line per run. Returns the runs to the end (by command) and the interrupted runs."""
    ends: dict[str, Outcome] = {}
    runs: list[Outcome] = []
    for name, argv in commands.items():
        end = ends[name] = run_to_end(argv, folder / name)
        say(f"{name}: to its end in {end.seconds:.1f} s, exit code {end.code} {end.problems or ''}")
        for k, t in enumerate(instants(name, counts[name], PAST_END * end.seconds, seed)):
            out = folder / name / f"at{k}"
            run = judge(interrupt_at(argv, t, out), out)
            runs.append(run)
            say(f"  SIGINT at {t:5.2f} s ({t / end.seconds:4.0%}): {run.verdict or 'FAILED'}, exit code {run.code}, "
                f"line {run.line_latency} s after, ended {run.latency} s after; {run.line[:100]!r} "
                f"{run.problems or ''}")
            shutil.rmtree(out, ignore_errors=True)
    return ends, runs


def page(ends: dict[str, Outcome], runs: list[Outcome], commands: dict[str, list[str]], seed: int,
         seconds: float) -> str:
    """The Markdown page of a sweep."""
    cores = os.cpu_count()
    load = ", ".join(f"{x:.2f}" for x in os.getloadavg())
    bad = [r for r in [*ends.values(), *runs] if r.problems]
    lines = [
        "# Ctrl-C at any instant",
        "",
        f"`python benchmarks/bench_sigint.py --seed {seed}` ({cores} cores, {platform.machine()}, load average "
        f"{load} at the end; {seconds:.0f} s in all): each command run once to its end, then SIGINT at seeded "
        f"instants, one per stratum of [0, {PAST_END:g} x that run's time]. Rules: the module docstring of "
        "`benchmarks/bench_sigint.py`; `tests/test_sigint.py` runs the same (slow) and a few instants of shorter "
        "runs (fast).",
        "",
        "| command | run to its end |",
        "|---|---|",
        *(f"| `mi-svbrdf {' '.join(commands[n])}` | {e.seconds:.1f} s, exit code {e.code} |" for n, e in ends.items()),
        "",
        "| command | SIGINT at | of its run | result | exit code | its line after | the process ended after | "
        "the line |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        frac = r.instant / ends[r.command].seconds
        latency = f"{r.latency:.1f} s" if r.latency is not None else ""
        said = f"{r.line_latency:.2f} s" if r.line_latency is not None else ""
        line = re.sub(r"\S*/at\d+/", "OUT/", r.line).replace("|", "\\|") if r.verdict == "interrupted" else ""
        lines.append(f"| {r.command} | {r.instant:.2f} s | {frac:.0%} | {r.verdict or 'FAILED'} | {r.code} | "
                     f"{said} | {latency} | {line} |")
    counts = {v: sum(r.verdict == v for r in runs) for v in ("interrupted", "ended first", "killed as it ended")}
    said = sorted(r.line_latency for r in runs if r.line_latency is not None)
    if said:
        lines += ["", f"The interrupted line came {said[len(said) // 2]:.2f} s after SIGINT (median; at most "
                      f"{said[-1]:.2f} s); the process ended later, after the interpreter's and Dr.Jit's shut-down, "
                      "as after any run."]
    lines += ["", f"{len(runs)} runs: " + ", ".join(f"{n} {v}" for v, n in counts.items()) +
              (f"; {len(bad)} FAILED: " + "; ".join(f"{r.command} at {r.instant} s: {r.problems}" for r in bad)
               if bad else "; none failed") + ".", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--instants", type=int, default=None, help="strata per command (default: optimize 5, others 4)")
    p.add_argument("--seed", type=int, default=0, help="seed of the instants (default 0)")
    p.add_argument("--only", choices=sorted(SWEEP), action="append", help="this command only (repeatable)")
    p.add_argument("--out", type=Path, default=PAGE, help="the page written (default docs/benchmarks/sigint.md)")
    args = p.parse_args(argv)
    if args.instants is not None and args.instants < 1:
        p.error(f"--instants: expected >= 1, got {args.instants}")
    commands = {n: a for n, a in SWEEP.items() if not args.only or n in args.only}
    counts = {n: args.instants or INSTANTS[n] for n in commands}
    start = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="sigint_") as tmp:
        ends, runs = sweep(commands, counts, Path(tmp), args.seed, say=lambda s: print(s, flush=True))
    from mi_svbrdf.io.atomic import write_text

    write_text(args.out, page(ends, runs, commands, args.seed, time.monotonic() - start))
    print(f"wrote {args.out}")
    return 1 if any(r.problems for r in [*ends.values(), *runs]) else 0


if __name__ == "__main__":
    raise SystemExit(main())
