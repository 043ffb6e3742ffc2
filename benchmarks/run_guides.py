"""Run every ``mi-svbrdf`` command of the README's and docs' bash blocks as a new user would, and time each.

The commands of each page (README.md, then docs/**/*.md: the guides, install) are run in the order
they are written, in a fresh folder per page as the working directory (so a command may use what an
earlier one on the same page wrote, as a reader following the page would), each in its own process
(``python -m mi_svbrdf.cli``, the same as ``mi-svbrdf``), with a fresh ``MI_SVBRDF_CACHE``
(held-out sets and training runs are built from nothing, as on a new machine). Only the bundled data
are at hand: commands on the reader's own photos, GPUs or hours of compute are listed in
:data:`EXEMPT`, each with its reason; a long run cut to a smoke run by options appended to it
(argparse keeps an option's last value) is in :data:`APPEND`, with its reason. A command of many minutes
is cut by its own options as :data:`CUTS` says, with its reason (``--as-written``: not cut). A command
of a page that none of them names is run as written.

    python benchmarks/run_guides.py                       # every page; writes docs/benchmarks/guide_commands.md
    python benchmarks/run_guides.py --only docs/guides/large-surfaces.md --out OUT.md --keep RUNS/
    python benchmarks/run_guides.py --only docs/guides/scan.md --update    # re-run one page's rows of the table

A command whose output folder's ``summary.json`` lists timed steps (``scan``'s) has each step's seconds in its
note (``steps: rectify 5.7 s, ...``): the figures a guide states about its steps are read from there
(``tests/test_docs_figures.py``).

``tests/test_guides_run.py`` (slow) runs the same and asserts that every command ran with exit code 0.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import re
import shlex
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from mi_svbrdf.io.atomic import write_text

ROOT = Path(__file__).resolve().parent.parent
#: Where the table goes by default.
TABLE = ROOT / "docs" / "benchmarks" / "guide_commands.md"
#: Seconds a command may take before it counts as failed.
TIMEOUT_S = 900.0

#: Documented commands that are not run, with the reason (keys: the command with single spaces).
EXEMPT: dict[str, str] = {
    "mi-svbrdf capture-file import their_capture/ --size 256 -o out/their_capture":
        "placeholder: a capture folder of another lab (e.g. ../shared/real/yellow_box, not in the package)",
    "mi-svbrdf optimize --capture out/their_capture -o out/their_fit": "needs the capture the exempt import above writes",
    "mi-svbrdf optimize --capture out/their_capture --method pixel -o out/their_pixel":
        "needs the capture the exempt import above writes",
    "mi-svbrdf capture photo.jpg -o out/cap": "placeholder: the reader's own flash photo",
    "mi-svbrdf capture flash.jpg b.jpg c.jpg -o out/cap": "placeholder: the reader's own photos",
    "mi-svbrdf capture photo.jpg --device cuda -o out/cap": "needs a GPU (and the reader's own photo)",
    "mi-svbrdf capture-file make photos/ --sample-width 150 --camera 0,0,400 --flash 20,0,400 --fov 65 -o my_capture":
        "placeholder: the reader's own photos/ and their camera and flash",
    "mi-svbrdf optimize --capture my_capture -o out/fit --budget-s 120":
        "needs the capture the previous (exempt) command makes from the reader's photos",
    "mi-svbrdf rectify IMG_*.jpg --frame tags --frame-size 180 -o rect":
        "placeholder: the reader's own photos of the AprilTag print",
    "mi-svbrdf optimize --capture rect/capture.json -o fit":
        "needs the capture the previous (exempt) command makes from the reader's photos",
    "mi-svbrdf scan IMG_*.jpg --frame tags --frame-size 180 -o out/my_scan":
        "placeholder: the reader's own photos of the AprilTag print",
    "mi-svbrdf evaluate --out report/ --cases all": "the full evaluation: about 2 h on 2 cores (--quick runs)",
    "mi-svbrdf ablations -o out/ablations": "the full ablation study: about 30 min on 2 cores (--quick runs)",
    "mi-svbrdf train full-single --device cuda -o runs/single_full": "needs a GPU (a 400 k-step run)",
    "mi-svbrdf train full-multi --device cuda -o runs/multi_full --resume": "needs a GPU (a 1 M-step run)",
}
#: Options appended to a documented command of hours (the command's own options; argparse keeps the last value),
#: with why: always.
APPEND: dict[str, tuple[str, str]] = {
    "mi-svbrdf train single": ("--set steps=2 --set validate_every=0 --set batch_size=1 --no-progress",
                               "hours of training: 2 steps of one sample (no validation) check the recipe, data and "
                               "checkpoint"),
    "mi-svbrdf train multi --resume --set lr=1e-4": (
        "--set steps=2 --set validate_every=0 --set batch_size=1 --no-progress",
        "hours of training: 2 steps of one sample (no validation; a step of the recipe's 8 took 54 s on 2 cores)"),
}
#: Options appended to a documented command of a minute or more to keep the whole run near 4 min on 2 cores, with
#: why: by default and in the test (``--as-written`` runs these as documented).
CUTS: dict[str, tuple[str, str]] = {
    "mi-svbrdf capture example:multi --refine -o out/cap-refined": (
        "--budget-s 5", "the refinement's 60 s budget (it converged after 45 s on 2 cores): 5 s of it"),
    "mi-svbrdf dataset render --scene flash_capture --materials bank/ --renders-per-material 10 --out data/": (
        "--limit 64", "640 renders (28 s on 2 cores): the first 64 of them"),
    "mi-svbrdf scan example --frame tags -o out/scan": (
        "--budget-s 20", "the fit's default budget (240 s for the example's 1024^2 rectified photos; the whole chain "
                         "took 3 min 49 s on 2 shared cores): 20 s of it"),
    "mi-svbrdf evaluate --quick --out report/": (
        "--materials 1 --no-foreign --stability-materials 0 --symmetries 1 --budgets 1 --refine-budgets 1 "
        "--uncalibrated-budgets 1 --no-progress",
        ("the quick evaluation as written took 652 s on 2 cores (4 materials, foreign set, stability): "
         "1 material, held-out set only, the nets alone, 1 s budgets")),
}


def normalise(command: str) -> str:
    """A command with single spaces (the key of :data:`EXEMPT` and :data:`APPEND`)."""
    return " ".join(command.split())


def documented_commands(path: Path) -> list[str]:
    """The ``mi-svbrdf ...`` commands of ``path``'s bash blocks, in order (continued lines joined, comments dropped,
    ``&&`` / ``;`` chains split), as ``tests/test_cli_readme.py`` parses them."""
    found = []
    for block in re.findall(r"```bash\n(.*?)```", path.read_text(encoding="utf-8"), flags=re.S):
        for line in block.replace("\\\n", " ").splitlines():
            for part in re.split(r"&&|;", line.split("#", 1)[0]):
                if part.split()[:1] == ["mi-svbrdf"]:
                    found.append(normalise(part))
    return found


def documents() -> list[Path]:
    """README.md and every page of docs/ with a documented command."""
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    return [p for p in pages if documented_commands(p)]


@dataclass
class Result:
    """One documented command and what happened to it."""

    document: str  #: the page, relative to the repository
    command: str  #: as documented
    status: str  #: "ok", "failed" (non-zero exit or timeout) or "exempt"
    seconds: float | None = None  #: wall time of the process
    note: str = ""  #: the exemption's reason, or the options appended and why
    output: str = ""  #: the end of stdout + stderr when it failed


def run_command(command: str, cwd: Path, env: dict[str, str], timeout: float = TIMEOUT_S) -> tuple[int, float, str]:
    """Run ``mi-svbrdf ...`` as ``python -m mi_svbrdf.cli ...`` in ``cwd``: ``(exit code, seconds, output)``."""
    argv = [sys.executable, "-m", "mi_svbrdf.cli", *shlex.split(command)[1:]]
    start = time.perf_counter()
    try:
        res = subprocess.run(argv, check=False, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout,
                             stdin=subprocess.DEVNULL)
        code, output = res.returncode, res.stdout + res.stderr
    except subprocess.TimeoutExpired as exc:
        code, output = -1, f"timed out after {timeout:.0f} s\n{exc.stdout or ''}{exc.stderr or ''}"
    return code, time.perf_counter() - start, output


def environment(cache: Path) -> dict[str, str]:
    """The commands' environment: this one, with this repository first on PYTHONPATH and a fresh cache."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT), *filter(None, [env.get("PYTHONPATH")])])
    env["MI_SVBRDF_CACHE"] = str(cache)
    env["TQDM_DISABLE"] = "1"  # no progress bars in the captured output
    return env


