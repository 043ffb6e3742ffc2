"""Shared fixtures (random materials), the split of the suite into fast and slow tests, the CUDA marker, the
Mitsuba variant the suite runs under, and docstring examples that leave no files behind
(:func:`_doctests_in_a_temporary_folder`).

``MI_SVBRDF_TEST_VARIANT=NAME`` (e.g. ``scalar_rgb``) makes ``NAME`` the active Mitsuba variant before
:mod:`mi_svbrdf` is imported, as a user's own code or another library may: mi_svbrdf's kernels must then run on
their tensors' device all the same (``.ci/run`` runs the kernel tests a second time so, below). Unset: the
variant the import picks (``llvm_ad_rgb`` here, ``cuda_ad_rgb`` on a GPU machine).

A variant can only change what a test sees if the test's own process launches a Dr.Jit kernel or asks Mitsuba for
its variant (the commands some tests run in a subprocess start with the import's default). Every run under the
import's own variant records, per test, what it did: the kernels it launched (their hashes, from Dr.Jit's kernel
history), the library code paths that called ``mi.variant`` / ``mi.set_variant``, and its seconds, in pytest's
cache (``mi_svbrdf/kernel_tests``). ``--kernel-tests`` then runs a cover of them: the fewest seconds of tests that
together launch every kernel and take every variant-asking path the recorded tests do (a greedy weighted set
cover), and the tests never recorded. A kernel that follows the variant instead of its tensors' device fails in
any test that launches it: one test per kernel finds it. ``.ci/run``'s variant pass uses it after the default pass
recorded the whole suite.

``MI_SVBRDF_TEST_LLVM_WIDTH=W`` (4, 8 or 16) makes Dr.Jit's LLVM backend compile its kernels ``W`` lanes wide
(``jit_llvm_set_target``, the CPU and its features kept) before :mod:`mi_svbrdf` is imported, as a CPU with
narrower or wider vector registers would: SSE4 (4), AVX2 (8), AVX-512 (16). Floating-point sums then add in
another order and a fit's last bits differ, so a test must assert what holds at every width (a converged quantity
or a margin measured at each), never the last bits of an unsettled fit; ``.ci/run`` runs the optimiser's, the
loss's and self-calibration's tests at the three widths. Unset: the width Dr.Jit picks for the machine's CPU. The
commands some tests run in a subprocess start at that native width too.
"""
from __future__ import annotations

import ctypes
import os
import sys
import threading
import time

# The tests import torch before mi_svbrdf (the variant must be set first): without a stated wait policy, import
# mi_svbrdf would then split the cores between PyTorch and Dr.Jit (mi_svbrdf.threads.share_cores). The suite runs
# as a user who imports mi_svbrdf first does: OpenMP's threads sleep when idle, and every library keeps its pool.
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")

import drjit as dr
import mitsuba as mi
import pytest
import torch

#: Dr.Jit's LLVM vector widths a test run may ask for (``MI_SVBRDF_TEST_LLVM_WIDTH``).
LLVM_WIDTHS = (4, 8, 16)


def _llvm_function(name: str, restype: object, argtypes: list[object] | None = None) -> ctypes._CFuncPtr:
    """A function of Dr.Jit's core library (``libdrjit-core``, already loaded by ``import drjit``) by its exported
    C++ name: the LLVM backend's target functions are exported but not bound in Python."""
    folder = os.path.dirname(dr.__file__)
    names = sorted(name for name in os.listdir(folder) if name.startswith("libdrjit-core."))
    try:
        function = getattr(ctypes.CDLL(os.path.join(folder, names[0])), name)
    except (IndexError, OSError, AttributeError) as error:
        raise pytest.UsageError(f"MI_SVBRDF_TEST_LLVM_WIDTH: expected Dr.Jit {dr.__version__}'s libdrjit-core in "
                                f"{folder} to export {name}, got {error!r}") from None
    function.restype = restype
    if argtypes is not None:
        function.argtypes = argtypes
    return function


def llvm_vector_width() -> int:
    """The vector width Dr.Jit's LLVM backend compiles its kernels for (lanes of 32 bits)."""
    return int(_llvm_function("_Z21jit_llvm_vector_widthv", ctypes.c_uint32)())


