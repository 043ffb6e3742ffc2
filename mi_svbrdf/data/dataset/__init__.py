"""Scene-file driven dataset rendering (``mi-svbrdf dataset render``).

* :mod:`~mi_svbrdf.data.dataset.job` -- what to render: the job, the ranges of each render's shot
  (flash offset and strength, material rotation and zoom) and the draws;
* :mod:`~mi_svbrdf.data.dataset.renderer` -- one Mitsuba scene, re-used for every render;
* :mod:`~mi_svbrdf.data.dataset.output` -- shards, strips, the 8-bit photo, the manifest and resuming;
* :mod:`~mi_svbrdf.data.dataset.workers` -- local processes or a Ray cluster, and the run loop.

The entry points are re-exported here: ``from mi_svbrdf.data.dataset import RenderJob, render_dataset``.
"""
from mi_svbrdf.data.dataset.job import RenderJob, ShotRanges
from mi_svbrdf.data.dataset.output import decode_photo
from mi_svbrdf.data.dataset.renderer import SceneRenderer
from mi_svbrdf.data.dataset.workers import RenderSummary, render_dataset

__all__ = ["RenderJob", "RenderSummary", "SceneRenderer", "ShotRanges", "decode_photo", "render_dataset"]
