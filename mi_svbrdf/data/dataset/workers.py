"""Where dataset renders run: this process, local processes or a Ray cluster.

:class:`Run` takes the work of :func:`mi_svbrdf.data.dataset.job.render_dataset` as :class:`Task`
items (one material and the indices of its missing renders) and yields a :class:`TaskResult`
per task as tasks finish. Every executor runs the same :class:`Worker`: it loads the capture
scene once (:class:`mi_svbrdf.data.dataset.job.SceneRenderer`), then for each task reads the
material, renders, and writes each render's strip and JSON itself. A render's output depends on
``(seed, index)`` only, so the three executors write identical files.

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
"""
from __future__ import annotations

import os
import socket
import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import torch

from mi_svbrdf.data.dataset.job import (RenderJob, SceneRenderer, render_one, square_material,
                                      write_render)
from mi_svbrdf.io.material_sets import MaterialSet

_READ_ERRORS = (ValueError, OSError, RuntimeError)


@dataclass(frozen=True)
class WorkerSpec:
    """Everything a worker needs (picklable)."""

    job: RenderJob  # the job, with absolute paths
    materials: MaterialSet  # the job's materials, in job order (on_error="raise")
    threads: int = 1  # Dr.Jit threads of the worker
    compressor: str = "zlib"  # deflate of the strip PNGs (dataset_output.COMPRESSORS), as in the manifest


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
    """A loaded capture scene and the material set; :meth:`run` renders and writes one task."""

    def __init__(self, spec: WorkerSpec) -> None:
        import drjit as dr

        self.spec = spec
        job = spec.job
        self.renderer = SceneRenderer(job.scene, size=job.size, spp=job.spp, fov=job.capture.fov,
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