def set_llvm_vector_width(width: int) -> None:
    """Make Dr.Jit's LLVM backend compile the kernels of this process ``width`` lanes wide, its target CPU and
    features kept (``jit_llvm_set_target``): before any kernel is compiled, as Dr.Jit's kernel cache is keyed by
    the IR, which names the width. Read back: a Dr.Jit whose LLVM backend did not start raises."""
    cpu = _llvm_function("_Z19jit_llvm_target_cpuv", ctypes.c_char_p)()
    features = _llvm_function("_Z24jit_llvm_target_featuresv", ctypes.c_char_p)()
    set_target = _llvm_function("_Z19jit_llvm_set_targetPKcS0_j", None,
                                [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_uint32])
    set_target(cpu, features, width)
    if llvm_vector_width() != width:
        raise pytest.UsageError(f"MI_SVBRDF_TEST_LLVM_WIDTH: expected Dr.Jit's LLVM backend to take width {width}, "
                                f"got {llvm_vector_width()} (is its LLVM library loaded? docs/install.md)")


#: The LLVM vector width set before the import (None: Dr.Jit's own for this CPU).
TEST_LLVM_WIDTH: int | None = None
if os.environ.get("MI_SVBRDF_TEST_LLVM_WIDTH"):
    _asked = os.environ["MI_SVBRDF_TEST_LLVM_WIDTH"].strip()
    if _asked not in {str(w) for w in LLVM_WIDTHS}:
        raise pytest.UsageError(f"MI_SVBRDF_TEST_LLVM_WIDTH: expected one of {', '.join(map(str, LLVM_WIDTHS))}, "
                                f"got {_asked!r}")
    TEST_LLVM_WIDTH = int(_asked)
    set_llvm_vector_width(TEST_LLVM_WIDTH)

#: The variant set before the import (None: the import's default).
TEST_VARIANT = os.environ.get("MI_SVBRDF_TEST_VARIANT") or None
if TEST_VARIANT is not None:
    if TEST_VARIANT not in mi.variants():
        raise pytest.UsageError(f"MI_SVBRDF_TEST_VARIANT: expected one of {mi.variants()}, got {TEST_VARIANT!r}")
    mi.set_variant(TEST_VARIANT)

import mi_svbrdf  # noqa: E402, F401  (keeps a variant already set, else picks one; registers plugins)

#: Why a ``@pytest.mark.cuda`` test is skipped (None: a CUDA device exists).
NO_CUDA = None if torch.cuda.is_available() and "cuda_ad_rgb" in mi.variants() else (
    "needs a CUDA device (torch.cuda.is_available() is False)" if not torch.cuda.is_available()
    else "needs Mitsuba's cuda_ad_rgb variant (not in this Mitsuba build)")

#: Tests that take minutes on 2 cores (``pytest --durations``): node-id prefixes marked ``slow`` here. The
#: default run skips them (``-m "not slow"`` in pyproject.toml); ``python -m pytest -q -m slow`` runs them,
#: as CI's second step does (.ci/run). Others carry ``@pytest.mark.slow`` themselves.
SLOW = ("tests/test_bundled_accuracy.py", "tests/test_notebooks.py",
        "tests/test_priors.py::test_refine_never_worse_than_its_net",
        "tests/test_priors.py::test_optimizer_not_worse_than_trivial_at_few_photos",
        "tests/test_priors.py::test_longer_budget_not_worse_per_map")