def appended(command: str, cuts: bool = True) -> tuple[str, str]:
    """``(options appended, why)`` of a documented command: :data:`APPEND`'s, else (``cuts``) :data:`CUTS`'."""
    if command in APPEND:
        return APPEND[command]
    return CUTS.get(command, ("", "")) if cuts else ("", "")


def out_folder(command: str) -> str | None:
    """The ``-o`` / ``--out`` value of a ``mi-svbrdf ...`` command (the last one given), or None."""
    words, found = shlex.split(command), None
    for i, word in enumerate(words):
        if word in ("-o", "--out") and i + 1 < len(words):
            found = words[i + 1]
        elif word.startswith("--out="):
            found = word.split("=", 1)[1]
    return found


def step_seconds(command: str, workdir: Path) -> str:
    """``"steps: rectify 5.7 s, optimize 25.1 s, ..."`` from the ``steps`` of the ``summary.json`` the command wrote in
    its output folder (``scan``'s: each step's name and seconds); ``""`` when it wrote none."""
    out = out_folder(command)
    path = workdir / out / "summary.json" if out else None
    if path is None or not path.is_file():
        return ""
    try:
        steps = json.loads(path.read_text(encoding="utf-8")).get("steps")
    except (OSError, ValueError, AttributeError):
        return ""
    if not isinstance(steps, list):
        return ""
    timed = [f"{s['name']} {float(s['seconds']):.1f} s" for s in steps
             if isinstance(s, dict) and isinstance(s.get("name"), str) and isinstance(s.get("seconds"), (int, float))]
    return f"steps: {', '.join(timed)}" if timed else ""


