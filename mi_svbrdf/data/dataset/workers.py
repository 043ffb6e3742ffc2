"""Running a dataset job: :func:`render_dataset`, in this process, local processes or on a Ray cluster.

:func:`render_dataset` checks the scene, scans the materials, writes (or checks) the manifest,
finds the renders already done (:mod:`mi_svbrdf.data.dataset.output`) and hands the missing ones
to :class:`Run` as :class:`Task` items (one material and the indices of its missing renders);
:class:`Run` yields a :class:`TaskResult` per task as tasks finish. Every executor runs the same
:class:`Worker`: it loads the scene once (:class:`mi_svbrdf.data.dataset.renderer.SceneRenderer`),
then for each task reads the material, renders, and writes each render's strip and JSON itself.
A render's output depends on ``(seed, index)`` only (:mod:`mi_svbrdf.data.dataset.job`), so the
three executors write identical files, and a killed run resumes where it stopped.

- ``workers=1``: in this process (Dr.Jit and torch thread counts restored afterwards).
- ``workers=N``: ``concurrent.futures.ProcessPoolExecutor`` with the ``spawn`` start method;
  each process initialises Mitsuba and loads the scene once.
- ``ray=...``: one Ray actor per worker (``num_cpus=1`` each), fed through
  ``ray.util.ActorPool``. Ray is an optional dependency (``pip install ray``). The output folder
  must be on a file system every node sees.

Workers render with ``threads`` Dr.Jit threads (default 1: on the LLVM backend one thread per
process costs the least CPU per image; use more processes for more cores). The Dr.Jit thread
count is set *after* the scene is loaded: loading a scene with a Python plugin while Dr.Jit has
one thread hangs (Mitsuba 3.9.1 / Dr.Jit 1.5).

CPU time: per task with ``time.process_time`` in the worker (``TaskResult.cpu_task``: read,
transform, render, encode, write), and per worker process for its whole life
(``Run.worker_cpu``: interpreter start-up, imports, scene loading and kernel loading included).

Examples:
    >>> import tempfile, pathlib
    >>> from mi_svbrdf.io import strip
    >>> from mi_svbrdf.core import maps as M
    >>> bank = pathlib.Path(tempfile.mkdtemp())
    >>> strip.write_strip(bank / "grey.png", M.constant_maps(1, 16, 16))
    >>> job = RenderJob(materials=str(bank), out=tempfile.mkdtemp(), renders_per_material=2, size=16, spp=2)
    >>> summary = render_dataset(job, progress=False)
    >>> summary.rendered, sorted(p.name for p in (pathlib.Path(job.out) / "shard_0000").iterdir())
    (2, ['000000.json', '000000.png', '000001.json', '000001.png'])
"""
from __future__ import annotations

import dataclasses
import os
import socket
import sys
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import torch
from tqdm import tqdm

from mi_svbrdf import scenes
from mi_svbrdf.data.dataset.job import RenderJob, is_int, square_material
from mi_svbrdf.data.dataset.output import (
    default_compressor,
    done_renders,
    manifest,
    prepare_out,
    previous_compressor,
    write_render,
)
from mi_svbrdf.data.dataset.renderer import SceneRenderer, render_one, resolve_scene
from mi_svbrdf.variant import scene_variant
from mi_svbrdf.io.material_sets import MaterialSet

#: CPU seconds per image of the thesis's renderer (200 000 images in 16 h on 40 CPUs).
THESIS_CPU_SECONDS_PER_IMAGE = 16 * 3600 * 40 / 200_000
_READ_ERRORS = (ValueError, OSError, RuntimeError)


@dataclass(frozen=True)
class WorkerSpec:
    """Everything a worker needs (picklable)."""

    job: RenderJob  # the job, with absolute paths
    materials: MaterialSet  # the job's materials, in job order (on_error="raise")
    threads: int = 1  # Dr.Jit threads of the worker
    compressor: str = "zlib"  # deflate of the strip PNGs (output.COMPRESSORS), as in the manifest


@dataclass(frozen=True)
class Task:
    """Renders of one material."""

    material: int  # material index
    indices: tuple[int, ...]  # render indices (material * renders_per_material + r)