#: pytest's cache key of the record: {node id: True if the test launched a kernel or asked for the variant}.
KERNEL_TESTS_KEY = "mi_svbrdf/kernel_tests"


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--kernel-tests", action="store_true",
                     help="run only the tests whose process launched a Dr.Jit kernel or asked Mitsuba for its "
                          "variant when last run (and those never run); the record is in pytest's cache")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mark the tests of :data:`SLOW` slow; skip the ``cuda`` tests where no CUDA device exists; with
    ``--kernel-tests``, deselect the tests recorded as launching no kernel (module docstring)."""
    for item in items:
        if item.nodeid.startswith(SLOW):
            item.add_marker(pytest.mark.slow)
        if NO_CUDA is not None and item.get_closest_marker("cuda") is not None:
            item.add_marker(pytest.mark.skip(reason=NO_CUDA))
    if config.getoption("--kernel-tests"):
        cache = getattr(config, "cache", None)  # None under -p no:cacheprovider
        record = cache.get(KERNEL_TESTS_KEY, {}) if cache is not None else {}
        if not record:
            raise pytest.UsageError("--kernel-tests: expected a record of an earlier run in pytest's cache "
                                    f"({KERNEL_TESTS_KEY}), got none: run the suite once without it first")
        chosen = kernel_cover({item.nodeid: record[item.nodeid] for item in items if item.nodeid in record})
        kept = [item for item in items if item.nodeid not in record or item.nodeid in chosen]
        dropped = [item for item in items if item.nodeid in record and item.nodeid not in chosen]
        if dropped:
            config.hook.pytest_deselected(items=dropped)
            items[:] = kept


def kernel_cover(record: dict[str, object]) -> set[str]:
    """The tests ``--kernel-tests`` runs, of those in ``record`` (``{node id: {"features": [...], "seconds": s}}``):
    a greedy weighted set cover of every feature (kernel hash, variant-asking path), cheapest per new feature first.
    A test recorded in the former form (True / False) is kept when True."""
    features = {node: set(entry["features"]) for node, entry in record.items() if isinstance(entry, dict)}
    seconds = {node: max(float(entry["seconds"]), 1e-3) for node, entry in record.items() if isinstance(entry, dict)}
    chosen = {node for node, entry in record.items() if entry is True}
    uncovered = set().union(*features.values()) if features else set()
    while uncovered:
        node = max(features, key=lambda t: (len(features[t] & uncovered) / seconds[t], t))
        chosen.add(node)
        uncovered -= features.pop(node)
    return chosen


def _kernel_feature(launch: dict) -> str:
    """A launch as a feature of the cover: its kernel's hash (Dr.Jit's built-in kernels, without one: their type)."""
    return f"kernel {launch.get('hash') or launch.get('type')}"


def _caller_path() -> str:
    """The library functions (``file:function``, outermost first) on the stack that led to a variant call, or the
    first caller outside Mitsuba when none: one path per way the code asks for the variant."""
    frame, path = sys._getframe(2), []
    while frame is not None:
        name = frame.f_code.co_filename
        if f"{os.sep}mi_svbrdf{os.sep}" in name and f"{os.sep}tests{os.sep}" not in name:
            path.append(f"{name.rsplit(os.sep + 'mi_svbrdf' + os.sep, 1)[1]}:{frame.f_code.co_name}")
        frame = frame.f_back
    if path:
        return " < ".join(path)
    frame = sys._getframe(2)
    return f"{os.path.basename(frame.f_code.co_filename)}:{frame.f_code.co_name}"


class _KernelRecorder:
    """Records, per test, the kernels its process launched (hashes) and the library paths that called
    ``mi.variant`` / ``mi.set_variant`` while the test ran (setup, call and teardown), and its seconds. Some tests
    read (and so clear) Dr.Jit's kernel history themselves or switch it off: the history is switched on again
    before each test and what they read is seen too.

    Dr.Jit keeps every launch's IR in its history until it is read (about 0.1 MB a launch of the fused loss: 1.8 GB
    for a fit of 2000 steps), so a thread reads it every :attr:`DRAIN_SECONDS` while a test runs and keeps only the
    hashes, until the test reads, clears or switches the history itself (then what it reads is its own)."""

    #: How often the history is read (and so freed) while a test runs.
    DRAIN_SECONDS = 0.5

    def __init__(self) -> None:
        self.record: dict[str, dict[str, object]] = {}
        self.features: set[str] = set()
        self._history = dr.kernel_history
        self._clear = dr.kernel_history_clear
        self._set_flag = dr.set_flag
        self._lock = threading.Lock()
        self._draining = False
        self._stop = threading.Event()

    def _drain(self) -> None:
        """Read the history now (which frees it), keeping only its launches' features."""
        self.features.update(map(_kernel_feature, self._history()))

    def _drain_while_tests_run(self) -> None:
        while not self._stop.wait(self.DRAIN_SECONDS):
            with self._lock:
                if self._draining:
                    self._drain()

    def _hand_over(self) -> None:
        """The test reads, clears or switches the history itself: a last read, then no more for this test."""
        with self._lock:
            if self._draining:
                self._draining = False
                self._drain()

    def install(self) -> None:
        def history(*args: object, **kwargs: object) -> list:
            self._hand_over()
            launches = self._history(*args, **kwargs)
            self.features.update(map(_kernel_feature, launches))
            return launches

        def clear(*args: object, **kwargs: object) -> object:
            self._hand_over()
            return self._clear(*args, **kwargs)

        def set_flag(flag: dr.JitFlag, *args: object, **kwargs: object) -> object:
            if flag == dr.JitFlag.KernelHistory:
                self._hand_over()
            return self._set_flag(flag, *args, **kwargs)

        dr.kernel_history, dr.kernel_history_clear, dr.set_flag = history, clear, set_flag
        for name in ("variant", "set_variant"):
            real = getattr(mi, name)

            def asking(*args: object, _real=real, _name=name, **kwargs: object) -> object:
                self.features.add(f"{_name} from {_caller_path()}")
                return _real(*args, **kwargs)

            setattr(mi, name, asking)
        threading.Thread(target=self._drain_while_tests_run, name="kernel history drain", daemon=True).start()

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(self, item: pytest.Item):  # noqa: ANN201 (a hook wrapper)
        self._set_flag(dr.JitFlag.KernelHistory, True)
        self._clear()
        self.features = set()
        start = time.perf_counter()
        with self._lock:
            self._draining = True
        yield
        with self._lock:
            self._draining = False
            self._drain()
        if self.features:
            self.record[item.nodeid] = {"features": sorted(self.features),
                                        "seconds": round(time.perf_counter() - start, 3)}
        else:
            self.record[item.nodeid] = False

    def pytest_unconfigure(self, config: pytest.Config) -> None:
        self._stop.set()

    def pytest_sessionfinish(self, session: pytest.Session) -> None:
        # Recorded under the import's own variant only: under another, Mitsuba's scalar variants launch no kernel;
        # and at Dr.Jit's own LLVM width only: another width compiles the same kernels under other hashes.
        cache = getattr(session.config, "cache", None)  # None under -p no:cacheprovider
        if cache is not None and self.record and TEST_VARIANT is None and TEST_LLVM_WIDTH is None:
            merged = dict(cache.get(KERNEL_TESTS_KEY, {}))
            merged.update(self.record)
            cache.set(KERNEL_TESTS_KEY, merged)


