"""Scene-file driven dataset rendering (``mi-svbrdf dataset render``).

* :mod:`~mi_svbrdf.data.dataset.job` -- what to render: the job, its view/light ranges and the draws;
* :mod:`~mi_svbrdf.data.dataset.renderer` -- one Mitsuba scene, re-used for every render;
* :mod:`~mi_svbrdf.data.dataset.output` -- shards, strips, the manifest and resuming;
* :mod:`~mi_svbrdf.data.dataset.workers` -- local processes or a Ray cluster, and the run loop.
"""