#: The note's part that :func:`step_seconds` writes (read back by :func:`steps_of_note`).
STEPS_NOTE = re.compile(r"steps: ((?:[\w-]+ [\d.]+ s(?:, )?)+)")


def steps_of_note(note: str) -> dict[str, float]:
    """``{step: seconds}`` of a table note written with :func:`step_seconds` (empty when it has none)."""
    match = STEPS_NOTE.search(note)
    if not match:
        return {}
    return {name: float(sec) for name, sec in re.findall(r"([\w-]+) ([\d.]+) s", match.group(1))}


def run_document(doc: Path, workdir: Path, env: dict[str, str], *, cuts: bool = True,
                 echo: bool = True) -> list[Result]:
    """Run ``doc``'s commands in order in ``workdir`` (created); a failed command does not stop the next
    (``cuts``: with the options of :data:`CUTS`)."""
    workdir.mkdir(parents=True, exist_ok=True)
    name = doc.relative_to(ROOT).as_posix()
    results = []
    for command in documented_commands(doc):
        if command in EXEMPT:
            result = Result(name, command, "exempt", note=EXEMPT[command])
        else:
            extra, why = appended(command, cuts)
            code, seconds, output = run_command(f"{command} {extra}".strip(), workdir, env)
            note = "; ".join(filter(None, [f"run with `{extra}`: {why}" if extra else "",
                                           step_seconds(command, workdir) if code == 0 else ""]))
            result = Result(name, command, "ok" if code == 0 else "failed", seconds, note,
                            "" if code == 0 else f"exit code {code}\n{output[-3000:]}")
        if echo:
            took = f"{result.seconds:7.1f} s" if result.seconds is not None else "      - "
            print(f"{took}  {result.status:6}  {name}: {command}", flush=True)
            if result.status == "failed":
                print(result.output, flush=True)
        results.append(result)
    return results


def run_all(pages: list[Path], folder: Path, *, cuts: bool = True, echo: bool = True) -> list[Result]:
    """Every page's commands, page by page, each page in its own working folder under ``folder``, one fresh cache."""
    env = environment(folder / "cache")
    results = []
    for i, doc in enumerate(pages):
        results += run_document(doc, folder / f"{i:02d}_{doc.stem}", env, cuts=cuts, echo=echo)
    return results