def _doctests_in_a_temporary_folder() -> None:
    """Every docstring's examples run (``doctest.testmod``, ``run_docstring_examples``: one ``DocTestRunner.run``
    each) with :mod:`tempfile`'s folder set to a fresh one that is removed after: what the examples write with
    ``tempfile.mkdtemp()`` and the like does not outlive them (a user's example keeps its files; the suite's must not
    pile up in the machine's temporary folder)."""
    import doctest
    import tempfile

    if getattr(doctest.DocTestRunner.run, "_mi_svbrdf_temporary", False):
        return
    real = doctest.DocTestRunner.run

    def run(self: doctest.DocTestRunner, test: doctest.DocTest, *args: object, **kwargs: object) -> object:
        saved = tempfile.tempdir
        with tempfile.TemporaryDirectory(prefix="mi_svbrdf_doctest_") as folder:
            tempfile.tempdir = folder
            try:
                return real(self, test, *args, **kwargs)
            finally:
                tempfile.tempdir = saved

    run._mi_svbrdf_temporary = True
    doctest.DocTestRunner.run = run


def pytest_configure(config: pytest.Config) -> None:
    recorder = _KernelRecorder()
    recorder.install()
    config.pluginmanager.register(recorder, "mi_svbrdf_kernel_recorder")
    _doctests_in_a_temporary_folder()


def _width_header() -> str:
    """The LLVM vector width the tests run at, and who chose it, for pytest's header."""
    if TEST_LLVM_WIDTH is not None:
        return f"{TEST_LLVM_WIDTH} (MI_SVBRDF_TEST_LLVM_WIDTH)"
    try:
        return f"{llvm_vector_width()} (chosen by Dr.Jit for this CPU)"
    except pytest.UsageError:  # a Dr.Jit build that does not export it: the header only
        return "unknown (chosen by Dr.Jit for this CPU)"


