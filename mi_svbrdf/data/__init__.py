"""Training and test data: procedural materials, augmentation, simulated photos, datasets.

* :mod:`~mi_svbrdf.data.procedural` -- nine vectorised material classes;
* :mod:`~mi_svbrdf.data.augment` -- mixing, rotation/scale/crop with consistent normals;
* :mod:`~mi_svbrdf.data.examples` -- two small built-in example materials;
* :mod:`~mi_svbrdf.data.bank` -- deterministic banks of procedural materials on disk;
* :mod:`~mi_svbrdf.data.photo_setups` -- random cameras, flashes and photo pipelines of simulated photos;
* :mod:`~mi_svbrdf.data.parameter_split` -- the parameter ranges training never draws;
* :mod:`~mi_svbrdf.data.simulator` -- the online capture simulator (an ``IterableDataset``);
* :mod:`~mi_svbrdf.data.cached_set` -- the one base of the evaluation sets built once and cached;
* :mod:`~mi_svbrdf.data.heldout` -- the fixed held-out set rendered by the simulator;
* :mod:`~mi_svbrdf.data.foreign` -- held-out materials under capture parameters training never draws;
* :mod:`~mi_svbrdf.data.realistic` -- calibrated captures with the nuisances of real photos, and clean twins;
* :mod:`~mi_svbrdf.data.large_scale` -- ambient photos, exemplars and maps of large surfaces (the large-scale net);
* :mod:`~mi_svbrdf.data.dataset` -- rendering a bank through a Mitsuba scene file into a dataset;
* :mod:`~mi_svbrdf.data.example_photos` -- re-makes the bundled example photos (``assets/``).
* :mod:`~mi_svbrdf.data.scan_examples` -- the phone-sized photos of ``rectify example`` / ``scan example``, cached.
"""
