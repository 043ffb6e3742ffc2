"""The learned methods: networks, their training, the bundled weights and inference.

* :mod:`~mi_svbrdf.nets.network` -- the single-image U-Net and the multi-image network (``NetConfig``);
* :mod:`~mi_svbrdf.nets.fusion` -- the fused multi-image net's head (the single-image net's maps on the flash
  photo blended with the multi-image net's; ``NetConfig.fusion``);
* :mod:`~mi_svbrdf.nets.large_scale` -- the by-example large-scale network (an ambient photo and exemplars);
* :mod:`~mi_svbrdf.nets.train` -- training on the online capture simulator (``TrainConfig``);
* :mod:`~mi_svbrdf.nets.weights` -- the bundled weights: loading, the manifest, export from a run;
* :mod:`~mi_svbrdf.nets.ensemble` -- the symmetry ensemble of a flash net (8 flips and rotations, averaged);
* :mod:`~mi_svbrdf.nets.tiling` -- any-size inference of the large-scale net, tile by tile;
* :mod:`~mi_svbrdf.nets.inference` -- photos to maps (:func:`~mi_svbrdf.nets.inference.predict`).
"""
from mi_svbrdf.nets import large_scale as _large_scale  # noqa: F401  (registers kind "large" with build_network)
