"""The figures the README and guides state that code knows agree with their source, as ``docs/results.md`` does
(``tests/test_cli_readme.py``): the bundled nets' steps and training hours with the weights' manifest, the scan
guide's timings with the documented commands' run (``docs/benchmarks/guide_commands.md``, written by
``benchmarks/run_guides.py``), and the README's picture and caption with the contact sheet ``capture`` writes
(``benchmarks/readme_figure.py`` remakes the picture). A figure reworded out of its sentence fails here with the
sentence expected: reword the pattern with it."""
from __future__ import annotations

import importlib.util
import json
import re
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
MANIFEST = json.loads((ROOT / "mi_svbrdf" / "weights" / "manifest.json").read_text(encoding="utf-8"))


def _thousands(n: int) -> str:
    """``15500`` -> ``"15 500"``, as the pages write counts."""
    return f"{int(n):,}".replace(",", " ")


def _figures(page: str, pattern: str) -> tuple[str, ...]:
    """The groups of ``pattern``'s match in one paragraph of ``page`` (its line breaks read as spaces)."""
    for paragraph in (ROOT / page).read_text(encoding="utf-8").split("\n\n"):
        match = re.search(pattern, re.sub(r"\s+", " ", paragraph))
        if match:
            return match.groups()
    raise AssertionError(f"{page}: expected a paragraph matching {pattern!r}, found none (reworded? update this test)")


def test_capture_guide_states_the_bundled_nets_steps_and_hours_of_the_manifest() -> None:
    single, multi = MANIFEST["single"], MANIFEST["multi"]
    page = "docs/guides/capture.md"
    assert _figures(page, r"Single-image net: ([\d ]+?) steps, ([\d.]+) h") == (
        _thousands(single["steps"]), f"{single['training_hours']:.1f}")
    assert _figures(page, r"the `single` recipe's ([\d ]+?) in ([\d.]+) h") == (
        _thousands(single["continues"]["steps"]), f"{single['continues']['training_hours']:.1f}")
    assert _figures(page, r"multi-image net: ([\d ]+?) steps, ([\d.]+) h") == (
        _thousands(multi["steps"]), f"{multi['training_hours']:.1f}")
    assert _figures(page, r"fine-tune's 1 500 \(([\d ]+?) steps, ([\d.]+) h\)") == (
        _thousands(multi["continues"]["steps"]), f"{multi['continues']['training_hours']:.1f}")


def test_training_and_large_surface_guides_state_the_manifest_steps() -> None:
    assert _figures("docs/guides/training.md", r"Bundled at step ([\d ]+?)\.") == (
        _thousands(MANIFEST["single"]["steps"]),)
    large = MANIFEST["large"]
    assert _figures("docs/guides/large-surfaces.md", r"bundled compact net \((\d+) steps of the recipe `large`, "
                                                     r"(\d+) hours") == (str(large["steps"]),
                                                                         f"{large['training_hours']:.0f}")


def _run_guides():
    spec = importlib.util.spec_from_file_location("run_guides", ROOT / "benchmarks" / "run_guides.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # its dataclass looks its module up
    spec.loader.exec_module(module)
    return module


def test_scan_guide_states_the_step_times_of_the_documented_run() -> None:
    run_guides = _run_guides()
    rows = [r for r in run_guides.read_table(run_guides.TABLE)
            if r.command == "mi-svbrdf scan example --frame tags -o out/scan"]
    assert len(rows) == 1 and rows[0].status == "ok", rows
    steps = run_guides.steps_of_note(rows[0].note)
    assert set(steps) == {"rectify", "optimize", "export", "view"}, \
        f"{run_guides.TABLE.name}: the scan's row has no step times ({rows[0].note!r}): run python " \
        "benchmarks/run_guides.py --only docs/guides/scan.md --update"
    page = "docs/guides/scan.md"
    stated = _figures(page, r"rectifying them ([\d.]+) s, .*?\(optimize ([\d.]+) s\), .*?export and view ([\d.]+) s")
    assert stated == (f"{steps['rectify']:.1f}", f"{steps['optimize']:.1f}", f"{steps['export'] + steps['view']:.1f}"), \
        f"{page}: its times are not those of {run_guides.TABLE.name}'s scan row ({steps})"


def _sheet_labels() -> list[str]:
    """The labels of the contact sheet ``capture example`` writes: one photo, the four maps, the relit panels."""
    import torch

    from mi_svbrdf.cli.capture import SHEET_LIGHTS, light_label
    from mi_svbrdf.core.maps import preview_panels
    from mi_svbrdf.core.metrics import eval_lights

    where = eval_lights(SHEET_LIGHTS)
    maps = list(preview_panels(torch.zeros(1, 10, 1, 1)))
    return ["input 1", *maps, *(f"relit: {light_label(where.light[k].tolist(), where.view[k].tolist())}"
                                for k in range(SHEET_LIGHTS))]


def test_readme_picture_carries_the_labels_capture_writes_and_its_caption_names_them() -> None:
    from PIL import Image

    from mi_svbrdf.io.figures import LABEL_PX, labelled_row

    labels = _sheet_labels()
    picture = np.asarray(Image.open(ROOT / "docs" / "images" / "capture_example.png").convert("RGB"))
    side = 256  # the single net's resolution: capture's maps and panels
    assert picture.shape == (side + LABEL_PX, side * len(labels), 3), \
        "docs/images/capture_example.png is not capture's contact sheet: run python benchmarks/readme_figure.py"
    expected = labelled_row([(label, np.zeros((side, side, 3), np.uint8)) for label in labels])
    assert np.array_equal(picture[:LABEL_PX], expected[:LABEL_PX]), \
        f"docs/images/capture_example.png's labels are not {labels}: run python benchmarks/readme_figure.py"
    caption = re.sub(r"\s+", " ", (ROOT / "README.md").read_text(encoding="utf-8")).split("capture_example.png)", 1)[1]
    caption = caption.split("*", 2)[1]
    for label in labels[-3:]:
        assert f'"{label.removeprefix("relit: ")}"' in caption, f"README: the picture's caption does not name {label!r}"