def pytest_report_header(config: pytest.Config) -> str:
    return (f"mitsuba variant: {mi.variant()} "
            f"({'MI_SVBRDF_TEST_VARIANT' if TEST_VARIANT else 'chosen by import mi_svbrdf'}); "
            f"Dr.Jit LLVM vector width: {_width_header()}; "
            f"cuda: {'yes' if NO_CUDA is None else 'no'}")


def random_maps(batch: int, height: int, width: int, *, seed: int = 0, rough_range: tuple[float, float] = (0.0, 1.0),
                max_tilt: float = 1.2, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """Random valid maps: unit normals tilted up to ``max_tilt`` radians, albedos and roughness uniform."""
    g = torch.Generator().manual_seed(seed)
    theta = torch.rand(batch, 1, height, width, generator=g) * max_tilt
    phi = torch.rand(batch, 1, height, width, generator=g) * 6.283185307
    n = torch.cat([torch.sin(theta) * torch.cos(phi), torch.sin(theta) * torch.sin(phi), torch.cos(theta)], 1)
    d = torch.rand(batch, 3, height, width, generator=g)
    lo, hi = rough_range
    r = lo + (hi - lo) * torch.rand(batch, 1, height, width, generator=g)
    s = torch.rand(batch, 3, height, width, generator=g)
    return torch.cat([n, d, r, s], 1).to(dtype)


@pytest.fixture
def cpu_scene_variant():
    """The CPU's Mitsuba variant for a test that builds and renders Mitsuba objects itself (``mi.load_dict``,
    ``mi.Vector3f``, ...): they are bound to the active variant, which ``MI_SVBRDF_TEST_VARIANT`` may have set to
    another (``pytestmark = pytest.mark.usefixtures("cpu_scene_variant")``)."""
    from mi_svbrdf.variant import scene_variant

    with scene_variant("cpu") as name:
        yield name


@pytest.fixture
def maps_factory():
    return random_maps


def export_tiny_net(folder, kind: str, resolution: int) -> None:
    """A tiny random ``kind`` net saved like a training checkpoint and bundled into ``folder``
    (weights + manifest), for tests of the network paths that must not depend on trained weights
    (``kind="large"``: exemplars of 16 px, ``resolution`` its tile; the checkpoint stays beside the weights)."""
    from mi_svbrdf.nets.network import build_network, network_config
    from mi_svbrdf.nets.weights import export_weights

    torch.manual_seed({"single": 1, "multi": 2, "large": 3}[kind])
    large = {"exemplar_features": (4, 8, 8, 8), "exemplar_size": 16} if kind == "large" else {}
    cfg = network_config("compact", kind, encoder_features=(8, 16, 16, 16), last_features=8, resolution=resolution,
                         **large)
    ckpt = folder / f"{kind}_checkpoint.pt"
    torch.save({"net_config": cfg.to_dict(), "model": build_network(cfg).state_dict(),
                "config": {"preset": "compact"}, "step": 0, "seconds": 0.0}, ckpt)
    export_weights(ckpt, folder=folder)


@pytest.fixture(scope="module")
def one_torch_thread():
    """Tiny tensors: torch's second OpenMP thread only contends with Dr.Jit's pool (measured
    1.4 s vs 0.03 s per tiny-net call on a loaded 2-core machine)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture(scope="module")
def one_thread():
    """One torch thread for a test module (``pytestmark = pytest.mark.usefixtures("one_thread")``), restored after."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.fixture
def forward_sizes(monkeypatch: pytest.MonkeyPatch) -> list[tuple[int, int]]:
    """The sizes ``mi_svbrdf.optim.fit`` builds its forward models at, in order (a spy on ``forward_for``)."""
    import mi_svbrdf.optim.fit as fit

    sizes: list[tuple[int, int]] = []
    real = fit.forward_for

    def spy(spec, size, *args, **kwargs):
        sizes.append(tuple(size))
        return real(spec, size, *args, **kwargs)

    monkeypatch.setattr(fit, "forward_for", spy)
    return sizes