@dataclass(frozen=True)
class TaskResult:
    """What a worker did for one task."""

    material: int  # material index
    done: tuple[int, ...]  # render indices written
    failed: tuple[str, str] | None  # (material, reason) if the material could not be read
    worker: str  # "host:pid" of the worker
    cpu_task: float  # CPU seconds of this task (read, transform, render, encode, write)


def make_tasks(pending: Sequence[int], renders_per_material: int) -> list[Task]:
    """Group missing render indices by material, in index order."""
    groups: dict[int, list[int]] = {}
    for index in pending:
        groups.setdefault(index // renders_per_material, []).append(index)
    return [Task(m, tuple(indices)) for m, indices in groups.items()]


class Worker:
    """A loaded scene and the material set; :meth:`run` renders and writes one task."""

    def __init__(self, spec: WorkerSpec) -> None:
        import drjit as dr

        self.spec = spec
        job = spec.job
        self.renderer = SceneRenderer(job.scene, size=job.size, spp=job.spp, fov=job.shots.fov,
                                      params=job.params)
        dr.set_thread_count(spec.threads)  # after loading: see the module doc
        self.id = f"{socket.gethostname()}:{os.getpid()}"

    def run(self, task: Task) -> TaskResult:
        """Render and write every index of ``task``."""
        c0 = time.process_time()
        job = self.spec.job
        try:
            name, material = self.spec.materials[task.material]
        except _READ_ERRORS as err:
            entry = self.spec.materials.items[task.material]
            return self._result(task, (), (entry.name, str(err)), c0)
        material = square_material(material)
        out = Path(job.out)
        with scene_variant("cpu"):  # once per task, not per render (the scene is bound to it)
            for index in task.indices:
                maps, linear, record = render_one(job, self.renderer, material, name, task.material, index)
                write_render(out, job, index, maps, linear, record, self.spec.compressor)
        return self._result(task, task.indices, None, c0)

    def _result(self, task: Task, done: tuple[int, ...], failed: tuple[str, str] | None, c0: float) -> TaskResult:
        return TaskResult(task.material, done, failed, self.id, time.process_time() - c0)


class Run:
    """An iteration over ``tasks`` on the chosen executor (see the module doc).

    Iterating yields a :class:`TaskResult` per task as tasks finish. Afterwards ``workers`` is the
    number of workers started and ``worker_cpu`` their CPU seconds outside this process: for
    local processes ``getrusage(RUSAGE_CHILDREN)`` over the pool's life (start-up included), for
    Ray actors each actor process's ``time.process_time()`` at the end (0 in this process).
    """

    def __init__(self, spec: WorkerSpec, tasks: Sequence[Task], *, workers: int = 1, ray: str | None = None) -> None:
        self.spec, self.tasks, self.requested, self.ray = spec, list(tasks), workers, ray
        self.workers = 0
        self.worker_cpu = 0.0

    def __iter__(self) -> Iterator[TaskResult]:
        if not self.tasks:
            return iter(())
        if self.ray is not None:
            return self._ray()
        if self.requested == 1:
            return self._serial()
        return self._processes()

    # --------------------------------------------------------------------------- this process
    def _serial(self) -> Iterator[TaskResult]:
        import drjit as dr

        threads, torch_threads = dr.thread_count(), torch.get_num_threads()
        try:
            torch.set_num_threads(1)
            worker = Worker(self.spec)
            self.workers = 1
            for task in self.tasks:
                yield worker.run(task)
        finally:
            dr.set_thread_count(threads)
            torch.set_num_threads(torch_threads)

    # ------------------------------------------------------------------------ local processes
    def _processes(self) -> Iterator[TaskResult]:
        import multiprocessing
        import resource
        from concurrent.futures import ProcessPoolExecutor, as_completed

        def children_cpu() -> float:
            usage = resource.getrusage(resource.RUSAGE_CHILDREN)
            return usage.ru_utime + usage.ru_stime

        before = children_cpu()
        self.workers = min(self.requested, len(self.tasks))
        pool = ProcessPoolExecutor(self.workers, mp_context=multiprocessing.get_context("spawn"),
                                   initializer=_init_process, initargs=(self.spec,))
        try:
            futures = [pool.submit(_run_in_process, task) for task in self.tasks]
            for future in as_completed(futures):
                yield future.result()
        finally:
            pool.shutdown(wait=True, cancel_futures=True)  # the processes end and are waited for
            self.worker_cpu = children_cpu() - before

    # ------------------------------------------------------------------------------------ Ray
    def _ray(self) -> Iterator[TaskResult]:
        try:
            import ray
            from ray.util import ActorPool
        except ImportError as err:
            raise ValueError("ray: expected the optional dependency Ray (pip install ray), "
                             "got no module 'ray'") from err
        started = False
        if not ray.is_initialized():
            try:
                if self.ray == "local":
                    ray.init(num_cpus=self.requested if self.requested > 1 else None, include_dashboard=False,
                             logging_level="warning")
                else:
                    ray.init(address=self.ray, logging_level="warning")
            except ConnectionError as err:
                raise ValueError(f"ray: expected a running Ray cluster at {self.ray!r} (start one with "
                                 f"`ray start --head`, or use --ray local), got: {err}") from err
            started = True
        actors = []
        try:
            count = self.requested if self.requested > 1 else int(ray.cluster_resources().get("CPU", 1))
            actor_class = ray.remote(num_cpus=1)(RayWorker)
            spec_ref = ray.put(self.spec)
            actors = [actor_class.remote(spec_ref) for _ in range(max(1, min(count, len(self.tasks))))]
            self.workers = len(actors)
            pool = ActorPool(actors)
            yield from pool.map_unordered(lambda actor, task: actor.run.remote(task), self.tasks)
            self.worker_cpu = float(sum(ray.get([actor.cpu.remote() for actor in actors])))
        finally:
            for actor in actors:
                ray.kill(actor)
            if started:
                ray.shutdown()


# -------------------------------------------------------------------------- local processes

_WORKER: Worker | None = None


def _init_process(spec: WorkerSpec) -> None:
    global _WORKER
    torch.set_num_threads(1)
    _WORKER = Worker(spec)


def _run_in_process(task: Task) -> TaskResult:
    assert _WORKER is not None, "worker process not initialised"
    return _WORKER.run(task)


# ------------------------------------------------------------------------------------- Ray

class RayWorker:
    """The Ray actor: a :class:`Worker` in an actor process."""

    def __init__(self, spec: WorkerSpec) -> None:
        torch.set_num_threads(1)
        self.worker = Worker(spec)

    def run(self, task: Task) -> TaskResult:
        """Run one task."""
        return self.worker.run(task)

    def cpu(self) -> float:
        """CPU seconds of this actor's process so far (all threads, since the process started)."""
        return time.process_time()


# ------------------------------------------------------------------------------------ the run

@dataclass
class RenderSummary:
    """What :func:`render_dataset` did."""

    out: Path  # output folder
    total: int  # renders of the job
    already_done: int  # renders found done at the start
    rendered: int  # renders made by this run
    remaining: int  # renders still missing after this run (failed materials, limit)
    failed: list[tuple[str, str]]  # (material, reason) of materials that could not be read
    skipped_at_scan: list[tuple[str, str]]  # (path, reason) of entries the material scan skipped
    seconds: float  # wall time of the run
    cpu_seconds: float  # CPU time of this process and of every worker process (their start-up included)
    render_cpu_seconds: float  # CPU time of the workers' tasks only (read, transform, render, write)
    workers: int  # workers started: processes or Ray actors (1: this process; 0: nothing to do)
    executor: str  # "serial", "processes" or "ray"

    @property
    def images_per_second(self) -> float:
        """Renders made per wall-clock second."""
        return self.rendered / max(self.seconds, 1e-9)

    @property
    def cpu_per_image(self) -> float:
        """CPU seconds per render, everything included."""
        return self.cpu_seconds / max(self.rendered, 1)

    @property
    def render_cpu_per_image(self) -> float:
        """CPU seconds per render in the workers' tasks (start-up excluded)."""
        return self.render_cpu_seconds / max(self.rendered, 1)

    def line(self) -> str:
        """The one-line summary printed at the end of a run."""
        ratio = THESIS_CPU_SECONDS_PER_IMAGE / max(self.cpu_per_image, 1e-12)
        return (f"rendered {self.rendered} images ({self.already_done} already done, {self.remaining} missing, "
                f"{len(self.failed)} materials failed) in {self.seconds:.2f} s with {self.workers} "
                f"{self.executor} worker(s): {self.images_per_second:.2f} images/s, "
                f"{self.cpu_per_image:.4f} CPU·s per image ({self.render_cpu_per_image:.4f} in render tasks; "
                f"thesis {THESIS_CPU_SECONDS_PER_IMAGE:.1f}: {ratio:.0f}x less)")


def absolute_job(job: RenderJob) -> RenderJob:
    """``job`` with absolute ``materials``, ``out`` and scene path (bundled scene names stay names)."""
    scene = job.scene if job.scene in scenes.scene_names() else str(resolve_scene(job.scene))
    return dataclasses.replace(job, scene=scene, materials=str(Path(job.materials).expanduser().resolve()),
                               out=str(Path(job.out).expanduser().resolve()))


def render_dataset(job: RenderJob, *, workers: int = 1, ray: str | None = None, threads: int = 1,
                   limit: int | None = None, progress: bool = True) -> RenderSummary:
    """Render (or resume) the dataset of ``job`` into ``job.out`` (see the module doc).

    Args:
        job: what to render.
        workers: local worker processes (1: this process), or Ray actors with ``ray`` (1: one per
            CPU of the cluster).
        ray: ``None`` (local), ``"auto"`` (the running cluster: ``RAY_ADDRESS`` or ``ray start``),
            an address (``host:6379``, ``ray://host:10001``) or ``"local"`` (start Ray here). An
            already initialised Ray connection is used as it is. ``out`` must be on a file system
            every node sees.
        threads: Dr.Jit threads per worker.
        limit: render at most this many missing images (in index order), then stop; ``None``: all.
        progress: show a progress bar.

    Returns:
        A :class:`RenderSummary`.

    Raises:
        ValueError: bad arguments, a scene breaking the contract, no materials, a manifest mismatch.
    """
    if not is_int(workers, 1) or not is_int(threads, 1):
        raise ValueError(f"workers, threads: expected integers >= 1, got {workers!r}, {threads!r}")
    if limit is not None and not is_int(limit, 0):
        raise ValueError(f"limit: expected None or an integer >= 0, got {limit!r}")
    start, cpu_start = time.perf_counter(), time.process_time()
    job = absolute_job(job)
    SceneRenderer(job.scene, size=8, spp=1, fov=job.shots.fov, params=job.params)  # fail early on a bad scene
    materials = MaterialSet(job.materials, size=None, on_error="raise")
    if len(materials) == 0:
        raise ValueError(f"materials: expected a folder with at least one readable material, got none in "
                         f"{job.materials} ({len(materials.skipped)} skipped)")
    names = [entry.name for entry in materials.items]
    out = Path(job.out)
    compressor = previous_compressor(out) or default_compressor()
    prepare_out(out, manifest(job, names, compressor, resolve_scene(job.scene)))
    total = len(names) * job.renders_per_material
    done = done_renders(out, total, job.shard_size)
    pending = [i for i in range(total) if i not in done]
    if limit is not None:
        pending = pending[:limit]
    spec = WorkerSpec(job, materials, threads, compressor)
    bar = tqdm(total=total, initial=len(done), desc=f"dataset -> {out}", unit="img", disable=not progress,
               file=sys.stderr)
    run = Run(spec, make_tasks(pending, job.renders_per_material), workers=workers, ray=ray)
    rendered, failed, task_cpu = 0, [], 0.0
    try:
        for result in run:
            rendered += len(result.done)
            task_cpu += result.cpu_task
            if result.failed is not None:
                failed.append(result.failed)
            bar.update(len(result.done))
    finally:
        bar.close()
    cpu = time.process_time() - cpu_start + run.worker_cpu
    executor = "ray" if ray is not None else ("processes" if workers > 1 else "serial")
    remaining = total - len(done_renders(out, total, job.shard_size))
    return RenderSummary(out, total, len(done), rendered, remaining, failed,
                         [(str(p), r) for p, r in materials.skipped], time.perf_counter() - start, cpu,
                         task_cpu, run.workers, executor)