def markdown(results: list[Result]) -> str:
    """The table of docs/benchmarks/guide_commands.md."""
    ran = [r for r in results if r.seconds is not None]
    total = sum(r.seconds for r in ran)
    intro = ("Written by `python benchmarks/run_guides.py` (`tests/test_guides_run.py`, slow, runs the same): every "
             "`mi-svbrdf` command of the bash blocks of README.md and docs/, in order per page, in a fresh folder per "
             "page, each in its own process (imports included), with an empty `MI_SVBRDF_CACHE` and only the bundled "
             f"data; {os.cpu_count()} cores, Python {platform.python_version()}, Dr.Jit's kernel cache warm. Exempt "
             "commands are not run (the reason is given); options appended to a command are the command's own. On a "
             "machine shared with other jobs a command's time varies several-fold from run to run.")
    counts = (f"{len(ran)} commands ran in {total:.0f} s; {sum(r.status == 'exempt' for r in results)} exempt; "
              f"{sum(r.status == 'failed' for r in results)} failed.")
    lines = ["# The documented commands run on the bundled data, with their wall time", "", intro, "", counts, "",
             "| page | command | status | seconds | note |", "|---|---|---|---|---|"]
    for r in results:
        seconds = f"{r.seconds:.1f}" if r.seconds is not None else ""
        lines.append(f"| {r.document} | `{r.command}` | {r.status} | {seconds} | {r.note} |")
    return "\n".join(lines) + "\n"


#: A row of :func:`markdown`'s table.
ROW = re.compile(r"^\| (?P<document>[^|]+) \| `(?P<command>[^`]+)` \| (?P<status>\w+) \| (?P<seconds>[\d.]*) \| "
                 r"(?P<note>.*) \|$")


def read_table(path: Path) -> list[Result]:
    """The rows of a table :func:`markdown` wrote (their output is not kept: empty).

    Raises:
        ValueError: ``path`` holds no such row.
    """
    rows = [m for m in map(ROW.match, path.read_text(encoding="utf-8").splitlines()) if m]
    if not rows:
        raise ValueError(f"{path}: expected the table of benchmarks/run_guides.py, got no row")
    return [Result(m["document"], m["command"], m["status"], float(m["seconds"]) if m["seconds"] else None,
                   m["note"]) for m in rows]


def updated(old: list[Result], new: list[Result]) -> list[Result]:
    """``old`` rows with the pages of ``new`` replaced by ``new``'s rows (a page not in ``old``: appended), in order."""
    pages = {r.document for r in new}
    out: list[Result] = []
    placed: set[str] = set()
    for r in old:
        if r.document not in pages:
            out.append(r)
        elif r.document not in placed:  # the page's first old row: its new rows go here
            out += [n for n in new if n.document == r.document]
            placed.add(r.document)
    return out + [n for n in new if n.document not in placed]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--only", action="append", default=[], metavar="PAGE",
                   help="run only this page (repeatable; a path relative to the repository)")
    p.add_argument("--out", default=str(TABLE), help=f"the table written (default: {TABLE.relative_to(ROOT)})")
    p.add_argument("--keep", default=None, metavar="DIR", help="run in DIR and keep it (default: a temporary folder)")
    p.add_argument("--as-written", action="store_true", help="run the commands of CUTS as documented")
    p.add_argument("--update", action="store_true",
                   help="replace only the rows of the pages run (--only) in the table --out holds, keep the others")
    args = p.parse_args(argv)
    if args.update and not args.only:
        p.error("--update: expected --only PAGE (the pages whose rows are replaced), got none")
    pages = [ROOT / page for page in args.only] if args.only else documents()
    if args.keep:
        results = run_all(pages, Path(args.keep), cuts=not args.as_written)
    else:
        with tempfile.TemporaryDirectory(prefix="run_guides_") as tmp:
            results = run_all(pages, Path(tmp), cuts=not args.as_written)
    failed = any(r.status == "failed" for r in results)
    if args.update:
        results = updated(read_table(Path(args.out)), results)
    write_text(args.out, markdown(results))
    print(f"wrote {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
